"""The defocus uncertainty model of a phase-shift scanner (Sect. 3, Eqs. 1-19 of [1]_).

Every function is vectorised over numpy arrays and propagates NaN. Lengths are in
millimetres, fringe periods in projector pixels, phase noise in projector pixels.

The model in one line (Eq. 18/19)::

    sigma(Q) = s_T(Q) * sigma_p
               / (F_gamma(Z_c) * A(C_p(Z_p)/omega_o(Z_p)) * A(C_c(Z_c)/omega_o(Z_p)))

The paper leaves readings open; each is an explicit option (``filter_form``,
``filter_floor``, ``noise_reading``; docs/model.rst, "Readings"; the two-source model,
docs/noise_model.rst), a short function in a mapping of name to function in
:mod:`scanqa.model.readings`, whose public names this module re-exports. The chain is
written once, in :mod:`scanqa.model.equations`, for this module's arrays and the compiled
annotate loop; the characterisation fit selects the readings on held-out positions.

Validity: the paper calls the disc-kernel model valid for r = C / omega_o <= 1/2. Past
the first zero of J1 (r = 1.2197) the fringe contrast inverts. :func:`predict` flags
points with r > 1/2 as outside the model's validity and returns NaN past the first zero.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.special import j1

from scanqa.errors import RangeError
from scanqa.model import equations
from scanqa.model.config import ScannerConfig
from scanqa.model.equations import (  # noqa: F401 - re-exported: optics is the entry
    VALID_RATIO,
    airy_diameter,
    camera_blur_area,
    circle_of_confusion,
    diffraction_blur_area,
)
from scanqa.model.geometry import projector_depth, triangulation_scale
from scanqa.model.readings import (  # noqa: F401 - re-exported: optics is the entry
    FILTER_FLOOR_METHODS,
    FILTER_FORM_METHODS,
    NOISE_READING_METHODS,
    camera_noise_area,
    code,
    filter_factor,
    lookup,
    noise_scales,
    optical_scale,
    scales_by_code,
)

#: Eqs. 3 and 4 (:mod:`scanqa.model.equations`), silent where they give NaN (Z_p < 4 f_p).
projector_magnification = np.errstate(invalid="ignore")(equations.projector_magnification)
fringe_period_on_object = np.errstate(invalid="ignore")(equations.fringe_period_on_object)
#: First zero of J1(pi r): r = j_{1,1} / pi, where the fringe contrast inverts [-].
FIRST_ZERO_RATIO = 3.8317059702075125 / np.pi


def attenuation(r: ArrayLike) -> np.ndarray:
    """Attenuation of the sine wave by a disc blur kernel, A(r) (Eq. 12).

    Parameters
    ----------
    r : array_like
        Ratio of blur diameter to fringe period, r = c / p [-].

    Returns
    -------
    ndarray
        A(r) = (2 J1(pi r) / (pi r))^2 [-], with A(0) = 1.

    Notes
    -----
    A is the squared magnitude ratio. It reaches 0 at the first zero of J1,
    r = 1.2197 (:data:`FIRST_ZERO_RATIO`); past it the contrast is inverted and A
    rises again in side lobes. The paper's model is valid for r <= 1/2.

    Examples
    --------
    >>> float(attenuation(0.0))
    1.0
    >>> round(float(attenuation(0.5)), 4)
    0.5209
    """
    x = np.abs(np.asarray(r, dtype=float))
    x *= np.pi
    ratio = j1(x, out=np.empty_like(x))
    ratio *= 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio /= x
    ratio[x < 1e-8] = 1.0  # the limit; 1 - x^2 / 8 rounds to 1 there in float64
    return np.square(ratio, out=ratio)


def ratio_at_attenuation(level: float) -> float:
    """Inverse of :func:`attenuation` on its main lobe: the r with A(r) = level.

    Parameters
    ----------
    level : float
        Attenuation level a, 0 < a <= 1 [-].

    Returns
    -------
    float
        r in [0, 1.2197) [-].
    """
    if not 0.0 < level <= 1.0:
        raise RangeError(f"attenuation level must be in (0, 1], got {level!r}")
    if level == 1.0:
        return 0.0
    return float(brentq(lambda r: attenuation(r) - level, 0.0, FIRST_ZERO_RATIO, xtol=1e-14))


def image_blur_diameter(z_c: ArrayLike, focal: float, focus: float, aperture: float
                        ) -> np.ndarray:
    """Diameter of the circle of confusion in the camera image, c_c (Eq. 14).

    Parameters
    ----------
    z_c : array_like
        Object distance Z_c [mm].
    focal, focus, aperture : float
        Camera focal length f_c, focus distance Z_c' and aperture Phi_c [mm].

    Returns
    -------
    ndarray
        c_c = f_c / (Z_c - f_c) * C_c(Z_c) [mm]; NaN at or before the lens (Z_c <= f_c).
    """
    z_c = np.asarray(z_c, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):  # no image there
        blur = equations.image_blur(z_c, focal, circle_of_confusion(z_c, focus, aperture))
    return np.where(z_c > focal, blur, np.nan)


@dataclass(frozen=True)
class OpticalTerms:
    """The depth-dependent part of the model (Eqs. 1-4, 12-17, 19): arrays of one shape.

    Lengths in mm, ratios and factors dimensionless. ``s_o`` is NaN past the first zero
    of J1 (the fringe contrast inverts there). ``s_o_scene`` and ``s_o_sensor`` are its
    scene-side and sensor parts (:func:`noise_scales`; the sensor part is 0 but for
    the two-source reading), s_o^2 = s_o_scene^2 + s_o_sensor^2 for "two_source";
    ``record`` holds the config's numbers and readings they were computed with.
    """

    z_c: np.ndarray
    z_p: np.ndarray
    omega_o: np.ndarray
    ratio_camera: np.ndarray
    ratio_projector: np.ndarray
    attenuation_camera: np.ndarray
    attenuation_projector: np.ndarray
    blur_area_camera: np.ndarray
    filter_factor: np.ndarray
    s_o: np.ndarray
    filter_floor: str
    noise_reading: str
    filter_form: str = "product"
    s_o_scene: np.ndarray | None = None
    s_o_sensor: np.ndarray | None = None
    filter_base: np.ndarray | None = None
    object_scale: np.ndarray | None = None
    record: equations.ModelRecord | None = None

    @property
    def within_validity(self) -> np.ndarray:
        """Both blur ratios within the paper's validity r <= 1/2."""
        return (self.ratio_camera <= VALID_RATIO) & (self.ratio_projector <= VALID_RATIO)

    def s_o_with(self, gamma: float, filter_floor: str, noise_reading: str,
                 sensor_ratio: float = 0.0) -> np.ndarray:
        """s_O at the same points for another gamma, floor or reading [-].

        F_gamma = F_1 / gamma in both forms of Eq. 17 (``filter_base`` is F_1, the factor
        for gamma = 1 without the floor), so a fit over gamma need not re-run the optics;
        the smooth floor's gamma is scaled to each range (:func:`correlation_gamma`).
        """
        scale = 1.0 if filter_floor != "smooth" or self.object_scale is None \
            else self.object_scale
        f = lookup(FILTER_FLOOR_METHODS, filter_floor, "floor")(
            self.filter_base / (gamma * scale))
        s_o = optical_scale(f, self.attenuation_projector, self.attenuation_camera,
                            noise_reading, sensor_ratio)
        beyond = (self.ratio_camera >= FIRST_ZERO_RATIO) | \
            (self.ratio_projector >= FIRST_ZERO_RATIO)
        return np.where(beyond, np.nan, s_o)


