"""The fitted model of a characterisation (``summary.json``, its ``best_variant``), and
the evidence a config's ``[model] characterised_by`` must name."""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path

from scanqa.errors import ConfigError, InputError

#: ``characterised_by``: a characterisation file, the start of its SHA-256 (16 to 64
#: hex digits) and an optional remark in parentheses.
EVIDENCE = re.compile(r"^(?P<path>\S.*?) sha256 (?P<hash>[0-9a-f]{16,64})(?: \((?P<note>.*)\))?$")
#: Kinds of file that count as evidence: a sweep characterisation (its best variant), a
#: board or repeats characterisation (a noise law), or a published measurement written
#: down as a file (``kind = "published"``, with its citation and sigma_p_px).
EVIDENCE_KINDS = ("board", "repeats", "published")


def evidence(path: str | os.PathLike, remark: str = "") -> str:
    """The ``characterised_by`` value that names a characterisation file [text]."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    return f"{path} sha256 {digest}" + (f" ({remark})" if remark else "")


def absolute_evidence(text: str, config_path: str | os.PathLike) -> str:
    """``characterised_by`` with its file named by absolute path (for a config written
    elsewhere: an export, a copy); other text unchanged."""
    found = EVIDENCE.match(text or "")
    if found is None or Path(found["path"]).is_absolute():
        return text
    path = (Path(config_path).parent / found["path"]).resolve()
    return f"{path}{text[found.end('path'):]}"


def check_characterised_by(text: str, config_path: str | os.PathLike) -> None:
    """Refuse a ``characterised_by`` that does not name a characterisation file whose
    SHA-256 starts with the digits given (the path relative to the config's folder).

    Raises
    ------
    ConfigError
        One line: free text, a missing or unreadable file, a changed file (its hash), or
        a file that is no characterisation.
    """
    if not text:
        return
    key = f"[model] characterised_by = {text!r} in {config_path}"
    found = EVIDENCE.match(text)
    if found is None:
        raise ConfigError(
            f"{key} does not name a characterisation: give the summary.json that scanqa "
            "characterize (sweep, board or repeats) wrote and the start "
            "of its sha256, as \"board_noise/summary.json sha256 <16 hex digits>\" (relative "
            "to the config; apply a summary with the model option to get the line), or "
            "leave it out: every point's sigma then comes from the scan's own images")
    path = Path(found["path"])
    if not path.is_absolute():
        path = Path(config_path).parent / path
    try:
        raw = path.read_bytes()
        data = json.loads(raw.decode("utf-8"))
    except OSError as err:
        raise ConfigError(f"{key}: cannot read {path} ({err.strerror}); give the "
                          "characterisation's summary.json, relative to the config") from None
    except (ValueError, RecursionError):
        raise ConfigError(f"{key}: {path} is not JSON, so no characterisation") from None
    digest = hashlib.sha256(raw).hexdigest()
    if not digest.startswith(found["hash"]):
        raise ConfigError(f"{key}: {path} has sha256 {digest[:16]}..., not {found['hash']}: "
                          "the file changed since the config named it; check it and give "
                          "its new hash")
    if not (isinstance(data, dict) and ("best_variant" in data
                                        or data.get("kind") in EVIDENCE_KINDS)):
        raise ConfigError(f"{key}: {path} is not a characterisation summary (no best_variant "
                          f"and no kind of {', '.join(EVIDENCE_KINDS)})")


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
        where = f"{path} sha256 {hashlib.sha256(raw).hexdigest()[:16]}"
        if isinstance(data, dict) and data.get("kind") in ("board", "repeats"):
            kind = "board" if data["kind"] == "board" else "repeats"
            return _board_law(data["noise_law"], where, kind)
        best = data["best_variant"]
        return {"characterised_by": f"{where} (scanqa characterize sweep)",
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
    characterize board``): the law, its systematic term and where it came from."""
    values = {"noise_read_var_dn2": float(law["read_var_dn2"]),
              "noise_shot_dn": float(law["shot_dn"]),
              "systematic_sigma_mm": 1e-3 * float(law["systematic_um"])}
    bad = [k for k, v in values.items() if not (math.isfinite(v) and v >= 0)]
    if bad:
        raise ValueError(f"noise_law {bad[0]} (must be a finite number >= 0)")
    data_hash = str(law.get("data_sha256", ""))[:16]
    return {"characterised_by": f"{where} (scanqa characterize {kind}, images sha256 "
                                f"{data_hash})", **values}
