"""Uniform performance (Sect. 5.2, Fig. 7 of [1]_): flatten the range uncertainty of a
decoded scan with a digital filter whose size depends on each point's range, and say what
it costs in lateral resolution.

The scan is decoded once; each pixel's range comes from the calibration (a table or a
parametric model). The per-point random sigma - the source the cloud would use
(:func:`scanqa.annotation.points.sigma_source`: the characterised model, a board's noise law or
the decoder's own image estimate) - is binned by range; its median per bin is the curve
to flatten, and the target is its lowest value (the flattest sigma the volume allows, as
:func:`scanqa.design.tools.flatten_curve` takes it) unless one is given. For every bin the
filter that brings the bin's sigma to the target is solved for, and each pixel gets the
filter of its range.

The filter is applied to the quadrature components (C, S) of the working phase set, the
linear least-squares fit of the fringe images (:mod:`scanqa.decoding.demodulate`):
filtering the N images with a kernel K and demodulating them is the same as filtering C
and S with K, so two images are filtered instead of N. The new wrapped phase replaces the
old one within the same fringe order (the phase moves by far less than half a period),
so x_p keeps the unwrapping of the first decode and any projector-response correction to
first order. The convolution is normalised by the pixels that take part: the valid ones
and those masked for their fringe order only (sets that disagree, a coordinate off the
panel), whose C and S are as good as a valid pixel's. A pixel left out is not neutral: the
fringe turns across the kernel, so a missing sample off the centre turns the phase of the
kernel's sum (by ~0.01 px for one pixel 4 px out of a 7 px disc at a 28 px fringe), and
where the holes differ from scan to scan that is noise the filter adds.

What a disc filter K of noise-equivalent area NEA = 1 / sum(K^2) [px^2] does to the two
noise sources of docs/noise_model.rst:

* the sensor part, white at the pixel scale, falls as 1 / sqrt(NEA);
* the scene part, already filtered by the camera's own kernel, falls by the exact
  second-order factor of :func:`scanqa.annotation.filterbank.scene_gain` (square cells of
  side gamma, following the point's range, :func:`scanqa.model.optics.correlation_gamma`,
  through pixel, defocus disc, Airy pattern and the filter) when the model has the
  smooth floor (``filter_floor = "smooth"``), which gives the unflattened sigma by the
  areas-add law F^2 = 1 + N / gamma^2; otherwise it falls as F_o / F_a of that law
  with N_a = N_o + NEA - 1, and a floored model ("one") leaves the plan its kink near
  focus (docs/flattening.rst);
* both are divided by the filter's transfer m_f at the fringe period in the camera image
  (the fringe amplitude falls, Eq. 11), P_cam = P / norm(grad x_p).

A board noise law or the image estimate is all sensor part. A point's lateral resolution
is the diameter 4 s of the camera-side kernel on the object, s^2 the per-axis second
moment of pixel (1/12 px^2), defocus disc (C_c^2 / 16, Eq. 2), Airy disc and digital
filter, scaled by the pixel's footprint Z / f_px. The projector's blur is left out: it
does not mix the x_p of neighbouring surfaces that the camera sees (a range edge).

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017 (Sect. 5.2, Fig. 7).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from scanqa.annotation.filterbank import (
    FilterBank,
    camera_noise_area_px2,
    default_bank,
    filter_phase,
    optics_moment_px2,
    reduction,
)
from scanqa.annotation.points import sigma_source
from scanqa.calibration.base import Calibration
from scanqa.calibration.parametric_checks import with_calibrated_geometry
from scanqa.decoding.coding import PatternDescription
from scanqa.decoding.imagenoise import phase_sigma_px
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.model import optics
from scanqa.model.config import ScannerConfig

#: Range bins of the curve: at most this many, each with at least MIN_BIN_PIXELS and at
#: least MIN_BIN_MM wide (the model's sigma changes over millimetres, not microns).
MAX_BINS, MIN_BIN_PIXELS, MIN_BIN_MM = 24, 200, 2.0
#: Samples per level of the continuous level index when solving for the filter.
_SUBSTEPS = 8
#: Pixels whose range is computed, about: the rest take their nearest sample's filter.
SAMPLED_PIXELS = 250_000


@dataclass(frozen=True)
class PixelNoise:
    """What the filter acts on, per valid pixel (flat arrays over ``index``).

    Lengths in mm; ``scene_mm``/``sensor_mm`` are the two parts of the random sigma
    along the line of sight, ``noise_area_px2`` the camera kernel's noise-equivalent
    area N_o, ``period_cam_px`` the fringe period in the image, ``footprint_mm`` one
    pixel on the object, ``optics_moment_px2`` the per-axis second moment of the
    camera's own kernel (pixel, defocus, Airy) [px^2].
    """

    index: np.ndarray
    z_mm: np.ndarray
    scene_mm: np.ndarray
    sensor_mm: np.ndarray
    noise_area_px2: np.ndarray
    period_cam_px: np.ndarray
    footprint_mm: np.ndarray
    optics_moment_px2: np.ndarray
    source: str

    @property
    def sigma_mm(self) -> np.ndarray:
        """The random sigma before filtering [mm]."""
        return np.hypot(self.scene_mm, self.sensor_mm)


def pixel_noise(phase_map: PhaseMap, calibration: Calibration, config: ScannerConfig,
                stride: int = 1) -> PixelNoise:
    """Range, noise parts and kernel terms of the decoded pixels inside the volume.

    Parameters
    ----------
    phase_map : PhaseMap
        The first (unfiltered) decode.
    calibration : Calibration
        Table or parametric calibration of the scanner.
    config : ScannerConfig
        Optics and ``[model]`` (the sigma source, gamma and the readings).
    stride : int
        Every ``stride``-th pixel along rows and columns [-] (the range changes slowly
        against the filter's size; a parametric triangulation of every pixel would cost
        more than the decode).

    Returns
    -------
    PixelNoise
        Over the sampled pixels with a finite point; ``index`` is their flat index in
        the image.
    """
    config = with_calibrated_geometry(calibration, config)  # a parametric one's pose wins
    calibration.check_scan(config, phase_map)
    grid = np.zeros(phase_map.xp.shape, bool)
    grid[::stride, ::stride] = True
    index = np.flatnonzero(grid & np.isfinite(phase_map.xp))
    look = calibration.apply_rows(phase_map.xp, 0, index)
    finite = np.isfinite(look.xyz).all(axis=-1)
    index, q, s_t = index[finite], look.xyz[finite], look.s_t[finite]
    if index.size == 0:
        raise InputError("the scan has no point inside the calibrated volume: nothing to "
                         "flatten (check the calibration and the decoding mask)")
    origin = sigma_source(config, phase_map)
    scene, sensor = _noise_parts(origin, phase_map, config, q, s_t, index)
    z = q[:, 2]
    return PixelNoise(index, z, scene, sensor, camera_noise_area_px2(z, config),
                      fringe_period_at(phase_map, *np.divmod(index, phase_map.xp.shape[1])),
                      z / config.camera.principal_distance_px,
                      optics_moment_px2(z, config), origin["random"])


def _noise_parts(origin: dict, phase_map: PhaseMap, config: ScannerConfig, q: np.ndarray,
                 s_t: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scene and sensor parts of the random sigma of the selected pixels [mm]."""
    if origin["random"] == "model":
        pred = optics.predict(q, config, s_t=s_t)
        return pred.sigma_scene, pred.sigma_sensor
    if origin["random"] == "law":
        a, b, period, steps = origin["law"]
        sigma = s_t * phase_sigma_px(phase_map.modulation.reshape(-1)[index],
                                     phase_map.offset.reshape(-1)[index], a, b, period, steps)
    else:
        sigma = s_t * phase_map.sigma_xp.reshape(-1)[index].astype(float)
    return np.zeros_like(sigma), sigma


