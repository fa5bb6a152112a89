"""Per-point uncertainty of a scan: the optics model through the calibration table.

For every decoded pixel the table gives X, Y, Z and the slope dQ/dx_p; the model gives
s_O at that point (Eqs. 12-19) and sigma = s_T s_O sigma_p (Eq. 18) with s_T = |dQ/dx_p|
from the table (DESIGN.md section 3). Alongside: the sigma implied by the decoder's own
per-pixel phase noise (s_T sigma_xp), the table's sigma, the combined sigma
sqrt(model^2 + table^2), and with repeated scans the measured per-point std.

Attribute names (PLY ``scalar_<name>``, LAS extra bytes, CSV columns), all float32:

=================  ====  ==================================================================
name               unit  meaning
=================  ====  ==================================================================
sigma_model_um     um    model sigma along the line of sight; NaN where the model is not
                         valid (a blur ratio > 1/2)
sx_um, sy_um,      um    its X, Y, Z components (CloudCompare M3C2 precision maps pick
sz_um                    fields containing "sx", "sy", "sz")
sigma_phase_um     um    s_T x decoder sigma_xp (intensity noise and measured modulation)
sigma_table_um     um    the calibration table's own std at that point
sigma_total_um     um    sqrt(sigma_model^2 + sigma_table^2)
att_camera         -     camera attenuation A_c
att_projector      -     projector attenuation A_p
filter_factor      -     F_gamma (Eq. 17)
s_o                -     optical scale s_O (Eq. 19)
s_t_um_px          um/px triangulation scale |dQ/dx_p|
modulation_dn      DN    fringe modulation B
in_volume          0/1   phase inside the pixel's calibrated range
model_valid        0/1   both blur ratios <= 1/2
pixel_u, pixel_v   px    camera pixel (column, row)
sigma_meas_um      um    with repeats: std over the repeats along the line of sight
n_repeats          -     with repeats: number of scans valid at that pixel
=================  ====  ==================================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from scanqa import optics
from scanqa.calibration import CalibrationTable
from scanqa.config import ScannerConfig
from scanqa.errors import InputError
from scanqa.phase import PhaseMap

#: Attribute names in export order (repeat fields only when repeats are given).
ATTRIBUTES = ("sigma_model_um", "sx_um", "sy_um", "sz_um", "sigma_phase_um", "sigma_table_um",
              "sigma_total_um", "att_camera", "att_projector", "filter_factor", "s_o",
              "s_t_um_px", "modulation_dn", "in_volume", "model_valid", "pixel_u", "pixel_v")
REPEAT_ATTRIBUTES = ("sigma_meas_um", "n_repeats")


@dataclass(frozen=True)
class AnnotatedCloud:
    """Points [mm] with per-point attributes, and counts of what was left out."""

    xyz: np.ndarray
    attributes: dict
    counts: dict = field(default_factory=dict)
    model: dict = field(default_factory=dict)

    def summary(self) -> str:
        """One line: points written, and how many pixels were left out and why."""
        c = self.counts
        parts = [f"{c.get('written', 0)} points written",
                 f"{c.get('decoder_masked', 0)} pixels masked by the decoder",
                 f"{c.get('out_of_volume', 0)} outside the calibrated volume"
                 + (" (kept, flagged)" if c.get("kept_invalid") else " (left out)"),
                 f"{c.get('model_invalid', 0)} outside the model's validity (kept, flagged)"]
        return "; ".join(parts)


def check_compatible(table: CalibrationTable, config: ScannerConfig, phase_map: PhaseMap,
                     source: str = "scan") -> None:
    """Raise unless table, config and scan describe the same scanner and camera."""
    h, w = phase_map.xp.shape
    if (w, h) != (table.width_px, table.height_px):
        raise InputError(f"{source} is {w} x {h} px but the calibration table was built for a "
                         f"{table.width_px} x {table.height_px} px camera: use the table of "
                         "this scanner")
    built = table.config
    for section in ("camera", "projector"):
        mine = config.to_dict()[section]
        for key, value in built.get(section, {}).items():
            if not np.allclose(np.asarray(mine.get(key), float), np.asarray(value, float)):
                raise InputError(f"config {config.source} does not match the table's: "
                                 f"{section}.{key} is {mine.get(key)!r} here and {value!r} in "
                                 "the table; pass the config the table was built with")


def annotate(phase_map: PhaseMap, table: CalibrationTable, config: ScannerConfig,
             repeats: Sequence[PhaseMap] = (), keep_invalid: bool = False,
             source: str = "scan") -> AnnotatedCloud:
    """Annotate a decoded scan with per-point sigmas.

    Parameters
    ----------
    phase_map : PhaseMap
        The decoded scan.
    table : CalibrationTable
        The scanner's calibration table.
    config : ScannerConfig
        The config the table was built with (its ``[model]`` gives sigma_p, gamma and
        the readings; they may differ from the table's).
    repeats : sequence of PhaseMap
        Further scans of the same static scene for the measured per-point std.
    keep_invalid : bool
        Keep points outside the calibrated volume (extrapolated, flagged).
    source : str
        Name of the scan for messages.

    Returns
    -------
    AnnotatedCloud
    """
    check_compatible(table, config, phase_map, source)
    if not np.isfinite(phase_map.xp).any():
        raise InputError(f"{source} has no valid phase at all (every pixel is NaN): check the "
                         "decoding mask or the pattern images")
    look = table.apply_image(phase_map.xp, extrapolate=keep_invalid)
    decoded = np.isfinite(phase_map.xp)
    keep = decoded & (look.in_volume | keep_invalid)
    rows, cols = np.nonzero(keep)
    xyz = look.xyz[rows, cols]
    slope = look.slope[rows, cols]
    s_t = np.linalg.norm(slope, axis=-1)
    pred = optics.predict(xyz, config, s_t=s_t)
    sigma = np.where(pred.valid, pred.sigma, np.nan)
    unit = slope / s_t[:, None]
    sig_tab = look.sigma_table[rows, cols]
    attrs = {
        "sigma_model_um": 1e3 * sigma,
        "sx_um": 1e3 * sigma * np.abs(unit[:, 0]),
        "sy_um": 1e3 * sigma * np.abs(unit[:, 1]),
        "sz_um": 1e3 * sigma * np.abs(unit[:, 2]),
        "sigma_phase_um": 1e3 * s_t * phase_map.sigma_xp[rows, cols],
        "sigma_table_um": 1e3 * sig_tab,
        "sigma_total_um": 1e3 * np.hypot(sigma, sig_tab),
        "att_camera": pred.attenuation_camera, "att_projector": pred.attenuation_projector,
        "filter_factor": pred.filter_factor, "s_o": pred.s_o, "s_t_um_px": 1e3 * s_t,
        "modulation_dn": phase_map.modulation[rows, cols],
        "in_volume": look.in_volume[rows, cols], "model_valid": pred.valid,
        "pixel_u": cols, "pixel_v": rows,
    }
    if repeats:
        std, count = measured_std(table, [phase_map, *repeats])
        attrs["sigma_meas_um"] = 1e3 * std[rows, cols]
        attrs["n_repeats"] = count[rows, cols]
    attrs = {k: np.asarray(v, dtype=np.float32) for k, v in attrs.items()}
    counts = {"written": int(rows.size), "decoder_masked": int((~decoded).sum()),
              "out_of_volume": int((decoded & ~look.in_volume).sum()),
              "model_invalid": int((~pred.valid).sum()), "kept_invalid": keep_invalid}
    model = {"sigma_p_px": config.model.sigma_p_px, "gamma": config.model.gamma,
             "filter_floor": config.model.filter_floor,
             "noise_reading": config.model.noise_reading}
    return AnnotatedCloud(xyz, attrs, counts, model)


def measured_std(table: CalibrationTable, scans: Sequence[PhaseMap]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel std over repeated scans, along the line of sight.

    Parameters
    ----------
    table : CalibrationTable
        Calibration table.
    scans : sequence of PhaseMap
        Two or more scans of one static scene.

    Returns
    -------
    std : (H, W) float
        Sample std (ddof = 1) of the range along the camera ray [mm]; NaN where fewer
        than two scans are valid.
    count : (H, W) int
        Number of valid scans per pixel.
    """
    shape = (table.height_px, table.width_px)
    total = np.zeros(shape)
    total_sq = np.zeros(shape)
    count = np.zeros(shape, dtype=int)
    ref = np.zeros(shape)
    for k, scan in enumerate(scans):
        if scan.xp.shape != shape:
            raise InputError(f"repeat {k} is {scan.xp.shape[1]} x {scan.xp.shape[0]} px, the "
                             f"table's camera {shape[1]} x {shape[0]} px")
        look = table.apply_image(scan.xp)
        rng = np.linalg.norm(look.xyz, axis=-1)
        ok = np.isfinite(rng)
        # centre on the first valid value per pixel to keep the sums well conditioned
        ref = np.where(ok & (count == 0), rng, ref)
        d = np.where(ok, rng - ref, 0.0)
        total += d
        total_sq += d * d
        count += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (total_sq - total**2 / count) / (count - 1)
    return np.where(count >= 2, np.sqrt(np.maximum(var, 0.0)), np.nan), count
