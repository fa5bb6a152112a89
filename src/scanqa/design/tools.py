"""Design tools built on the defocus model: depth of field, the W curve, the usable
volume (Sect. 5.1) and the range-dependent filter that flattens the curve (Sect. 5.2).

All lengths in mm; the depth of field is the length of the interval around focus where
the attenuation stays at or above a level (Tables 1 and 2 of the paper).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from scanqa.errors import InputError, RangeError
from scanqa.model import geometry, optics
from scanqa.model.config import ScannerConfig
from scanqa.numeric import inclusive_range

#: The ten attenuation levels of Tables 1 and 2 [-].
TABLE_LEVELS = (0.25, 0.30, 0.36, 0.42, 0.49, 0.56, 0.64, 0.72, 0.81, 0.90)


@dataclass(frozen=True)
class DepthOfField:
    """Depth of field of one device at one attenuation level and period.

    ``near_mm``/``far_mm`` are the interval ends along the device's optical axis [mm];
    ``model_valid`` is False when the level needs a blur ratio above 1/2, outside the
    range the paper validates the disc model for.
    """

    device: str
    level: float
    period_px: float
    near_mm: float
    far_mm: float
    ratio: float

    @property
    def dof_mm(self) -> float:
        """Length of the interval [mm]."""
        return self.far_mm - self.near_mm

    @property
    def model_valid(self) -> bool:
        """Whether the level lies inside the model's validity, r <= 1/2."""
        return self.ratio <= optics.VALID_RATIO

    def as_row(self) -> dict:
        """Row for tables: device, level, period_px, dof_mm, near_mm, far_mm, model_valid."""
        return {"device": self.device, "level": self.level, "period_px": self.period_px,
                "dof_mm": self.dof_mm, "near_mm": self.near_mm, "far_mm": self.far_mm,
                "model_valid": self.model_valid}


def _omega_o(z_p: float | np.ndarray, config: ScannerConfig, period_px: float) -> np.ndarray:
    """Fringe period on the object at projector distance z_p (Eq. 4) [mm]."""
    proj = config.projector
    return optics.fringe_period_on_object(z_p, period_px, proj.pitch_um * 1e-3,
                                          proj.focus_mm, proj.focal_mm)


def camera_dof(config: ScannerConfig, level: float, period_px: float) -> DepthOfField:
    """Depth of field of the camera (Table 1 set-up, Sect. 4.1).

    The flat stays at the projector's focus (so omega_o = omega_o(Z_p') is fixed) and
    the camera moves along its axis; the interval is where A(C_c(Z_c) / omega_o) >= level.

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    level : float
        Attenuation level a, 0 < a < 1 [-].
    period_px : float
        Fringe period [projector px].

    Returns
    -------
    DepthOfField
        With near/far in camera Z [mm]; the interval is Z_c' +- r_a omega_o Z_c' / Phi_c.
    """
    cam = config.camera
    r_a = optics.ratio_at_attenuation(level)
    omega_o = float(_omega_o(config.projector.focus_mm, config, period_px))
    half = r_a * omega_o * cam.focus_mm / cam.aperture_mm
    return DepthOfField("camera", level, period_px, cam.focus_mm - half, cam.focus_mm + half,
                        r_a)


def projector_dof(config: ScannerConfig, level: float, period_px: float) -> DepthOfField:
    """Depth of field of the projector (Table 2 set-up, Sect. 4.2).

    The camera stays in focus and the projector moves along its axis, so the flat's
    distance Z_p varies; the interval is where A(C_p(Z_p) / omega_o(Z_p)) >= level. It is
    asymmetric because omega_o grows with Z_p (Eq. 3/4).

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    level : float
        Attenuation level a, 0 < a < 1 [-].
    period_px : float
        Fringe period [projector px].

    Returns
    -------
    DepthOfField
        With near/far in projector Z [mm]; far is inf when the level is never reached.
    """
    proj = config.projector
    r_a = optics.ratio_at_attenuation(level)
    z_f = proj.focus_mm

    def excess(z: float) -> float:
        c = optics.circle_of_confusion(z, z_f, proj.aperture_mm)
        return float(c / _omega_o(z, config, period_px)) - r_a

    lo = 4.0 * proj.focal_mm * (1.0 + 1e-12)
    near = brentq(excess, lo, z_f, xtol=1e-10) if excess(lo) > 0 else lo
    hi = 1000.0 * z_f
    far = brentq(excess, z_f, hi, xtol=1e-10) if excess(hi) > 0 else np.inf
    return DepthOfField("projector", level, period_px, near, far, r_a)