def fringe_period_at(phase_map: PhaseMap, rows: np.ndarray, cols: np.ndarray
                     ) -> np.ndarray:
    """The working fringe's period in the camera image at pixels (rows, cols),
    P / norm(grad x_p) with central differences (one-sided at the border) [camera px]."""
    xp = phase_map.xp
    h, w = xp.shape

    def slope(a: np.ndarray, b: np.ndarray, axis: int) -> np.ndarray:
        lo, hi = np.maximum(a - 1, 0), np.minimum(a + 1, (h, w)[axis] - 1)
        pick = (lambda i: xp[i, b]) if axis == 0 else (lambda i: xp[b, i])
        return (pick(hi) - pick(lo)) / np.maximum(hi - lo, 1)

    with np.errstate(invalid="ignore", divide="ignore"):
        return phase_map.period_px / np.hypot(slope(rows, cols, 0), slope(cols, rows, 1))


@dataclass(frozen=True)
class FlattenCurve:
    """The filter against range (Fig. 7) for one scan, per range bin.

    Attributes
    ----------
    target_um : float
        The sigma every bin is brought to [um].
    target_stated : bool
        True when the user gave the target, False when it is the lowest bin's sigma.
    z_mm : (n,) float
        Bin centres (camera Z) [mm].
    count : (n,) int
        Pixels per bin [-].
    sigma_um, sigma_flat_um : (n,) float
        Median random sigma of the bin before and (predicted) after filtering [um].
    level : (n,) float
        Level index of the filter in the bank [-].
    filter_diameter_px : (n,) float
        Equivalent disc diameter of the filter, 4 sqrt(second moment) [camera px].
    optical_blur_px : (n,) float
        The same for the camera's own kernel (pixel, defocus, Airy) [camera px].
    lateral_resolution_mm : (n,) float
        Median lateral resolution after filtering (module notes) [mm].
    lateral_before_mm : (n,) float
        The same without the digital filter [mm].
    reachable : (n,) bool
        Whether the bank's filters bring the bin to the target (the fringe's attenuation
        by a large filter ends the gain).
    source : str
        The random sigma flattened: "model", "law" or "images".
    """

    target_um: float
    target_stated: bool
    z_mm: np.ndarray
    count: np.ndarray
    sigma_um: np.ndarray
    sigma_flat_um: np.ndarray
    level: np.ndarray
    filter_diameter_px: np.ndarray
    optical_blur_px: np.ndarray
    lateral_resolution_mm: np.ndarray
    lateral_before_mm: np.ndarray
    reachable: np.ndarray
    source: str

    def level_at(self, z_mm: np.ndarray) -> np.ndarray:
        """The filter level of points at range ``z_mm`` (held at the end bins) [-]."""
        return np.interp(z_mm, self.z_mm, self.level)

    def as_dict(self) -> dict:
        """Plain lists for JSON (the phase map's provenance, summaries)."""
        out = {"target_um": self.target_um, "target_stated": self.target_stated,
               "source": self.source}
        for name in ("z_mm", "count", "sigma_um", "sigma_flat_um", "level",
                     "filter_diameter_px", "optical_blur_px", "lateral_resolution_mm",
                     "lateral_before_mm", "reachable"):
            out[name] = np.asarray(getattr(self, name)).tolist()
        return out

    @classmethod
    def from_dict(cls, data: dict) -> FlattenCurve:
        """Inverse of :meth:`as_dict`."""
        arrays = {k: np.asarray(v) for k, v in data.items()
                  if k not in ("target_um", "target_stated", "source")}
        return cls(float(data["target_um"]), bool(data["target_stated"]),
                   source=str(data["source"]), **arrays)

    def rows(self) -> list[dict]:
        """One row per bin: the trade-off table (range, sigma, filter, lateral res.)."""
        return [{"z_mm": float(z), "n": int(n), "sigma_um": float(s),
                 "sigma_flat_um": float(f), "filter_diameter_px": float(d),
                 "lateral_before_mm": float(lb), "lateral_resolution_mm": float(la),
                 "reachable": bool(r)}
                for z, n, s, f, d, lb, la, r in zip(
                    self.z_mm, self.count, self.sigma_um, self.sigma_flat_um,
                    self.filter_diameter_px, self.lateral_before_mm,
                    self.lateral_resolution_mm, self.reachable, strict=True)]


