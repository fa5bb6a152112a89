"""The model's chain at one point (Eqs. 1-4, 13-19 of [1]_), written once for two callers.

Each function is an equation or a step of the chain made of arithmetic and numpy ufuncs
only: :func:`scanqa.model.optics.optical_terms` runs it on arrays, and numba compiles it
into the annotate loop (``scanqa.annotation.kernels``), which calls it per point
(:func:`scanqa.compiled.jitable`); the config reaches both as one :class:`ModelRecord`.
The callers differ in what selects values (NaN past the first zero of J1 or before the
camera lens: ``np.where`` on arrays, ``if`` per point) and in J1 (scipy's on arrays, a
series per point); ``tests/test_annotkernels.py`` holds them together.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from scanqa.compiled import jitable
from scanqa.model import readings
from scanqa.model.config import ScannerConfig

#: Validity limit of the disc-kernel model, r = C / omega_o (Sect. 3.1 of [1]) [-].
VALID_RATIO = 0.5


class ModelRecord(NamedTuple):
    """The config's numbers and readings as the chain reads them (:func:`model_record`).

    Lengths in mm: the fringe period [projector px] and the projector's pitch, focus,
    focal length and aperture; the camera's focus, aperture, focal length and pixel;
    ``b_d`` (Eq. 16) [px^2]; ``gamma``, ``sensor_ratio`` [-] and ``sigma_p_px``
    [projector px]; the readings' codes (:func:`scanqa.model.readings.code`).
    """

    period_px: float
    pitch_mm: float
    proj_focus_mm: float
    proj_focal_mm: float
    proj_aperture_mm: float
    cam_focus_mm: float
    cam_aperture_mm: float
    cam_focal_mm: float
    pixel_mm: float
    b_d: float
    gamma: float
    sensor_ratio: float
    sigma_p_px: float
    form: int
    floor: int
    reading: int


def model_record(config: ScannerConfig, period_px: float | None = None,
                 gamma: float | None = None, filter_floor: str | None = None,
                 noise_reading: str | None = None, filter_form: str | None = None,
                 sensor_ratio: float | None = None, sigma_p: float | None = None
                 ) -> ModelRecord:
    """The :class:`ModelRecord` of ``config``, with the arguments given overriding it.

    Parameters are those of :func:`scanqa.model.optics.optical_terms` and ``sigma_p``
    [projector px] (default ``config.model.sigma_p_px``). Every number is a Python
    float and every code an int, so that compiled code sees one type.
    """
    cam, proj, model = config.camera, config.projector, config.model
    sp = model.sigma_p_px if sigma_p is None else sigma_p
    pixel = cam.pixel_um * 1e-3
    return ModelRecord(*(float(v) for v in (
        config.fringes.working_period_px if period_px is None else period_px,
        proj.pitch_um * 1e-3, proj.focus_mm, proj.focal_mm, proj.aperture_mm,
        cam.focus_mm, cam.aperture_mm, cam.focal_mm, pixel,
        diffraction_blur_area(airy_diameter(model.wavelength_nm * 1e-6, cam.f_number), pixel),
        model.gamma if gamma is None else gamma,
        model.sensor_sigma_p_px / sp if sensor_ratio is None else sensor_ratio, sp)),
        *(readings.code(methods, default if given is None else given, what)
          for methods, given, default, what in (
              (readings.FILTER_FORM_METHODS, filter_form, model.filter_form, "form"),
              (readings.FILTER_FLOOR_METHODS, filter_floor, model.filter_floor, "floor"),
              (readings.NOISE_READING_METHODS, noise_reading, model.noise_reading, "reading"))))


@jitable
def circle_of_confusion(z: ArrayLike, focus: float, aperture: float) -> np.ndarray:
    """C(Z) = Phi |Z - Z'| / Z', the circle of confusion in the object plane (Eqs. 1, 2)
    [mm], at the distance ``z`` from the lens, Z_c or Z_p [mm], with the on-focus distance
    ``focus`` Z' [mm] and the aperture diameter ``aperture`` Phi = f / N [mm].

    >>> float(circle_of_confusion(460.0, 450.0, 12.5))
    0.2777777777777778
    """
    return aperture * np.abs(np.subtract(z, focus)) / focus


@jitable
def projector_magnification(z_p: ArrayLike, focus: float, focal: float) -> np.ndarray:
    """m_p = 2 f_p / (Z_p' - 2 f_p + sqrt(Z_p (Z_p - 4 f_p))), the projector's magnification
    (Eq. 3, as printed) [-], at the distance ``z_p`` Z_p from the projector lens, with the
    on-focus distance ``focus`` Z_p' and focal length ``focal`` f_p [mm]; NaN where
    Z_p < 4 f_p (the square root is undefined).

    Notes
    -----
    Eq. 3 is the thin-lens magnification written for a total object-image distance; the
    paper applies it with Z_p as the object distance and so does this function, so that
    the paper's tables are reproduced. It differs from the pinhole magnification of the
    geometry (:attr:`ProjectorConfig.principal_distance_px`) by a few percent.
    """
    root = np.sqrt(np.multiply(z_p, np.subtract(z_p, 4.0 * focal)))
    return 2.0 * focal / (focus - 2.0 * focal + root)


@jitable
def fringe_period_on_object(z_p: ArrayLike, period_px: float, pitch_mm: float,
                            focus: float, focal: float) -> np.ndarray:
    """omega_o = omega pitch / m_p(Z_p), the period of the projected sine wave on the
    object (Eq. 4) [mm], at the distance ``z_p`` from the projector lens [mm], for the
    period ``period_px`` [projector px], the pixel pitch ``pitch_mm``, the on-focus
    distance ``focus`` and focal length ``focal`` (:func:`projector_magnification`) [mm].
    """
    return period_px * pitch_mm / projector_magnification(z_p, focus, focal)


@jitable
def image_blur(z_c: ArrayLike, focal: float, coc: ArrayLike) -> np.ndarray:
    """c_c = f_c / (Z_c - f_c) C_c (Eq. 14) [mm], from the object-side circle C_c [mm];
    finite but meaningless for Z_c <= f_c [mm], where callers put NaN
    (:func:`scanqa.model.optics.image_blur_diameter`)."""
    return focal / (z_c - focal) * coc


@jitable
def camera_blur_area(c_image: ArrayLike, pixel: float) -> np.ndarray:
    """b_c = max(pi (c_c / (2 s_c))^2, 1), the camera-induced blur area in pixel units
    (Eq. 13) [px^2], for the image-side blur diameter ``c_image`` c_c [mm] and the camera
    pixel ``pixel`` s_c [mm]; NaN stays NaN."""
    return np.maximum(readings.blur_area(c_image, pixel), 1.0)


def airy_diameter(wavelength: float, f_number: float) -> float:
    """d_c = 2 * 1.22 * lambda * N, the Airy disc's diameter in the camera image (Eq. 15)
    [mm], for the wavelength lambda [mm] (the paper's 450 um is a typo for 450 nm) and
    the camera's f-number N [-].

    >>> round(airy_diameter(450e-6, 8.0) * 1e3, 4)
    8.784
    """
    return 2.0 * 1.22 * wavelength * f_number


def diffraction_blur_area(airy: float, pixel: float) -> float:
    """Area of the diffraction blur in pixel units, b_d = pi (d_c / (2 s_c))^2 (Eq. 16),
    for the Airy disc's diameter ``airy`` and the camera pixel ``pixel`` [mm] [px^2]."""
    return float(np.pi * (airy / (2.0 * pixel)) ** 2)


@jitable
def blur_ratios(z_c: ArrayLike, z_p: ArrayLike, m: ModelRecord) -> tuple:
    """omega_o (Eq. 4), C_c (Eq. 1) [mm] and the blur ratios r_c = C_c / omega_o and
    r_p = C_p / omega_o [-] at the distances Z_c, Z_p [mm]."""
    omega_o = fringe_period_on_object(z_p, m.period_px, m.pitch_mm, m.proj_focus_mm,
                                      m.proj_focal_mm)
    coc_c = circle_of_confusion(z_c, m.cam_focus_mm, m.cam_aperture_mm)
    r_p = circle_of_confusion(z_p, m.proj_focus_mm, m.proj_aperture_mm) / omega_o
    return omega_o, coc_c, coc_c / omega_o, r_p


@jitable
def filter_factors(z_c: ArrayLike, c_image: ArrayLike, m: ModelRecord) -> tuple:
    """b_c (Eq. 13) [px^2], F_1 (gamma 1, no floor) and F_gamma (Eq. 17, the record's
    form and floor, gamma at range Z_c [mm]) [-], from the image blur c_c [mm]."""
    b_c = camera_blur_area(c_image, m.pixel_mm)
    area = b_c if m.form == readings.PRODUCT else \
        readings.camera_noise_area(c_image, m.pixel_mm, m.b_d)
    gamma = range_gamma(m.gamma, m.cam_focus_mm, z_c, m.floor)
    return (b_c, readings.filter_by_code(area, m.b_d, 1.0, m.form, readings.UNCLAMPED),
            readings.filter_by_code(area, m.b_d, gamma, m.form, m.floor))


@jitable
def range_gamma(gamma: float, focus: float, z_c: ArrayLike, floor: int) -> np.ndarray:
    """gamma focus / Z_c with the smooth floor, else gamma [px]; focus and Z_c [mm]
    (:func:`scanqa.model.optics.correlation_gamma`)."""
    return gamma * focus / z_c if floor == readings.SMOOTH else gamma


@jitable
def optical_scale_of(scene: ArrayLike, sensor: ArrayLike, m: ModelRecord) -> np.ndarray:
    """s_O (Eq. 19) [-] from its scene-side and sensor parts [-]: their root sum of
    squares for the two-source reading, else the scene part."""
    return np.hypot(scene, sensor) if m.reading == readings.TWO_SOURCE else scene


@jitable
def point_sigma(s_t: ArrayLike, s_o: ArrayLike, scene: ArrayLike, sensor: ArrayLike,
                r_c: ArrayLike, r_p: ArrayLike, m: ModelRecord) -> tuple:
    """sigma = s_T s_O sigma_p (Eq. 18) with its scene and sensor parts [mm], from s_T
    [mm / px] and s_O and its parts [-]; valid where both blur ratios are within the
    paper's validity (:data:`VALID_RATIO`) and sigma is finite."""
    sigma = s_t * s_o * m.sigma_p_px
    valid = (r_c <= VALID_RATIO) & (r_p <= VALID_RATIO) & np.isfinite(sigma)
    return sigma, s_t * scene * m.sigma_p_px, s_t * sensor * m.sigma_p_px, valid
