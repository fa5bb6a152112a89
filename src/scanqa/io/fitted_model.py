"""The fitted model of a characterisation (``summary.json``, its ``best_variant``)."""

from __future__ import annotations

import json
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
        sensor: their fits used Eq. 17 as printed ("product") and no sensor term.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        best = data["best_variant"]
        return {"filter_floor": str(best["filter_floor"]),
                "noise_reading": str(best["noise_reading"]),
                "filter_form": str(best.get("filter_form", "product")),
                "sigma_p_px": float(best["sigma_p_px"]), "gamma": float(best["gamma"]),
                "sensor_sigma_p_px": float(best.get("sensor_sigma_p_px", 0.0))}
    except OSError as err:
        raise InputError(f"cannot read characterisation {path}: {err.strerror}") from None
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{path} is not a characterisation summary (scanqa characterize "
                         f"writes one; missing or bad {err})") from None
