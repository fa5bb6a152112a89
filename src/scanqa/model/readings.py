"""The model's readings of Eqs. 17 and 19 of [1]_, one mapping of name to function each.

The paper leaves open how the camera blur filters the noise (Eq. 17) and how the
attenuation enters the scale factor s_O (Eq. 19); docs/model.rst ("Readings") and
docs/noise_model.rst give the choices. Each choice is a short function citing its
equation, looked up once by name in a mapping, as colour's ``DELTA_E_METHODS`` does:

* :data:`FILTER_FORM_METHODS` - how F_gamma is formed from the blur areas (Eq. 17);
* :data:`FILTER_FLOOR_METHODS` - whether F_gamma is clamped to >= 1 (Eq. 17's bound);
* :data:`NOISE_READING_METHODS` - how the attenuations divide the noise (Eq. 19).

The names are those a config accepts (:data:`scanqa.model.config.FILTER_FORMS`,
:data:`~scanqa.model.config.FILTER_FLOORS`, :data:`~scanqa.model.config.NOISE_READINGS`);
an unknown name raises :class:`~scanqa.errors.MethodError` listing the known ones.
:mod:`scanqa.model.optics` re-exports every public name here.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from scanqa.compiled import jitable
from scanqa.errors import MethodError

#: Codes of the readings in compiled code (:class:`scanqa.model.equations.ModelRecord`):
#: each name's place in its mapping below (:func:`code`).
PRODUCT, SUM = 0, 1
UNCLAMPED, CLAMPED, SMOOTH = 0, 1, 2
POWER, AMPLITUDE, MIXED, TWO_SOURCE = 0, 1, 2, 3


def method_names(methods: Mapping[str, Callable]) -> str:
    """The names of a method mapping as prose: "'a', 'b' or 'c'"."""
    names = [repr(n) for n in methods]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]


def lookup(methods: Mapping[str, Callable], name: str, what: str) -> Callable:
    """The function a method mapping holds under ``name``.

    Parameters
    ----------
    methods : mapping of str to callable
        One of this module's ``*_METHODS`` mappings.
    name : str
        The method's name, as a config gives it.
    what : str
        The option's name for the message ("form", "floor", "reading").

    Returns
    -------
    callable
        ``methods[name]``.

    Raises
    ------
    MethodError
        For a name the mapping does not hold; the message lists every name it holds.
    """
    if isinstance(name, str) and name in methods:
        return methods[name]
    raise MethodError(f"{what} must be {method_names(methods)}, got {name!r}")


def code(methods: Mapping[str, Callable], name: str, what: str) -> int:
    """The code of ``name`` in compiled code: its place in ``methods`` (:func:`lookup`)."""
    lookup(methods, name, what)
    return list(methods).index(name)


@jitable
def camera_noise_area(c_image: ArrayLike, pixel: float, b_d: float) -> np.ndarray:
    """Noise-equivalent area of the camera's kernel: pixel, defocus disc and Airy disc.

    Parameters
    ----------
    c_image : array_like
        Image-side blur diameter c_c (Eq. 14) [mm].
    pixel : float
        Camera pixel size s_c [mm].
    b_d : float
        Diffraction blur area (Eq. 16) [px^2].

    Returns
    -------
    ndarray
        1 + pi (c_c / (2 s_c))^2 + b_d [px^2]: the areas add because the second moments
        of convolved kernels do (docs/noise_model.rst); the pixel counts as its area, 1.

    Examples
    --------
    >>> float(camera_noise_area(0.0, 0.008, 1.0))
    2.0
    """
    return 1.0 + blur_area(c_image, pixel) + b_d


@jitable
def blur_area(c_image: ArrayLike, pixel: float) -> np.ndarray:
    """pi (c_c / (2 s_c))^2, the area of the image blur c_c [mm] on pixels of s_c [mm],
    Eq. 13 without its floor [px^2]."""
    return np.pi * np.divide(c_image, 2.0 * pixel) ** 2


@jitable
def product_filter(b_c: np.ndarray, b_d: float, gamma: float) -> np.ndarray:
    """F_gamma = sqrt(b_c b_d) / gamma, Eq. 17 of the paper as printed [-].

    ``b_c`` is the camera blur area of Eq. 13 [px^2], ``b_d`` the diffraction blur area
    of Eq. 16 [px^2], ``gamma`` the noise correlation [-].
    """
    return np.sqrt(b_c * b_d) / gamma


@jitable
def sum_filter(b_c: np.ndarray, b_d: float, gamma: float) -> np.ndarray:
    """F_gamma = sqrt(1 + b_disc + b_d) / gamma, Eq. 17 with the areas added [-].

    ``b_c`` is already the noise-equivalent area 1 + b_disc + b_d
    (:func:`camera_noise_area`, docs/noise_model.rst) [px^2], so ``b_d`` is not used
    again [px^2]; ``gamma`` is the noise correlation [-].
    """
    return np.sqrt(b_c) / gamma


@jitable
def unclamped(f: np.ndarray) -> np.ndarray:
    """F_gamma as Eq. 17 of the paper prints it: no floor, F may be < 1 [-]."""
    return f


@jitable
def clamped_at_one(f: np.ndarray) -> np.ndarray:
    """F_gamma >= 1: the bound 1 <= gamma <= sqrt(b_c b_d) stated under Eq. 17 [-].

    Filtering never amplifies noise; NaN stays NaN.
    """
    return np.maximum(f, 1.0)


@jitable
def smooth_floor(f: np.ndarray) -> np.ndarray:
    """F_gamma^2 = 1 + F^2: noise correlated over gamma^2 px^2, filtered by a kernel [-].

    With the sum form, F^2 = N / gamma^2 for a kernel of noise-equivalent area N [px^2]
    (:func:`camera_noise_area`), so 1 / F_gamma^2 = gamma^2 / (gamma^2 + N): the share of
    the variance of noise constant over cells of area gamma^2 that survives averaging
    over N, the Gaussian form in which second moments of convolved kernels add. It is
    the smooth curve that ``"one"`` (max(1, F)) bends at F = 1, and the law by which
    flattening's digital filter reduces the scene noise
    (:func:`scanqa.annotation.filterbank.reduction`), so model and filter are one law. A
    departure from the paper, whose bound under Eq. 17 only says F >= 1. NaN stays NaN.

    Examples
    --------
    >>> float(smooth_floor(np.array(0.0))), round(float(smooth_floor(np.array(1.0))), 4)
    (1.0, 1.4142)
    """
    return np.sqrt(1.0 + np.square(f))


#: How F_gamma is formed from the blur areas (Eq. 17): name -> f(b_c, b_d, gamma).
FILTER_FORM_METHODS: dict[str, Callable] = {"product": product_filter, "sum": sum_filter}
#: Whether F_gamma is clamped (Eq. 17's bound): name -> f(F).
FILTER_FLOOR_METHODS: dict[str, Callable] = {"none": unclamped, "one": clamped_at_one,
                                               "smooth": smooth_floor}


def filter_factor(b_c: ArrayLike, b_d: float, gamma: float, floor: str = "none",
                  form: str = "product") -> np.ndarray:
    """Noise reduction by camera blur and diffraction, F_gamma (Eq. 17).

    Parameters
    ----------
    b_c : array_like
        "product": camera blur area b_c (Eq. 13); "sum": the kernel's noise-equivalent
        area (:func:`camera_noise_area`, which already holds b_d) [px^2].
    b_d : float
        Diffraction blur area [px^2].
    gamma : float
        Spatial correlation of the noise, >= 1 [-].
    floor : {"none", "one", "smooth"}
        "none": Eq. 17 as printed (F may be < 1); "one": F clamped to >= 1; "smooth":
        F^2 + 1, the smooth curve "one" bends (:data:`FILTER_FLOOR_METHODS`).
    form : {"product", "sum"}
        "product": F = sqrt(b_c b_d) / gamma, Eq. 17 as printed; "sum":
        F = sqrt(b_c) / gamma with b_c the noise-equivalent area
        (:data:`FILTER_FORM_METHODS`).

    Returns
    -------
    ndarray
        F_gamma [-].
    """
    return filter_by_code(np.asarray(b_c, dtype=float), b_d, gamma,
                          code(FILTER_FORM_METHODS, form, "form"),
                          code(FILTER_FLOOR_METHODS, floor, "floor"))


@jitable
def filter_by_code(area: ArrayLike, b_d: float, gamma: ArrayLike, form: int, floor: int
                   ) -> np.ndarray:
    """:func:`filter_factor` by the codes of its form and floor (:func:`code`) [-]."""
    f = product_filter(area, b_d, gamma) if form == PRODUCT else sum_filter(area, b_d, gamma)
    if floor == CLAMPED:
        return clamped_at_one(f)
    return smooth_floor(f) if floor == SMOOTH else f


@jitable
def power_reading(f_gamma: np.ndarray, a_p: np.ndarray, a_c: np.ndarray,
                  sensor_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """s_O = 1 / (F_gamma A_p A_c), Eq. 19 of the paper as printed; no sensor part [-].

    A is the squared magnitude ratio of Eq. 12, so this divides the noise by the power
    of the fringe, not its amplitude. ``sensor_ratio`` is not used.
    """
    scene = 1.0 / (f_gamma * (a_p * a_c))
    return scene, 0.0


@jitable
def amplitude_reading(f_gamma: np.ndarray, a_p: np.ndarray, a_c: np.ndarray,
                      sensor_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """s_O = 1 / (F_gamma sqrt(A_p A_c)): Eq. 19 with the fringe amplitude [-].

    Additive intensity noise divides by the amplitude ratio sqrt(A) of Eq. 12
    (docs/model.rst, reading (ii)). ``sensor_ratio`` is not used.
    """
    scene = 1.0 / (f_gamma * np.sqrt(a_p * a_c))
    return scene, 0.0


@jitable
def mixed_reading(f_gamma: np.ndarray, a_p: np.ndarray, a_c: np.ndarray,
                  sensor_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """s_O = 1 / (F_gamma sqrt(A_p) A_c): Eq. 19, amplitude for the projector [-].

    docs/model.rst, reading (ii). ``sensor_ratio`` is not used.
    """
    scene = 1.0 / (f_gamma * (np.sqrt(a_p) * a_c))
    return scene, 0.0


@jitable
def two_source_reading(f_gamma: np.ndarray, a_p: np.ndarray, a_c: np.ndarray,
                       sensor_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """The two-source model: s_O^2 = (1 / F_gamma^2 + rho^2) / (A_p A_c) [-].

    Scene-side noise filtered by the camera blur (Eq. 17) and sensor noise that the blur
    does not filter, both additive in intensity and so both divided by the fringe
    amplitude sqrt(A_p A_c) of Eq. 12 (docs/noise_model.rst). Returns the scene part
    1 / (F sqrt(A_p A_c)) and the sensor part rho / sqrt(A_p A_c), rho =
    ``sensor_ratio``; the sensor part is 0 for rho <= 0.
    """
    a = np.sqrt(a_p * a_c)
    scene = 1.0 / (f_gamma * a)
    return scene, sensor_ratio / a if sensor_ratio > 0 else 0.0


#: How the attenuations enter s_O (Eq. 19): name -> f(F, A_p, A_c, rho) returning the
#: scene-side and sensor parts; the paper's readings first, then the two-source model.
NOISE_READING_METHODS: dict[str, Callable] = {
    "power": power_reading, "amplitude": amplitude_reading, "mixed": mixed_reading,
    "two_source": two_source_reading}


def noise_scales(f_gamma: ArrayLike, a_p: ArrayLike, a_c: ArrayLike,
                 reading: str = "power", sensor_ratio: float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The scene-side and sensor parts of s_O, relative to sigma_p [-].

    Parameters are those of :func:`optical_scale`. The paper's readings have no sensor
    part (zeros); for "two_source" s_O = sqrt(scene^2 + sensor^2).

    Returns
    -------
    scene, sensor : ndarray
        1 / (F a) with a the reading's attenuation, and rho / sqrt(A_p A_c) [-]
        (:data:`NOISE_READING_METHODS`).
    """
    reading = code(NOISE_READING_METHODS, reading, "reading")
    a_p, a_c = np.asarray(a_p, dtype=float), np.asarray(a_c, dtype=float)
    with np.errstate(divide="ignore"):
        scene, sensor = scales_by_code(np.asarray(f_gamma, dtype=float), a_p, a_c, reading,
                                       sensor_ratio)
    return scene, sensor + np.zeros_like(scene)