def _bins(z: np.ndarray) -> np.ndarray:
    """Bin edges of equal width over the central 99 % of the ranges [mm]."""
    lo, hi = np.percentile(z, [0.5, 99.5])
    n = int(min(z.size // MIN_BIN_PIXELS, MAX_BINS, (hi - lo) // MIN_BIN_MM))
    if n < 1:
        return np.array([z.min() - 1e-6, z.max() + 1e-6])
    edges = np.linspace(lo, hi, n + 1)
    edges[0], edges[-1] = min(lo, z.min()), max(hi, z.max())
    return edges


def _sample(sel: np.ndarray, size: int = 500) -> np.ndarray:
    """At most ``size`` evenly spaced members of an index array."""
    return sel if sel.size <= size else sel[np.linspace(0, sel.size - 1, size).astype(int)]


def plan(noise: PixelNoise, config: ScannerConfig, target_um: float | None = None,
         bank: FilterBank | None = None) -> FlattenCurve:
    """The filter level of every range bin that brings its median sigma to the target.

    Parameters
    ----------
    noise : PixelNoise
        From :func:`pixel_noise`.
    config : ScannerConfig
        Its ``[model]`` (gamma, form, floor).
    target_um : float, optional
        The sigma to reach [um]; default the lowest bin's median sigma (the flattest the
        volume allows without making any bin worse).
    bank : FilterBank, optional
        Default :func:`default_bank`.

    Returns
    -------
    FlattenCurve
        Per bin; bins with fewer than ``MIN_BIN_PIXELS // 2`` pixels are dropped.
    """
    bank = bank or default_bank()
    if target_um is not None and not (np.isfinite(target_um) and target_um > 0):
        raise InputError(f"the flattening target must be a sigma > 0 um, got {target_um!r}")
    edges = _bins(noise.z_mm)
    which = np.clip(np.searchsorted(edges, noise.z_mm) - 1, 0, edges.size - 2)
    members = [np.flatnonzero(which == b) for b in range(edges.size - 1)]
    members = [m for m in members if m.size >= MIN_BIN_PIXELS // 2
               and np.isfinite(noise.sigma_mm[m]).sum() >= MIN_BIN_PIXELS // 2]
    if not members:
        raise InputError(f"too few points to flatten ({noise.z_mm.size}; at least "
                         f"{MIN_BIN_PIXELS // 2} with a finite sigma are needed)")
    grid = np.linspace(0.0, bank.top, int(bank.top) * _SUBSTEPS + 1)
    finite = np.isfinite(noise.sigma_mm) & np.isfinite(noise.period_cam_px)
    curves = [_bin_curve(noise, _sample(m[finite[m]]), grid, config, bank) for m in members]
    before = np.array([c[0] for c in curves])
    target = float(np.min(before)) if target_um is None else 1e-3 * target_um
    levels, reach = zip(*(_solve(c, grid, target) for c in curves), strict=True)
    level = np.array(levels)
    z = np.array([np.median(noise.z_mm[m]) for m in members])
    moment = np.array([np.median(noise.optics_moment_px2[m]) for m in members])
    foot = np.array([np.median(noise.footprint_mm[m]) for m in members])
    after = np.array([np.interp(t, grid, c) for t, c in zip(level, curves, strict=True)])
    filt = bank.moment_px2(level)
    return FlattenCurve(1e3 * target, target_um is not None, z,
                        np.array([m.size for m in members]), 1e3 * before, 1e3 * after,
                        level, 4 * np.sqrt(filt), 4 * np.sqrt(moment),
                        4 * np.sqrt(moment + filt) * foot, 4 * np.sqrt(moment) * foot,
                        np.array(reach), noise.source)


def _bin_curve(noise: PixelNoise, sel: np.ndarray, grid: np.ndarray, config: ScannerConfig,
               bank: FilterBank) -> np.ndarray:
    """Median sigma of a bin's pixels after the filter at each level of ``grid`` [mm]."""
    levels = np.arange(len(bank.kernels))
    m_levels = bank.level_transfer(levels[:, None], noise.period_cam_px[sel][None, :])
    k, w = bank._split(grid)
    m_f = (1 - w)[:, None] * m_levels[k] + w[:, None] * m_levels[k + 1]
    g_scene, g_sensor = reduction(noise.noise_area_px2[sel][None, :], m_f,
                                  grid[:, None], config, bank, transfer=True,
                                  z_mm=noise.z_mm[sel][None, :])
    after = np.hypot(noise.scene_mm[sel] * g_scene, noise.sensor_mm[sel] * g_sensor)
    return np.median(after, axis=1)


def _solve(curve: np.ndarray, grid: np.ndarray, target: float) -> tuple[float, bool]:
    """The lowest level where the bin's curve reaches the target (linear between grid
    points), or the level of its minimum when it never does."""
    if curve[0] <= target:
        return 0.0, True
    below = np.flatnonzero(curve <= target)
    if below.size == 0:
        return float(grid[int(np.nanargmin(curve))]), False
    i = int(below[0])
    w = (curve[i - 1] - target) / (curve[i - 1] - curve[i])
    return float(grid[i - 1] + w * (grid[i] - grid[i - 1])), True


@dataclass(frozen=True, eq=False)
class FlattenedScan:
    """A flattened decode and what it cost, per pixel.

    Attributes
    ----------
    phase_map : PhaseMap
        x_p after filtering; ``sigma_xp`` the decoder's image estimate after filtering;
        modulation and offset those of the fringe as captured; the curve in
        ``provenance["flatten"]``.
    curve : FlattenCurve
        The filter against range.
    level : (H, W) float
        Filter level per pixel, NaN where not decoded [-].
    sigma_mm, sigma_flat_mm : (H, W) float
        Random sigma before and (predicted) after filtering [mm], on the sampled pixels
        (every ``stride``-th along rows and columns; NaN elsewhere).
    lateral_resolution_mm : (H, W) float
        Camera kernel plus digital filter on the object, as a disc diameter [mm], on the
        sampled pixels.
    stride : int
        Sampling of the range [px].
    """

    phase_map: PhaseMap
    curve: FlattenCurve
    level: np.ndarray
    sigma_mm: np.ndarray
    sigma_flat_mm: np.ndarray
    lateral_resolution_mm: np.ndarray
    stride: int = 1


def flatten(desc: PatternDescription, stacks: Sequence[np.ndarray], phase_map: PhaseMap,
            calibration: Calibration, config: ScannerConfig, target_um: float | None = None,
            bank: FilterBank | None = None) -> FlattenedScan:
    """Flatten a decoded scan's range uncertainty (Sect. 5.2; module notes).

    Parameters
    ----------
    desc : PatternDescription
        The coding the scan was decoded with (its finest phase set is filtered).
    stacks : sequence of (N, H, W) array
        The fringe images, one stack per set [DN].
    phase_map : PhaseMap
        Their decode (:func:`scanqa.decoding.decoder.decode_images`).
    calibration : Calibration
        Table or parametric calibration (for each pixel's range).
    config : ScannerConfig
        The scanner's config (optics and ``[model]``).
    target_um : float, optional
        The sigma to flatten to [um]; default the lowest over the scan's ranges.
    bank : FilterBank, optional
        Default :func:`default_bank`.

    Returns
    -------
    FlattenedScan
        The filtered map, the curve and the per-pixel sigma and lateral resolution.
    """
    if not desc.phase_sets:
        raise InputError(f"{desc.source or 'the coding'} has no phase set: a Gray code "
                         "alone has no fringe to filter, so it cannot be flattened")
    if desc.options.fuse_periods:
        raise InputError("flattening filters the finest phase set, which fuse_periods mixes "
                         "with the others: decode without fusing the periods to flatten")
    bank = bank or default_bank()
    shape = phase_map.xp.shape
    stride = max(1, round(math.sqrt(phase_map.xp.size / SAMPLED_PIXELS)))
    noise = pixel_noise(phase_map, calibration, config, stride)
    curve = plan(noise, config, target_um, bank)
    level = _level_map(shape, stride, noise, curve, phase_map.valid)
    working = desc.phase_sets[-1]
    stack = stacks[[s.name for s in desc.sets].index(working.name)]
    with ThreadPoolExecutor(max_workers=1) as pool:  # the sampled pixels' gains meanwhile
        filtered = pool.submit(filter_phase, stack, working.shifts_rad, phase_map, level,
                               bank)
        g_scene, g_sensor = reduction(noise.noise_area_px2, noise.period_cam_px,
                                      curve.level_at(noise.z_mm), config, bank,
                                      z_mm=noise.z_mm)
        xp, gain = filtered.result()
    sigma, flat, lateral = (np.full(shape, np.nan) for _ in range(3))
    sigma.flat[noise.index] = noise.sigma_mm
    flat.flat[noise.index] = np.hypot(noise.scene_mm * g_scene, noise.sensor_mm * g_sensor)
    lateral.flat[noise.index] = 4 * noise.footprint_mm * np.sqrt(
        noise.optics_moment_px2 + bank.moment_px2(curve.level_at(noise.z_mm)))
    sensor_gain = np.where(np.isfinite(level), gain, 1.0)
    prov = {**phase_map.provenance, "flatten": curve.as_dict()}
    out = replace(phase_map, xp=xp, sigma_xp=(phase_map.sigma_xp * sensor_gain).astype(
        np.float32), provenance=prov)
    return FlattenedScan(out, curve, level, sigma, flat, lateral, stride)


def _level_map(shape: tuple, stride: int, noise: PixelNoise, curve: FlattenCurve,
               valid: np.ndarray) -> np.ndarray:
    """Filter level of every valid pixel: that of the nearest sampled pixel [-]."""
    coarse = np.full(shape, np.nan)
    coarse.flat[noise.index] = curve.level_at(noise.z_mm)
    coarse = coarse[::stride, ::stride]
    missing = np.isnan(coarse)
    if missing.all():
        return np.full(shape, np.nan)
    if missing.any():
        near = ndimage.distance_transform_edt(missing, return_distances=False,
                                              return_indices=True)
        coarse = coarse[tuple(near)]
    full = np.repeat(np.repeat(coarse, stride, axis=0), stride, axis=1)[:shape[0], :shape[1]]
    return np.where(valid, full, np.nan)


#: Attributes a flattened cloud adds, with units in their names.
FLAT_ATTRIBUTES = ("sigma_flat_um", "sigma_unflattened_um", "filter_diameter_px",
                   "lateral_resolution_mm")


def flattened_attributes(attributes: dict, xyz: np.ndarray, phase_map: PhaseMap,
                         config: ScannerConfig, bank: FilterBank | None = None) -> dict:
    """Per-point attributes of a cloud annotated from a flattened phase map.

    Parameters
    ----------
    attributes : dict of (n,) array
        The cloud's attributes (:func:`scanqa.annotation.points.annotate` of the flattened map).
    xyz : (n, 3) float
        Its points [mm].
    phase_map : PhaseMap
        The flattened map (``provenance["flatten"]``).
    config : ScannerConfig
        The scanner's config.
    bank : FilterBank, optional
        Default :func:`default_bank`.

    Returns
    -------
    dict of (n,) float32
        ``sigma_flat_um`` (the random sigma after filtering), ``sigma_unflattened_um``
        (before), ``filter_diameter_px``, ``lateral_resolution_mm``, and
        ``sigma_random_um``, ``sigma_total_um`` and ``sx_um``/``sy_um``/``sz_um``
        replaced by their flattened values.
    """
    if "flatten" not in phase_map.provenance:
        raise InputError("the phase map was not flattened (no 'flatten' in its "
                         "provenance): decode or annotate it with flattening on")
    bank = bank or default_bank()
    curve = FlattenCurve.from_dict(phase_map.provenance["flatten"])
    z = xyz[:, 2]
    level = curve.level_at(z)
    u, v = attributes["pixel_u"].astype(int), attributes["pixel_v"].astype(int)
    period = fringe_period_at(phase_map, v, u)
    model = config.model
    g_scene, g_sensor = reduction(camera_noise_area_px2(z, config), period, level, config,
                                  bank, z_mm=z)
    random = attributes["sigma_random_um"].astype(float)
    source = curve.source
    if source == "model":
        before = random
        flat = np.hypot(attributes["sigma_scene_um"] * g_scene,
                        attributes["sigma_sensor_um"] * g_sensor)
    elif source == "law":
        before, flat = random, random * g_sensor
    else:  # images: sigma_xp of a flattened map is already the filtered estimate
        before, flat = random / g_sensor, random
    lateral = 4 * z / config.camera.principal_distance_px * np.sqrt(
        optics_moment_px2(z, config) + bank.moment_px2(level))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = flat / random
    table = attributes["sigma_calibration_um"].astype(float)
    total = np.sqrt(flat ** 2 + table ** 2 + (1e3 * model.systematic_sigma_mm) ** 2)
    out = {"sigma_flat_um": flat, "sigma_unflattened_um": before,
           "filter_diameter_px": 4 * np.sqrt(bank.moment_px2(level)),
           "lateral_resolution_mm": lateral, "sigma_random_um": flat, "sigma_total_um": total}
    for name in ("sx_um", "sy_um", "sz_um"):
        out[name] = attributes[name] * scale
    return {k: np.asarray(v, dtype=np.float32) for k, v in out.items()}
