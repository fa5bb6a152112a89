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

import math
import os
from dataclasses import dataclass
from pathlib import Path

from scanqa.errors import InputError
from scanqa.io.tomlfile import read_toml

#: Value of the ``format`` key this version reads.
FORMAT = "scanqa-budget/1"
#: Coverage choice that computes k from the effective degrees of freedom.
WELCH_SATTERTHWAITE = "welch-satterthwaite"
#: Known keys per table: name -> (unit for messages, lowest allowed value).
_KEYS = {
    "gauge_blocks": {"certificate_U_um": ("um", 0.0), "certificate_U_per_mm_um": ("um/mm", 0.0),
                     "certificate_k": ("", 1e-9)},
    "temperature": {"deviation_K": ("K", -math.inf), "uncertainty_K": ("K", 0.0),
                    "expansion_per_K": ("1/K", -math.inf),
                    "expansion_uncertainty_per_K": ("1/K", 0.0)},
    "stage": {"scale_uncertainty_ppm": ("ppm", 0.0)},
    "calibration_flat": {"flatness_um": ("um", 0.0)},
}


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
    data = read_toml(path, "uncertainty budget")
    if data.get("format") != FORMAT:
        raise _err(path, f"format must be {FORMAT!r}, got {data.get('format')!r}")
    values: dict = {"source": str(path)}
    for table, content in data.items():
        if table == "format":
            continue
        if table == "coverage":
            values["coverage_k"] = _coverage(path, content)
            continue
        if table not in _KEYS or not isinstance(content, dict):
            raise _err(path, f"unknown table [{table}] (known: "
                             f"{', '.join(sorted([*_KEYS, 'coverage']))})")
        for key, value in content.items():
            values[key] = _number(path, table, key, value)
    inputs = BudgetInputs(**values)
    thermal = (inputs.deviation_K, inputs.uncertainty_K, inputs.expansion_uncertainty_per_K)
    if any(v is not None for v in thermal) and inputs.expansion_per_K is None:
        raise _err(path, "[temperature] needs expansion_per_K (the blocks' expansion "
                         "coefficient, e.g. 11.5e-6 for steel)")
    return inputs


def _number(path, table: str, key: str, value) -> float:
    known = _KEYS[table]
    if key not in known:
        raise _err(path, f"[{table}] unknown key {key!r} (known: {', '.join(known)})")
    unit, lowest = known[key]
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and value >= lowest
    if not ok:
        rng = "a finite number" if lowest == -math.inf else f"a number >= {lowest:g}"
        raise _err(path, f"[{table}] {key} must be {rng} [{unit}], got {value!r}")
    return float(value)


def _coverage(path, content) -> float | str:
    if not isinstance(content, dict) or set(content) != {"k"}:
        raise _err(path, "[coverage] must hold one key, k (a number or "
                         f"{WELCH_SATTERTHWAITE!r})")
    k = content["k"]
    if k == WELCH_SATTERTHWAITE:
        return k
    if isinstance(k, bool) or not isinstance(k, (int, float)) or not k > 0:
        raise _err(path, f"[coverage] k must be a number > 0 or {WELCH_SATTERTHWAITE!r}, "
                         f"got {k!r}")
    return float(k)