@jitable
def scales_by_code(f_gamma: ArrayLike, a_p: ArrayLike, a_c: ArrayLike, reading: int,
                   sensor_ratio: float) -> tuple:
    """:func:`noise_scales` by the code of its reading (:func:`code`) [-]."""
    if reading == POWER:
        return power_reading(f_gamma, a_p, a_c, sensor_ratio)
    if reading == AMPLITUDE:
        return amplitude_reading(f_gamma, a_p, a_c, sensor_ratio)
    if reading == MIXED:
        return mixed_reading(f_gamma, a_p, a_c, sensor_ratio)
    return two_source_reading(f_gamma, a_p, a_c, sensor_ratio)


def optical_scale(f_gamma: ArrayLike, a_p: ArrayLike, a_c: ArrayLike,
                  reading: str = "power", sensor_ratio: float = 0.0) -> np.ndarray:
    """The optically induced blurring scale factor, s_O (Eq. 19).

    Parameters
    ----------
    f_gamma : array_like
        Filter factor F_gamma [-].
    a_p, a_c : array_like
        Projector and camera attenuation A [-].
    reading : {"power", "amplitude", "mixed", "two_source"}
        "power": 1 / (F A_p A_c) as printed; "amplitude": 1 / (F sqrt(A_p A_c));
        "mixed": 1 / (F sqrt(A_p) A_c); "two_source":
        sqrt(1 / F^2 + rho^2) / sqrt(A_p A_c) (docs/noise_model.rst).
    sensor_ratio : float
        rho, the sensor's phase noise over the scene-side one at focus
        (``sensor_sigma_p_px / sigma_p_px``); "two_source" only [-].

    Returns
    -------
    ndarray
        s_O [-]; inf where an attenuation is 0.
    """
    scene, sensor = noise_scales(f_gamma, a_p, a_c, reading, sensor_ratio)
    return np.sqrt(scene**2 + sensor**2) if reading == "two_source" else scene
