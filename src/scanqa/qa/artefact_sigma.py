"""Per-point sigma and shared errors of a VDI/VDE 2634-2 artefact's points.

What U and the predicted form of :mod:`scanqa.qa.artefacts` rest on.

Per-point sigma (what U and the predicted form rest on). The optics model gives each
point's sigma along its line of sight for a surface facing the scanner (the paper's
Eqs. 18-19). On a curved artefact the fringe signal changes where the surface turns away
from the scanner (fringes foreshortened, light at an angle), and so does the phase
noise, differently for its two sources:

* the sensor part (shot and read noise) grows as the signal falls; the decoder knows it
  (its sensor noise model from the measured modulation and level, ``sigma_phase_um``);
* the scene part is proportional to the light itself, so it follows the inverse fringe
  contrast A / B (``offset_dn`` / ``modulation_dn``), not the brightness: dimmer light
  at an angle leaves it unchanged, a fringe attenuated by the pixel's own width (a large
  pixel on a foreshortened fringe) raises it.

Each part of the model's sigma (``sigma_scene_um``, ``sigma_sensor_um``) is scaled by
its factor, the ratio of the point's value to its median over the points seen within
20 deg of their normal (the part of the artefact that faces the scanner, as the model
assumes), both with the model's defocus amplitude sqrt(A_c A_p) divided out, which the
model already holds. Simulated: at 64 um pixels the noise along the line of sight at
55-70 deg incidence is about 1.8 times the model's (the pixel attenuates the
foreshortened fringe); at the paper's 8 um pixels it is 1.15 times, where the
decoder's sigma alone says 1.4 and over-predicted the sphere's PF by 40 %; the two-part
factor predicts PF within 4 % there (scans not among the acceptance runs). A cloud
without the two parts or the offset (a one-source reading, an older file) is scaled by
the decoder's sigma alone. ``oblique="modulation"`` scales by the modulation alone
(1 / B: an upper bound), ``"none"`` keeps the model's sigma.

Shared errors. The calibration table's own error (``sigma_calibration_um``, correlated over
``table_corr_mm``) shifts a ball as a whole: its standard uncertainty on a radius or a
centre coordinate is taken as the RMS sigma_calibration over sqrt(n_eff), n_eff the number of
correlation cells the ball's seen area covers (at least 1).

Noise correlation. Neighbouring points share noise (blur); the fits' covariances from
the per-point sigmas are scaled per parameter by a factor kappa >= 1 measured on the
artefact itself, as for gauge blocks (:func:`scanqa.qa.correlation.noise_correlation`):
the cluster-robust covariance with cubes of ``tile_mm`` as clusters over the one with
every point its own cluster; 1 when too few tiles hold 3 points.
"""

from __future__ import annotations

import math

import numpy as np

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud, random_sigma_name
from scanqa.qa.correlation import noise_correlation
from scanqa.qa.results import Options

#: Incidence within which a point counts as facing the scanner (oblique-sigma reference) [deg].
FRONTAL_DEG = 20.0