def dof_table(config: ScannerConfig, levels=TABLE_LEVELS, periods=None) -> list[DepthOfField]:
    """Depth of field of camera and projector per level and period (Tables 1, 2).

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    levels : sequence of float
        Attenuation levels [-]; default the ten of Table 1.
    periods : sequence of float, optional
        Fringe periods [projector px]; default the config's periods.

    Returns
    -------
    list of DepthOfField
        Camera rows first, then projector rows, each ordered by period then level.
    """
    periods = config.fringes.periods_px if periods is None else periods
    for level in levels:
        if not 0.0 < level < 1.0:
            raise RangeError(f"attenuation level must be in (0, 1), got {level!r}")
    for p in periods:
        if not p > 0:
            raise RangeError(f"fringe period must be > 0 projector px, got {p!r}")
    rows = [camera_dof(config, a, p) for p in periods for a in levels]
    return rows + [projector_dof(config, a, p) for p in periods for a in levels]


#: Most range samples a curve takes (a 0.001 mm step over 100 mm; printing them as JSON
#: takes seconds).
MAX_RANGE_SAMPLES = 100_001


def _z_grid(z_min: float, z_max: float, step: float) -> np.ndarray:
    """Range samples from z_min to z_max inclusive [mm]."""
    if not (np.isfinite(z_min) and np.isfinite(z_max) and z_max > z_min):
        raise InputError(f"z_max must be > z_min, got z_min={z_min}, z_max={z_max} [mm]")
    if not step > 0:
        raise InputError(f"the range step must be > 0 mm, got {step}")
    if (z_max - z_min) / step >= MAX_RANGE_SAMPLES:
        raise InputError(
            f"a range step of {step:g} mm from {z_min:g} to {z_max:g} mm gives "
            f"{(z_max - z_min) / step + 1:.3g} samples (at most {MAX_RANGE_SAMPLES}): give "
            f"a step of at least {(z_max - z_min) / (MAX_RANGE_SAMPLES - 1):.3g} mm or a "
            "narrower range")
    return inclusive_range(z_min, z_max, step)


def axis_curve(config: ScannerConfig, z_min: float, z_max: float, step: float,
               period_px: float | None = None) -> dict[str, np.ndarray]:
    """The uncertainty-vs-range ("W") curve for points on the camera's optical axis.

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    z_min, z_max, step : float
        Range samples [mm].
    period_px : float, optional
        Fringe period [projector px]; default the working period.

    Returns
    -------
    dict of ndarray
        ``z_mm``, ``attenuation_camera``, ``attenuation_projector``, ``filter_factor``,
        ``s_o``, ``s_t_mm_per_px``, ``sigma_um`` and ``model_valid``.
    """
    z = _z_grid(z_min, z_max, step)
    pts = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
    pred = optics.predict(pts, config, period_px=period_px)
    return {"z_mm": z, "attenuation_camera": pred.attenuation_camera,
            "attenuation_projector": pred.attenuation_projector,
            "filter_factor": pred.filter_factor, "s_o": pred.s_o,
            "s_t_mm_per_px": pred.s_t, "sigma_um": pred.sigma * 1e3,
            "model_valid": pred.valid}


@dataclass(frozen=True)
class UsableVolume:
    """Sect. 5.1: total reconstruction volume vs the part usable at an attenuation level.

    Volumes in mm^3; the grid arrays describe the XZ slice at Y = 0 for pictures.
    """

    level: float
    z_min_mm: float
    z_max_mm: float
    step_mm: float
    total_mm3: float
    usable_mm3: float
    slice_x_mm: np.ndarray
    slice_z_mm: np.ndarray
    slice_inside: np.ndarray
    slice_usable: np.ndarray
    coc_max_mm: float | None = None

    @property
    def fraction(self) -> float:
        """Usable / total [-]."""
        return self.usable_mm3 / self.total_mm3 if self.total_mm3 > 0 else float("nan")


