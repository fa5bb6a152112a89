"""The fitted model of a characterisation (``summary.json``, its ``best_variant``)."""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

from scanqa.errors import InputError


def read_fitted_model(path: str | os.PathLike) -> dict:
    """The best variant of a characterisation ``summary.json`` as ``[model]`` overrides.

    Returns
    -------
    dict
        ``filter_floor``, ``noise_reading``, ``filter_form``, ``sigma_p_px``
        [projector px], ``gamma`` [-] and ``sensor_sigma_p_px`` [projector px]. Summaries
        written before the two-source model lack the last two keys of the form and the
        sensor: their fits used Eq. 17 as printed ("product") and no sensor term. Every
        summary also gives ``characterised_by`` (the file and its hash); a board
        characterisation gives its noise law instead of the variant
        (``noise_read_var_dn2`` [DN^2], ``noise_shot_dn`` [DN], ``systematic_sigma_mm``).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
        data = json.loads(raw.decode("utf-8"))
        where = f"{path.name} (sha256 {hashlib.sha256(raw).hexdigest()[:16]})"
        if isinstance(data, dict) and data.get("kind") in ("board", "repeats"):
            kind = "board" if data["kind"] == "board" else "repeats"
            return _board_law(data["noise_law"], where, kind)
        best = data["best_variant"]
        return {"characterised_by": f"scanqa characterize: {where}",
                "filter_floor": str(best["filter_floor"]),
                "noise_reading": str(best["noise_reading"]),
                "filter_form": str(best.get("filter_form", "product")),
                "sigma_p_px": _number(best["sigma_p_px"], "sigma_p_px"),
                "gamma": _number(best["gamma"], "gamma"),
                "sensor_sigma_p_px": _number(best.get("sensor_sigma_p_px", 0.0),
                                             "sensor_sigma_p_px")}
    except OSError as err:
        raise InputError(f"cannot read characterisation {path}: {err.strerror}") from None
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as err:
        raise InputError(f"{path} is not a characterisation summary (scanqa characterize "
                         f"writes one; missing or bad {err})") from None


def _number(value, key: str) -> float:
    """A JSON number (not a boolean, which float() would take as 0 or 1)."""
    if isinstance(value, bool):
        raise ValueError(f"best_variant {key} (a number, got {str(value).lower()})")
    return float(value)


def _board_law(law: dict, where: str, kind: str) -> dict:
    """``[model]`` overrides of a board characterisation's noise law (``scanqa
    characterize-board``): the law, its systematic term and where it came from."""
    values = {"noise_read_var_dn2": float(law["read_var_dn2"]),
              "noise_shot_dn": float(law["shot_dn"]),
              "systematic_sigma_mm": 1e-3 * float(law["systematic_um"])}
    bad = [k for k, v in values.items() if not (math.isfinite(v) and v >= 0)]
    if bad:
        raise ValueError(f"noise_law {bad[0]} (must be a finite number >= 0)")
    data_hash = str(law.get("data_sha256", ""))[:16]
    return {"characterised_by": f"scanqa characterize-{kind}: {where}, images sha256 "
                                f"{data_hash}", **values}