def incidence_cos(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """|cos| of the angle between each line of sight (from the origin) and the normal.

    Parameters
    ----------
    points : (n, 3) float
        Points in the scanner frame, the camera at the origin [mm].
    normals : (n, 3) float
        Their unit surface normals [-].

    Returns
    -------
    (n,) float
        |l_i . n_i| [-]; NaN for a point at the origin or a NaN input.

    Notes
    -----
    l_i = p_i / |p_i|, the unit line of sight; the incidence angle is acos |l_i . n_i|
    (module notes, docs/artefacts.rst).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        los = points / np.linalg.norm(points, axis=1, keepdims=True)
    return np.abs(np.sum(los * normals, axis=1))


def point_sigma(cloud: AnnotatedCloud, idx: np.ndarray, normals: np.ndarray,
                options: Options) -> np.ndarray | None:
    """Per-point sigma along the line of sight, scaled for oblique views (module notes)
    [mm]; None when the cloud has no ``sigma_model_um``.

    Notes
    -----
    sigma_i = 1e-3 sigma_model,i f_i [mm]: the model's sigma (Eqs. 18-19 of the paper)
    times the oblique-view factor f_i of :func:`oblique_factor` (module notes,
    docs/artefacts.rst).
    """
    attrs = cloud.attributes
    name = random_sigma_name(attrs)
    if name is None:
        return None
    sig = 1e-3 * np.asarray(attrs[name], float)[idx]
    bad = np.flatnonzero(np.isinf(sig) | (sig <= 0))
    if bad.size:
        raise InputError(f"the cloud's {name} holds {bad.size} values that are 0, negative "
                         f"or infinite on the artefact's points: a predicted sigma must be "
                         "> 0, or NaN where there is none (annotate the scan again)")
    if options.oblique == "none":
        return sig
    return sig * oblique_factor(cloud, idx, normals, options.oblique)


def oblique_factor(cloud: AnnotatedCloud, idx: np.ndarray, normals: np.ndarray,
                   how: str = "decoder") -> np.ndarray:
    """How much noisier each point is than where the artefact faces the scanner [-]
    (module notes); 1 where it cannot be formed.

    Parameters
    ----------
    cloud : AnnotatedCloud
        With ``sigma_phase_um`` and ``s_t_um_px`` ("decoder"; with ``offset_dn``,
        ``modulation_dn``, ``sigma_scene_um`` and ``sigma_sensor_um`` also the two-part
        form) or ``modulation_dn`` ("modulation"; also the fallback), and
        ``att_camera``, ``att_projector``.
    idx : (n,) int
        The artefact's points [-].
    normals : (n, 3) float
        Their unit surface normals [-].
    how : {"decoder", "modulation"}
        The decoder's phase-noise sigma (sensor part) and inverse contrast (scene part),
        or 1 / modulation.

    Notes
    -----
    f_i = sqrt(w_i f_scene,i^2 + (1 - w_i) f_sensor,i^2), w_i = s_scene,i^2 /
    (s_scene,i^2 + s_sensor,i^2), each part's factor its noise over its median on the points
    seen within 20 deg of their normal, with the defocus amplitude sqrt(A_c A_p) (Eq. 12 of
    the paper) divided out. scanqa's own model (module notes, docs/artefacts.rst).
    """
    attrs = cloud.attributes
    att = np.ones(idx.size)
    for name in ("att_camera", "att_projector"):
        if name in attrs:
            att = att * np.asarray(attrs[name], float)[idx]
    amp = np.sqrt(att)  # the model's fringe amplitude from defocus, divided out below

    def col(name: str) -> np.ndarray:
        return np.asarray(attrs[name], float)[idx]

    frontal = incidence_cos(cloud.xyz[idx], normals) >= math.cos(math.radians(FRONTAL_DEG))
    with np.errstate(invalid="ignore", divide="ignore"):
        if how == "decoder" and "sigma_phase_um" in attrs and "s_t_um_px" in attrs:
            sensor = _relative(col("sigma_phase_um") / col("s_t_um_px") * amp, frontal)
            if sensor is None:
                return np.ones(idx.size)
            parts = ("offset_dn", "modulation_dn", "sigma_scene_um", "sigma_sensor_um")
            if not all(k in attrs for k in parts):
                return sensor   # an older cloud: the decoder's sigma alone
            n2 = col("sigma_sensor_um") ** 2
            if not np.any(n2 > 0):
                return sensor   # a one-source reading: the decoder's sigma alone
            scene = _relative(col("offset_dn") / col("modulation_dn") * amp, frontal)
            if scene is None:
                return sensor
            s2 = col("sigma_scene_um") ** 2
            w = s2 / (s2 + n2)
            out = np.sqrt(w * scene**2 + (1.0 - w) * sensor**2)
            return np.where(np.isfinite(out), out, sensor)
        if "modulation_dn" in attrs:
            out = _relative(amp / col("modulation_dn"), frontal)
            return np.ones(idx.size) if out is None else out
    return np.ones(idx.size)


def _relative(noise: np.ndarray, frontal: np.ndarray) -> np.ndarray | None:
    """``noise`` over its median where the artefact faces the scanner (all points when
    fewer than 10 do); 1 where it is not finite and positive; None with < 10 usable."""
    ok = np.isfinite(noise) & (noise > 0)
    if ok.sum() < 10:
        return None
    front = ok & frontal
    ref = float(np.median(noise[front] if front.sum() >= 10 else noise[ok]))
    return np.where(ok, noise / ref, 1.0)


def table_uncertainty(cloud: AnnotatedCloud, idx: np.ndarray, area_mm2: float) -> float:
    """Standard uncertainty of an artefact's position from the table's own errors [mm]
    (module notes); 0 when the cloud does not carry them.

    Notes
    -----
    u = sqrt(mean sigma_calibration,i^2) / sqrt(n_eff), n_eff = max(1, area / l^2) with l the
    table's correlation length: the standard uncertainty of a mean of n_eff independent
    errors (GUM 4.2.3, Eq. 5); scanqa's model of the table's shared error (module notes,
    docs/artefacts.rst).
    """
    if not (math.isfinite(area_mm2) and area_mm2 >= 0):
        raise InputError(f"table uncertainty: the artefact's area must be finite and >= 0 "
                         f"mm^2, got {area_mm2!r}")
    if np.asarray(idx).size == 0:
        raise InputError("table uncertainty: the artefact has no points")
    attrs = cloud.attributes
    if "sigma_calibration_um" not in attrs:
        return 0.0
    tab = np.asarray(attrs["sigma_calibration_um"], float)[idx]
    if np.any(np.isinf(tab) | (tab < 0)):
        raise InputError("the cloud's sigma_calibration_um holds negative or infinite values: a "
                         "table sigma must be >= 0 um, or NaN where there is none (annotate "
                         "the scan again)")
    if not np.isfinite(tab).any():
        return 0.0
    rms = 1e-3 * float(np.sqrt(np.nanmean(tab**2)))
    corr = np.asarray(attrs.get("table_corr_mm", np.full(len(cloud), np.nan)), float)[idx]
    c = float(np.nanmedian(corr)) if np.isfinite(corr).any() else math.nan
    n_eff = max(1.0, area_mm2 / c**2) if math.isfinite(c) and c > 0 else 1.0
    return rms / math.sqrt(n_eff)


def tile_correlation(tile_mm: float):
    """A noise-correlation callable for :func:`scanqa.qa.sphere.fit_sphere`: kappa per
    parameter with cubes of ``tile_mm`` as clusters
    (:func:`scanqa.qa.correlation.noise_correlation`), 1 with too few tiles.

    Raises
    ------
    InputError
        A tile edge ``tile_mm`` that is not finite and > 0 [mm].

    Notes
    -----
    kappa_j as :func:`scanqa.qa.correlation.noise_correlation` (cluster-robust over
    heteroscedasticity-robust variance, Cameron and Miller (2015)) with cubes of
    ``tile_mm``; 1 where it cannot be measured.
    """
    if not (math.isfinite(tile_mm) and tile_mm > 0):
        raise InputError(f"noise correlation: the tile size must be finite and > 0 mm, "
                         f"got {tile_mm!r}")

    def kappa(points: np.ndarray, jac: np.ndarray, res: np.ndarray) -> np.ndarray:
        factor, _ = noise_correlation(jac, res, points, tile_mm)
        return np.where(np.isfinite(factor), factor, 1.0)
    return kappa