def _in_frusta(x: np.ndarray, y: np.ndarray, z: np.ndarray | float,
               config: ScannerConfig) -> np.ndarray:
    """Whether points (x, y, z broadcast together, scanner frame [mm]) project inside both
    the camera sensor and the projector panel.

    Each term is computed on the smallest shape it depends on (the camera's u on x and
    z, v on y and z) before the masks are combined, so that a slice costs a few passes.
    """
    cam, proj = config.camera, config.projector
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam.principal_distance_px * x / z + cam.principal_point_px[0]
        v = cam.principal_distance_px * y / z + cam.principal_point_px[1]
        rot, pos = _rotation(config), proj.position_mm
        d = (x - pos[0], y - pos[1], z - pos[2])
        qp = [_dot(rot[j], d) for j in range(3)]
        xp = proj.principal_distance_px * qp[0] / qp[2] + proj.principal_point_px[0]
        yp = proj.principal_distance_px * qp[1] / qp[2] + proj.principal_point_px[1]
    in_cam = (np.asarray(z) > 0) & ((u >= -0.5) & (u <= cam.width_px - 0.5)) \
        & ((v >= -0.5) & (v <= cam.height_px - 0.5))
    in_proj = (qp[2] > 0) & (xp >= -0.5) & (xp <= proj.width_px - 0.5) \
        & (yp >= -0.5) & (yp <= proj.height_px - 0.5)
    return in_cam & in_proj


def _rotation(config: ScannerConfig) -> np.ndarray:
    """The projector's rotation, computed once per pose (the optics module caches it)."""
    return geometry.projector_rotation(config.projector)


def _dot(row: np.ndarray, d: tuple) -> np.ndarray:
    """row . d for broadcastable components, skipping exact zeros of ``row`` (a projector
    in the XZ plane has no Y in its x and z axes, so they stay functions of x and z)."""
    terms = [r * c for r, c in zip(row, d, strict=True) if r != 0.0]
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


