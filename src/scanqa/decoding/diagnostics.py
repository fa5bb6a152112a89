"""What a decode tells its user: the misstatement guard, the disagreement between
periods, why pixels were masked and which key would change it.

Everything here works on the counts a decode gathered (:class:`~scanqa.decoding.unwrap.
ChainStats`) and ends up in the phase map's provenance (``provenance["decode"]``), from
which :meth:`~scanqa.decoding.phasemap.PhaseMap.summary` writes the summary lines.

The guard: a step that compares a set with its estimate (or a Gray code with its phase)
rejects a small share of the pixels when the coding is stated right, and about
``1 - 2 unwrap_max_residual`` of them when the two are unrelated - which is what a
misstated period, cell width or coded width makes them. When a step's rejected share
reaches ``coincidence_fraction`` times that, the pixels it let through agree by
coincidence, and every pixel is masked as inconsistent.
"""

from __future__ import annotations

import numpy as np

from scanqa.decoding.coding import PatternDescription
from scanqa.decoding.phasemap import MASK_INCONSISTENT, MASK_REASONS, MASK_VALID
from scanqa.decoding.unwrap import LOW_GRAY, LOW_PHASE, LOW_REASONS, LOW_STEP, ChainStats
from scanqa.numeric import robust_std

#: Fewest checked pixels for the guard to judge a step.
GUARD_MIN_PIXELS = 200
#: Steps where unrelated patterns would reject less than this share cannot be judged.
GUARD_MIN_UNIFORM = 0.2


def misstated_steps(desc: PatternDescription, stats: ChainStats) -> list[dict]:
    """Steps whose rejections look like unrelated patterns.

    Parameters
    ----------
    desc : PatternDescription
        The coding (``coincidence_fraction``).
    stats : ChainStats
        Counts of the decode.

    Returns
    -------
    list of dict
        ``step``, ``checked`` [-], ``rejected_share`` [-] and ``uniform_share`` [-].
    """
    out = []
    for step, checked in stats.checked.items():
        uniform = stats.uniform[step]
        share = stats.rejected[step] / checked if checked else 0.0
        if checked >= GUARD_MIN_PIXELS and uniform >= GUARD_MIN_UNIFORM and \
                share >= desc.thresholds.coincidence_fraction * uniform:
            out.append({"step": step, "checked": int(checked),
                        "rejected_share": round(share, 4), "uniform_share": round(uniform, 4)})
    return out


def apply_guard(out: dict[str, np.ndarray]) -> int:
    """Mask every valid pixel as inconsistent; return how many were valid."""
    valid = out["mask"] == MASK_VALID
    out["mask"][valid] = MASK_INCONSISTENT
    for name in out:
        if name in ("xp", "sigma_xp") or name.startswith("x:"):
            out[name][valid] = np.nan
    return int(valid.sum())


def disagreement(stats: ChainStats) -> list[dict]:
    """Median and robust spread of every set's coordinate minus x_p.

    Returns
    -------
    list of dict
        ``set``, ``median_px``, ``spread_px`` (1.4826 x median absolute deviation),
        ``p05_px``, ``p95_px`` [projector px] and ``samples`` [-].
    """
    rows = []
    for name, parts in stats.disagreement.items():
        d = np.concatenate(parts)
        if d.size == 0:
            continue
        p05, med, p95 = (float(q) for q in np.quantile(d, [0.05, 0.5, 0.95]))  # one sort
        rows.append({"set": name, "median_px": round(med, 4),
                     "spread_px": round(robust_std(d, centre=med), 4),
                     "p05_px": round(float(p05), 4), "p95_px": round(float(p95), 4),
                     "samples": int(d.size)})
    return rows


def mask_hint(desc: PatternDescription, counts: dict, stats: ChainStats,
              contradicted: bool = False) -> str:
    """When most pixels are masked: the dominant reason and the key that changes it.

    Parameters
    ----------
    contradicted : bool
        The images contradict the description (the guard or the residual test of
        :mod:`scanqa.decoding.consistency` fired): the hint then points at the
        description, never at thresholds or light, which cannot mend it.
    """
    total = sum(counts.values())
    masked = {k: v for k, v in counts.items() if k != "valid"}
    if not total or counts["valid"] >= 0.5 * total or not any(masked.values()):
        return ""
    reason = max(masked, key=masked.get)
    share = 100.0 * masked[reason] / total
    head = f"most pixels are masked: {reason} {share:.0f} % of the frame"
    if contradicted:
        return (f"{head}; the images contradict the description (see the warnings): fix "
                "patterns.toml first - thresholds and light cannot mend it")
    return f"{head}; {_fix(desc, reason, stats)}"


def _fix(desc: PatternDescription, reason: str, stats: ChainStats) -> str:
    th, sensor = desc.thresholds, desc.sensor
    if reason == "saturated":
        return ("lower the exposure (or set sensor.saturation_dn if the camera saturates "
                "above the image's full scale)")
    if reason == "out_of_range":
        return f"check projector_width_px (now {desc.projector_width_px})"
    if reason == "inconsistent":
        return ("the sets disagree: check period_px, shifts_rad, cell_px and "
                f"projector_width_px; thresholds.unwrap_max_residual (now "
                f"{th.unwrap_max_residual:g}) and thresholds.gray_edge_cells (now "
                f"{th.gray_edge_cells:g}) set how much disagreement is accepted, and a "
                "projector response (decode.response) removes gamma ripple")
    return _low_fix(desc, stats, sensor.knows_noise)


def _low_fix(desc: PatternDescription, stats: ChainStats, given: bool) -> str:
    th = desc.thresholds
    low = {bit: stats.low.get(bit, 0) for bit in LOW_REASONS}
    bit = max(low, key=low.get)
    what = LOW_REASONS[bit]
    if bit == LOW_STEP and stats.noisy:
        step = max(stats.noisy, key=stats.noisy.get)
        what += f" (mostly at step {step!r})"
    noise = ("or give the camera's [sensor] gain_e_per_dn and read_noise_e" if not given
             else "or check [sensor] gain_e_per_dn and read_noise_e")
    if bit == LOW_GRAY:
        key = f"lower thresholds.gray_min_contrast_sigma (now {th.gray_min_contrast_sigma:g})"
    elif bit in (LOW_PHASE, LOW_STEP):
        key = f"lower thresholds.unwrap_sigma_margin (now {th.unwrap_sigma_margin:g})"
    else:
        key = f"lower thresholds.min_modulation_dn (now {th.min_modulation_dn:g})"
    return f"mostly {what}: {key}, {noise}, or add light"


def mask_reason_names() -> dict:
    """Reason code to name, as stored in provenance."""
    return {str(k): v for k, v in MASK_REASONS.items()}
