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
from scanqa.io.tomlfile import known_table, read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-spec/1"
#: MPE keys and the quantity each bounds.
MPE_KEYS = {"mpe_pf_um": "PF", "mpe_ps_um": "PS", "mpe_sd_um": "SD", "mpe_f_um": "F"}
_TOP = ("format", "name", *MPE_KEYS, "sphere", "ball_bar", "flat")
_SPHERE = {"diameter_mm": True, "diameter_uncertainty_um": True, "k": False, "form_um": False}
_BAR = {"distance_mm": True, "distance_uncertainty_um": True, "k": False, "diameter_mm": False}
_FLAT = {"flatness_um": True}


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


def _number(path, key: str, value, positive: bool = True) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= 0 if positive else value < 0):
        rule = "> 0" if positive else ">= 0"
        raise _err(path, f"{key} must be a number {rule}, got {value!r}")
    return float(value)


def _mpe(path, key: str, value) -> Mpe:
    if isinstance(value, dict):
        if key != "mpe_sd_um":
            raise _err(path, f"{key} must be a number [um]; only mpe_sd_um may depend on "
                             "the length ({a = .., b = ..})")
        unknown = sorted(set(value) - {"a", "b"})
        if unknown or "a" not in value:
            raise _err(path, f"{key} must be a number or {{a = A, b = K}} meaning A + L/K "
                             f"[um] with L in mm, got {value!r}")
        return Mpe(_number(path, f"{key}.a", value["a"]),
                   _number(path, f"{key}.b", value.get("b", math.inf)))
    return Mpe(_number(path, key, value))


def _table(path, data: dict, name: str, keys: dict) -> dict | None:
    table = known_table(data.get(name), name, keys, lambda msg: _err(path, msg))
    if table is None:
        return None
    missing = [k for k, required in keys.items() if required and k not in table]
    if missing:
        raise _err(path, f"[{name}]: {missing[0]} is missing (the certificate's value)")
    return {k: _number(path, f"{name}.{k}", v, positive=k not in ("form_um", "flatness_um"))
            for k, v in table.items()}


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
    data = read_toml(path, "acceptance spec")
    if data.get("format") != FORMAT:
        raise _err(path, f"format must be {FORMAT!r}, got {data.get('format')!r}")
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise _err(path, f"unknown key {unknown[0]!r} (known: {', '.join(_TOP)})")
    mpe = {q: _mpe(path, key, data[key]) for key, q in MPE_KEYS.items() if key in data}
    if not mpe:
        raise _err(path, "no MPE given: set at least one of " + ", ".join(MPE_KEYS)
                   + " (the maker's maximum permissible errors [um])")
    sphere = _table(path, data, "sphere", _SPHERE)
    bar = _table(path, data, "ball_bar", _BAR)
    flat = _table(path, data, "flat", _FLAT)
    return Spec(name=str(data.get("name", path.stem)), mpe=mpe,
                sphere=None if sphere is None else SphereCertificate(**sphere),
                ball_bar=None if bar is None else BallBarCertificate(**bar),
                flat=None if flat is None else FlatCertificate(**flat), source=str(path))