def usable_volume(config: ScannerConfig, level: float = 0.49, z_min: float | None = None,
                  z_max: float | None = None, step: float = 1.0,
                  period_px: float | None = None, coc_max_mm: float | None = None
                  ) -> UsableVolume:
    """Usable reconstruction volume (Sect. 5.1, Fig. 6).

    The total volume is the intersection of the camera and projector frusta between
    the near and far planes; the usable part is where the combined attenuation
    A_c A_p stays at or above ``level`` (both attenuations on their main lobe).

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    level : float
        Combined attenuation threshold [-]; the paper's Fig. 6 uses 0.49.
    z_min, z_max : float, optional
        Near and far planes [mm]; default the camera focus -+ 25 %.
    step : float
        Voxel size [mm].
    period_px : float, optional
        Fringe period [projector px]; default the working period.
    coc_max_mm : float, optional
        Also require the camera's image-side circle of confusion c_c (Eq. 14) to stay at
        or below this [mm]; Fig. 6 draws c_c < 0.030 mm as a band but does not cut the
        usable volume with it, so the default is None.

    Returns
    -------
    UsableVolume
        Volumes in mm^3 and an XZ slice at Y = 0 for the picture.
    """
    if not 0.0 < level < 1.0:
        raise RangeError(f"level must be in (0, 1), got {level!r}")
    focus = config.camera.focus_mm
    z_min = 0.75 * focus if z_min is None else z_min
    z_max = 1.25 * focus if z_max is None else z_max
    zs = _z_grid(z_min, z_max, step)
    half_w = field_half_extent(config, z_max)
    _check_voxels(half_w, zs.size, step)
    xs = np.arange(-half_w[0], half_w[0] + step, step)
    ys = np.arange(-half_w[1], half_w[1] + step, step)
    total = usable = 0
    per_slab = max(1, SLAB_VOXELS // (xs.size * ys.size))
    for k in range(0, zs.size, per_slab):  # slabs of planes bound the memory
        inside, good = volume_masks(xs[None, None, :], ys[None, :, None],
                                    zs[k:k + per_slab, None, None], config, level, period_px,
                                    coc_max_mm)
        total += int(inside.sum())
        usable += int((inside & good).sum())
    inside, good = volume_masks(xs[None, :], np.zeros((1, 1)), zs[:, None], config, level,
                                period_px, coc_max_mm)
    return UsableVolume(level, z_min, z_max, step, total * step**3, usable * step**3,
                        xs, zs, np.array(inside), inside & good, coc_max_mm)


def volume_masks(x: np.ndarray, y: np.ndarray, z: float | np.ndarray, config: ScannerConfig,
                 level: float, period_px: float | None, coc_max_mm: float | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Inside both frusta, and usable, on the grid x, y, z broadcast together.

    Parameters
    ----------
    x, y, z : ndarray
        Voxel centres in the scanner frame, broadcastable, e.g. (1, 1, nx), (1, ny, 1) and
        (nz, 1, 1) [mm].
    config : ScannerConfig
        Scanner config.
    level : float
        Combined attenuation threshold A_c A_p [-].
    period_px : float or None
        Fringe period [projector px]; None for the working period.
    coc_max_mm : float or None
        Largest image-side circle of confusion c_c (Eq. 14) [mm]; None for no limit.

    Returns
    -------
    inside, usable : ndarray of bool
        Of the broadcast shape; ``usable`` is the model's verdict alone (and it with
        ``inside`` is the usable volume).

    Notes
    -----
    The model depends on a voxel only through Z_c and Z_p. On a plane Z_c is fixed, and
    when the projector sits in the XZ plane (the usual layout) Z_p varies along X only,
    so a plane takes one row of model evaluations instead of one per voxel; otherwise
    every voxel is evaluated.
    """
    shape = np.broadcast_shapes(np.shape(x), np.shape(y), np.shape(z))
    inside = np.broadcast_to(_in_frusta(x, y, z, config), shape)
    rz, pos = _rotation(config)[2], config.projector.position_mm
    z_p = _dot(rz, (x - pos[0], y - pos[1], z - pos[2]))
    z_c, z_p = np.broadcast_arrays(np.asarray(z, dtype=float), z_p)
    good = _usable_at(z_c, z_p, config, level, period_px, coc_max_mm)
    return inside, np.broadcast_to(good, shape)


def _usable_at(z_c: np.ndarray, z_p: np.ndarray, config: ScannerConfig, level: float,
               period_px: float | None, coc_max_mm: float | None) -> np.ndarray:
    """A_c A_p >= level (and c_c <= coc_max_mm when given) at distances Z_c, Z_p [mm]."""
    terms = optics.optical_terms(z_c, z_p, config, period_px)
    good = terms.attenuation_camera * terms.attenuation_projector >= level
    if coc_max_mm is not None:
        good &= camera_image_blur(z_c, config) <= coc_max_mm
    return good


def camera_image_blur(z_c: np.ndarray, config: ScannerConfig) -> np.ndarray:
    """The camera's circle of confusion in the image, c_c(Z_c) (Eq. 14) [mm]."""
    cam = config.camera
    return optics.image_blur_diameter(z_c, cam.focal_mm, cam.focus_mm, cam.aperture_mm)


def coc_band(config: ScannerConfig, coc_max_mm: float) -> tuple[float, float]:
    """The camera ranges where c_c(Z_c) <= coc_max_mm (Eq. 14; Fig. 6's red lines) [mm].

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    coc_max_mm : float
        Largest image-side circle of confusion [mm]; Fig. 6 uses 0.030.

    Returns
    -------
    (near, far) : tuple of float
        Solving f Phi |Z - Z'| = c Z' (Z - f) for Z on either side of focus; far is inf
        when the blur never reaches c behind focus [mm].

    Examples
    --------
    >>> from scanqa.model.config import load_config
    >>> [round(z, 2) for z in coc_band(load_config("calib/paper_scanner.toml"), 0.030)]
    [446.26, 453.82]
    """
    if not coc_max_mm > 0:
        raise RangeError(f"coc_max_mm must be > 0 mm, got {coc_max_mm!r}")
    cam = config.camera
    f, phi, zf, c = cam.focal_mm, cam.aperture_mm, cam.focus_mm, coc_max_mm
    near = zf * f * (phi + c) / (f * phi + c * zf)
    far = zf * f * (phi - c) / (f * phi - c * zf) if f * phi > c * zf else np.inf
    return float(near), float(far)


#: Voxels :func:`usable_volume` evaluates at once: a slab of whole planes, ~40 MB of
#: temporaries, few enough numpy calls that their overhead does not dominate.
SLAB_VOXELS = 500_000
#: Largest XY slice and whole grid :func:`usable_volume` evaluates [voxels]: ~100 MB of
#: temporaries per slice, a few minutes in all.
MAX_SLICE_VOXELS, MAX_VOXELS = 4_000_000, 200_000_000


def _check_voxels(half_w: tuple[float, float], n_z: int, step: float) -> None:
    """Refuse, before allocating, a grid too large for memory or time."""
    n_x, n_y = (int(2 * h / step) + 2 for h in half_w)
    total = n_x * n_y * n_z
    if n_x * n_y <= MAX_SLICE_VOXELS and total <= MAX_VOXELS:
        return
    need = step * max((n_x * n_y / MAX_SLICE_VOXELS) ** 0.5, (total / MAX_VOXELS) ** (1 / 3))
    raise InputError(f"a voxel size of {step:g} mm gives {n_x} x {n_y} x {n_z} = {total:.3g} "
                     f"voxels (at most {MAX_SLICE_VOXELS:.0e} per slice and {MAX_VOXELS:.0e} "
                     f"in all): use a step of at least {need * 1.01:.3g} mm")


def field_half_extent(config: ScannerConfig, z: float) -> tuple[float, float]:
    """Half width and height of the camera's field of view at range z, plus 1 mm of
    margin: the box :func:`usable_volume` grids [mm]."""
    cam = config.camera
    scale = z / cam.principal_distance_px
    return (0.5 * cam.width_px * scale + 1.0, 0.5 * cam.height_px * scale + 1.0)


def flatten_curve(config: ScannerConfig, z_min: float, z_max: float, step: float,
                  period_px: float | None = None) -> dict[str, np.ndarray]:
    """Range-dependent digital filter that flattens the W curve (Sect. 5.2, Fig. 7).

    A disc filter of area b_f [px^2] applied to the phase image adds to the optical blur
    area, so F_gamma becomes sqrt((b_c + b_f) b_d) / gamma (areas of convolved discs add
    as their second moments do). The target is the lowest valid sigma over the range;
    sigma is inversely proportional to F_gamma (Eq. 18/19), so at each range the filter
    area that brings sigma down to it is b_f = (gamma F_gamma sigma / target)^2 / b_d - b_c,
    which is b_c ((sigma / target)^2 - 1) for Eq. 17 as printed.

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    z_min, z_max, step : float
        Range samples on the camera axis [mm].
    period_px : float, optional
        Fringe period [projector px].

    Returns
    -------
    dict of ndarray
        ``z_mm``, ``optical_blur_diameter_px`` (diameter of a disc of area b_c),
        ``filter_diameter_px`` (diameter of the digital filter), ``sigma_um`` (before)
        and ``sigma_flat_um`` (after), ``model_valid``.

    Notes
    -----
    Only the noise term is modelled: filtering the unwrapped phase image does not
    attenuate the fringes, but it does widen the lateral resolution by the filter size.
    With ``filter_floor = "one"`` a filter where F is held at 1 must first lift
    sqrt(b_c b_d) / gamma to 1 before it lowers sigma, so it is larger there.
    ``sigma_flat_um`` is sigma with the filter's area added in Eq. 17.
    """
    curve = axis_curve(config, z_min, z_max, step, period_px)
    z = curve["z_mm"]
    pred = optics.predict(np.stack([0 * z, 0 * z, z], axis=-1), config, period_px=period_px)
    sigma = curve["sigma_um"]
    ok = curve["model_valid"]
    if not ok.any():
        raise RangeError("the model is not valid anywhere in the requested range; "
                         "widen or move z_min/z_max towards the focus")
    target = float(np.nanmin(np.where(ok, sigma, np.nan)))
    b_c, f_gamma, gamma = pred.blur_area_camera, pred.filter_factor, config.model.gamma
    b_d = optics.diffraction_blur_area(
        optics.airy_diameter(config.model.wavelength_nm * 1e-6, config.camera.f_number),
        config.camera.pixel_um * 1e-3)
    with np.errstate(invalid="ignore"):
        excess = (gamma * f_gamma * sigma / target) ** 2 / b_d - b_c
        b_f = np.where(ok, np.where(sigma > target, np.maximum(excess, 0.0), 0.0), np.nan)
    f_flat = optics.filter_factor(b_c + b_f, b_d, gamma, pred.filter_floor)
    return {"z_mm": z, "optical_blur_diameter_px": 2.0 * np.sqrt(b_c / np.pi),
            "filter_diameter_px": 2.0 * np.sqrt(b_f / np.pi), "sigma_um": sigma,
            "sigma_flat_um": np.where(ok, sigma * f_gamma / f_flat, np.nan),
            "model_valid": ok}
