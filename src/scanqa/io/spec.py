"""Acceptance specs (TOML, ``format = "scanqa-spec/1"``): a scanner's MPEs and the test
artefacts' certificates for the VDI/VDE 2634-2 tests.

Example::

    format = "scanqa-spec/1"
    name = "Maker M, model X, data sheet 2024-03"   # optional
    mpe_pf_um = 15.0                      # probing error form PF
    mpe_ps_um = 10.0                      # probing error size PS (applies to |PS|)
    mpe_sd_um = { a = 20.0, b = 1000.0 }  # sphere-spacing error SD: 20 um + L/1000
    mpe_f_um = 25.0                       # flatness measurement error F

    [sphere]                              # certificate of the test sphere
    diameter_mm = 25.4013
    diameter_uncertainty_um = 1.0         # expanded uncertainty U as certified
    k = 2.0                               # its coverage factor (default 2)
    form_um = 1.5                         # optional: certified form deviation

    [ball_bar]
    distance_mm = 300.0042
    distance_uncertainty_um = 2.0
    k = 2.0
    diameter_mm = 25.4                    # optional: nominal ball diameter (finding)

    [flat]
    flatness_um = 2.0                     # certified flatness

Every MPE is optional, but a spec needs at least one. An MPE is a number [um] or, for a
length-dependent one, ``{a = A, b = K}``: MPE(L) = A + L / K [um] with L the calibrated
length in mm, the way maker data sheets print "A + L/K" (20 + L/1000 is 20.3 um at
300 mm). Certificates are optional; without one, the quantity that needs the calibrated
value (PS, SD) is not evaluated. This module reads and checks the file into records;
:mod:`scanqa.qa.vdi2634` uses them.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.schema import Field, Schema, at_least, declare, greater
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-spec/1"
#: MPE keys and the quantity each bounds.
MPE_KEYS = {"mpe_pf_um": "PF", "mpe_ps_um": "PS", "mpe_sd_um": "SD", "mpe_f_um": "F"}
_CERTIFIED = "the certificate's value"


def _mpe(key: str, doc: str) -> Field:
    return Field(key, "number", "um", check=greater(0), doc=doc)


def _k() -> Field:
    return Field("k", "number", "-", default=2.0, check=greater(0),
                 doc="coverage factor of the certified U")


_SPHERE = Schema("[sphere]", (
    Field("diameter_mm", "number", "mm", required=True, check=greater(0), doc=_CERTIFIED),
    Field("diameter_uncertainty_um", "number", "um", required=True, check=greater(0),
          doc=_CERTIFIED), _k(),
    Field("form_um", "number", "um", check=at_least(0), doc="certified form deviation")))
_BAR = Schema("[ball_bar]", (
    Field("distance_mm", "number", "mm", required=True, check=greater(0), doc=_CERTIFIED),
    Field("distance_uncertainty_um", "number", "um", required=True, check=greater(0),
          doc=_CERTIFIED), _k(),
    Field("diameter_mm", "number", "mm", check=greater(0), doc="nominal ball diameter")))
_FLAT = Schema("[flat]", (
    Field("flatness_um", "number", "um", required=True, check=at_least(0),
          doc=_CERTIFIED),))
#: The acceptance spec's keys (module notes); at least one MPE.
SCHEMA = declare(Schema("acceptance spec", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    Field("name", "string", doc="the spec's name (default: the file's stem)"),
    _mpe("mpe_pf_um", "MPE of the probing error form PF; only mpe_sd_um may depend on the "
                      "length"),
    _mpe("mpe_ps_um", "MPE of the probing error size PS, applies to abs(PS)"),
    Field("mpe_sd_um", "number or table", "um", check=greater(0),
          doc="MPE of the sphere-spacing error SD; {a = A, b = K}: A + L/K, L in mm",
          table=Schema("mpe_sd_um (A + L/K [um] with L in mm)", (
              Field("a", "number", "um", required=True, check=greater(0),
                    doc="constant part A"),
              Field("b", "number", "-", check=greater(0), doc="length divisor K")))),
    _mpe("mpe_f_um", "MPE of the flatness measurement error F"),
    Field("sphere", "table", table=_SPHERE, doc="certificate of the test sphere"),
    Field("ball_bar", "table", table=_BAR, doc="certificate of the ball bar"),
    Field("flat", "table", table=_FLAT, doc="certificate of the flat"),
), formats=(FORMAT,)))


@dataclass(frozen=True)
class Mpe:
    """A maximum permissible error MPE(L) = a_um + L / b [um], L in mm (b = inf: constant)."""

    a_um: float
    b: float = math.inf

    def at(self, length_mm: float = 0.0) -> float:
        """MPE at a length [mm], in mm."""
        return 1e-3 * (self.a_um + length_mm / self.b)


@dataclass(frozen=True)
class SphereCertificate:
    """Calibrated test sphere: diameter [mm], its expanded uncertainty [um] at coverage k,
    and optionally its form deviation [um]."""

    diameter_mm: float
    diameter_uncertainty_um: float
    k: float = 2.0
    form_um: float | None = None


@dataclass(frozen=True)
class BallBarCertificate:
    """Calibrated ball bar: centre distance [mm], its expanded uncertainty [um] at
    coverage k, optionally the nominal ball diameter [mm]."""

    distance_mm: float
    distance_uncertainty_um: float
    k: float = 2.0
    diameter_mm: float | None = None


@dataclass(frozen=True)
class FlatCertificate:
    """Calibrated flat: its flatness [um]."""

    flatness_um: float


@dataclass(frozen=True)
class Spec:
    """An acceptance spec: MPEs by quantity ("PF", "PS", "SD", "F") and certificates."""

    name: str
    mpe: dict
    sphere: SphereCertificate | None = None
    ball_bar: BallBarCertificate | None = None
    flat: FlatCertificate | None = None
    source: str = ""


def _err(path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def _mpe_value(value) -> Mpe:
    """An MPE key's value (checked by :data:`SCHEMA`): a number or {a = A, b = K}."""
    if isinstance(value, dict):
        return Mpe(float(value["a"]), float(value.get("b", math.inf)))
    return Mpe(float(value))


def _table(data: dict, name: str) -> dict | None:
    """A certificate table (checked by :data:`SCHEMA`) as floats, or None."""
    table = data.get(name)
    return None if table is None else {k: float(v) for k, v in table.items()}


def read_spec(path: str | os.PathLike) -> Spec:
    """Read and check an acceptance spec.

    Parameters
    ----------
    path : str or PathLike
        The spec file (module notes).

    Returns
    -------
    Spec

    Raises
    ------
    InputError
        Unreadable file, wrong format, unknown key, no MPE, bad value, missing certified
        value.
    """
    path = Path(path)
    data = SCHEMA.validate(read_toml(path, "acceptance spec"), path)
    mpe = {q: _mpe_value(data[key]) for key, q in MPE_KEYS.items() if key in data}
    if not mpe:
        raise _err(path, "no MPE given: set at least one of " + ", ".join(MPE_KEYS)
                   + " (the maker's maximum permissible errors [um])")
    sphere, bar, flat = (_table(data, name) for name in ("sphere", "ball_bar", "flat"))
    return Spec(name=str(data.get("name", path.stem)), mpe=mpe,
                sphere=None if sphere is None else SphereCertificate(**sphere),
                ball_bar=None if bar is None else BallBarCertificate(**bar),
                flat=None if flat is None else FlatCertificate(**flat), source=str(path))
