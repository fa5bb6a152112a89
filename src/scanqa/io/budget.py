"""Uncertainty budget files (TOML, ``format = "scanqa-budget/1"``): the Type B inputs of
the gauge-block QA that no scan can measure.

Every table and key is optional; what is missing is not in the budget (and the report
says so)::

    format = "scanqa-budget/1"

    [gauge_blocks]                    # the blocks' calibration certificate
    certificate_U_um = 0.10           # expanded uncertainty of a block's length, constant part [um]
    certificate_U_per_mm_um = 0.001   # its length-proportional part [um per mm of length]
    certificate_k = 2.0               # coverage factor of those U (default 2)

    [temperature]                     # the blocks' temperature during the scan
    deviation_K = 0.5                 # measured deviation from 20 degC [K]
    uncertainty_K = 0.2               # standard uncertainty of that deviation [K]
    expansion_per_K = 11.5e-6         # linear expansion coefficient of the blocks [1/K]
    expansion_uncertainty_per_K = 1.0e-6   # its standard uncertainty [1/K]

    [stage]                           # the calibration stage's length scale
    scale_uncertainty_ppm = 20.0      # standard uncertainty of its scale [1e-6]

    [calibration_flat]
    flatness_um = 0.5                 # peak-to-valley flatness of the calibration flat [um]

    [coverage]
    k = 2.0                           # a stated k, or "welch-satterthwaite"

This module reads and checks the file (:func:`read_budget_file`); the budget itself is
computed by :mod:`scanqa.qa.budget`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.schema import Field, Schema, at_least, declare, greater
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-budget/1"
#: Coverage choice that computes k from the effective degrees of freedom.
WELCH_SATTERTHWAITE = "welch-satterthwaite"


def _table(name: str, *fields: Field) -> Field:
    return Field(name, "table", table=Schema(f"[{name}]", fields), doc=_TABLE_DOCS[name])


_TABLE_DOCS = {"gauge_blocks": "the blocks' calibration certificate",
               "temperature": "the blocks' temperature during the scan",
               "stage": "the calibration stage's length scale",
               "calibration_flat": "the calibration flat", "coverage": "the coverage factor"}
#: The budget file's keys (module notes); every table and key is optional.
SCHEMA = declare(Schema("uncertainty budget", (
    Field("format", "string", required=True, doc=f"{FORMAT!r}"),
    _table("gauge_blocks",
           Field("certificate_U_um", "number", "um", check=at_least(0),
                 doc="expanded uncertainty of a block's length, constant part"),
           Field("certificate_U_per_mm_um", "number", "um/mm", check=at_least(0),
                 doc="its length-proportional part"),
           Field("certificate_k", "number", "-", default=2.0, check=greater(0),
                 doc="coverage factor of those U")),
    _table("temperature",
           Field("deviation_K", "number", "K", doc="measured deviation from 20 degC"),
           Field("uncertainty_K", "number", "K", check=at_least(0),
                 doc="standard uncertainty of that deviation"),
           Field("expansion_per_K", "number", "1/K",
                 doc="linear expansion coefficient of the blocks"),
           Field("expansion_uncertainty_per_K", "number", "1/K", check=at_least(0),
                 doc="its standard uncertainty")),
    _table("stage", Field("scale_uncertainty_ppm", "number", "ppm", check=at_least(0),
                          doc="standard uncertainty of its scale")),
    _table("calibration_flat", Field("flatness_um", "number", "um", check=at_least(0),
                                     doc="peak-to-valley flatness")),
    _table("coverage", Field("k", "number or string", "-", required=True,
                             check=greater(0),
                             doc=f"a stated k, or {WELCH_SATTERTHWAITE!r}")),
), formats=(FORMAT,)))


@dataclass(frozen=True)
class BudgetInputs:
    """The Type B inputs of a budget file (None: not given). Units as in the key names."""

    source: str = ""
    certificate_U_um: float | None = None
    certificate_U_per_mm_um: float | None = None
    certificate_k: float = 2.0
    deviation_K: float | None = None
    uncertainty_K: float | None = None
    expansion_per_K: float | None = None
    expansion_uncertainty_per_K: float | None = None
    scale_uncertainty_ppm: float | None = None
    flatness_um: float | None = None
    coverage_k: float | str | None = None


def _err(path, msg: str) -> InputError:
    return InputError(f"{path}: {msg}")


def read_budget_file(path: str | os.PathLike) -> BudgetInputs:
    """Read and check a budget file (module notes).

    Raises
    ------
    InputError
        Unreadable file, wrong format, unknown table or key, a value that is not a
        number or out of range, a temperature deviation without its expansion
        coefficient.
    """
    path = Path(path)
    data = SCHEMA.validate(read_toml(path, "uncertainty budget"), path)
    values: dict = {"source": str(path)}
    for table, content in data.items():
        if table == "coverage":
            values["coverage_k"] = _coverage(path, content["k"])
        elif table != "format":
            values.update({key: float(value) for key, value in content.items()})
    inputs = BudgetInputs(**values)
    thermal = (inputs.deviation_K, inputs.uncertainty_K, inputs.expansion_uncertainty_per_K)
    if any(v is not None for v in thermal) and inputs.expansion_per_K is None:
        raise _err(path, "[temperature] needs expansion_per_K (the blocks' expansion "
                         "coefficient, e.g. 11.5e-6 for steel)")
    return inputs


def _coverage(path, k) -> float | str:
    """``[coverage] k``: a number (checked by :data:`SCHEMA`) or the one named method."""
    if isinstance(k, str) and k != WELCH_SATTERTHWAITE:
        raise _err(path, f"[coverage] k must be a number > 0 or {WELCH_SATTERTHWAITE!r}, "
                         f"got {k!r}")
    return k if isinstance(k, str) else float(k)