def correlation_gamma(gamma: float, z_c: ArrayLike, config: ScannerConfig,
                      filter_floor: str) -> np.ndarray:
    """The noise correlation gamma at range ``z_c`` [camera px].

    Parameters
    ----------
    gamma : float
        ``[model] gamma``: with the smooth floor, the side of the scene noise's
        correlation cell at the camera's focus distance [px]; otherwise the paper's
        constant gamma [-].
    z_c : array_like
        Distance along the camera axis [mm].
    config : ScannerConfig
        Its ``camera.focus_mm``.
    filter_floor : str
        ``"smooth"`` scales gamma; the paper's forms keep it constant.

    Returns
    -------
    ndarray
        gamma focus / Z_c for the smooth floor, else gamma, broadcast to ``z_c``.

    Notes
    -----
    Scene-side noise is fixed on the object, so its cells cover Z_focus / Z_c as many
    camera pixels at Z_c as at focus (the pixel's footprint is Z / f). The paper's gamma
    (Eq. 17) is one number; the smooth floor, already a departure
    (:func:`scanqa.model.readings.smooth_floor`), follows the range (docs/flattening.rst).
    """
    z = np.asarray(z_c, dtype=float)
    floor = code(FILTER_FLOOR_METHODS, filter_floor, "floor")
    return equations.range_gamma(float(gamma), config.camera.focus_mm, z, floor) + np.zeros(z.shape)


def optical_terms(z_c: ArrayLike, z_p: ArrayLike, config: ScannerConfig,
                  period_px: float | None = None, gamma: float | None = None,
                  filter_floor: str | None = None, noise_reading: str | None = None,
                  filter_form: str | None = None, sensor_ratio: float | None = None,
                  sigma_p: float | None = None) -> OpticalTerms:
    """The model chain from the distances to the camera and the projector to s_O.

    This is the one implementation of Eqs. 1-4 and 12-19 (without s_T): prediction
    (:func:`predict`), characterisation and the design tools all call it.

    Parameters
    ----------
    z_c : array_like
        Distance of the points along the camera axis, Z_c [mm].
    z_p : array_like
        Distance along the projector axis, Z_p [mm].
    config : ScannerConfig
        Optics and the model's parameters and readings.
    period_px : float, optional
        Fringe period [projector px]; default the config's working (finest) period.
    gamma : float, optional
        Noise correlation gamma [-]; default ``config.model.gamma``.
    filter_floor, noise_reading, filter_form : str, optional
        Override the config's readings (module notes).
    sensor_ratio : float, optional
        Sensor over scene-side phase noise at focus [-]; default
        ``sensor_sigma_p_px / sigma_p`` of the config (two-source reading only).
    sigma_p : float, optional
        Scene-side phase noise at focus [projector px]; default the config's.

    Returns
    -------
    OpticalTerms
        Every intermediate quantity, broadcast to one shape.
    """
    m = equations.model_record(config, period_px, gamma, filter_floor, noise_reading, filter_form,
                     sensor_ratio, sigma_p)
    z_c, z_p = np.broadcast_arrays(np.asarray(z_c, dtype=float), np.asarray(z_p, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        omega_o, _, r_c, r_p = equations.blur_ratios(z_c, z_p, m)
        a_c, a_p = attenuation(r_c), attenuation(r_p)
        c_image = image_blur_diameter(z_c, m.cam_focal_mm, m.cam_focus_mm, m.cam_aperture_mm)
        b_c, base, f_gamma = equations.filter_factors(z_c, c_image, m)
        scene, sensor = scales_by_code(f_gamma, a_p, a_c, m.reading, m.sensor_ratio)
    beyond = (r_c >= FIRST_ZERO_RATIO) | (r_p >= FIRST_ZERO_RATIO)
    scene, sensor = np.where(beyond, np.nan, scene), np.where(beyond, np.nan, sensor)
    return OpticalTerms(z_c, z_p, omega_o, r_c, r_p, a_c, a_p, b_c, f_gamma,
                        equations.optical_scale_of(scene, sensor, m),
                        list(FILTER_FLOOR_METHODS)[m.floor], list(NOISE_READING_METHODS)[m.reading],
                        list(FILTER_FORM_METHODS)[m.form], scene, sensor, base,
                        m.cam_focus_mm / z_c, m)


@dataclass(frozen=True, kw_only=True)
class Prediction(OpticalTerms):
    """The model's terms (:class:`OpticalTerms`) and sigma for a set of points.

    ``s_t`` [mm / px] and ``sigma`` [mm] have the terms' shape. ``valid`` is False where a
    blur ratio exceeds 1/2 (outside the paper's validity); ``sigma`` is NaN past the
    first zero of J1 and for NaN input. ``sigma_scene`` and ``sigma_sensor`` are its
    scene-side and sensor parts [mm] (the sensor part is 0 but for "two_source").
    """

    s_t: np.ndarray
    sigma: np.ndarray
    valid: np.ndarray
    sigma_scene: np.ndarray
    sigma_sensor: np.ndarray

    @property
    def sigma_trusted(self) -> np.ndarray:
        """``sigma`` where the model is valid, NaN elsewhere [mm]."""
        return np.where(self.valid, self.sigma, np.nan)


def predict(points: ArrayLike, config: ScannerConfig, period_px: float | None = None,
            s_t: ArrayLike | None = None, sigma_p: float | None = None,
            filter_floor: str | None = None, noise_reading: str | None = None) -> Prediction:
    """Predicted standard deviation sigma(Q) of points (Eqs. 1-19).

    Parameters
    ----------
    points : (..., 3) array_like
        Points in the scanner (camera) frame [mm].
    config : ScannerConfig
        Scanner config (optics, poses, model parameters and readings).
    period_px : float, optional
        Fringe period [projector px]; default the config's working (finest) period.
    s_t : array_like, optional
        Triangulation scale |dQ/dx_p| [mm / px], e.g. from a calibration table's slope;
        default from the config geometry
        (:func:`~scanqa.model.geometry.triangulation_scale`).
    sigma_p : float, optional
        Scene-side phase noise at focus [projector px]; default
        ``config.model.sigma_p_px`` (the sensor's, ``sensor_sigma_p_px``, is kept).
    filter_floor, noise_reading : str, optional
        Override the config's readings (see module notes).

    Returns
    -------
    Prediction
        sigma along the line of sight [mm] and every intermediate quantity.
    """
    q = np.asarray(points, dtype=float)
    t = optical_terms(q[..., 2], projector_depth(q, config), config, period_px,
                      filter_floor=filter_floor, noise_reading=noise_reading, sigma_p=sigma_p)
    s_t = triangulation_scale(q, config) if s_t is None else np.asarray(s_t, dtype=float)
    sigma, scene, sensor, valid = equations.point_sigma(s_t, t.s_o, t.s_o_scene, t.s_o_sensor,
                                              t.ratio_camera, t.ratio_projector, t.record)
    return Prediction(**vars(t), s_t=np.broadcast_to(s_t, np.shape(sigma)), sigma=sigma,
                      valid=valid, sigma_scene=scene, sigma_sensor=sensor)
