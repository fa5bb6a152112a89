"""A reconfigurable scanner as the design page shows it (Sect. 5.1, Fig. 6 of [1]_).

The page's inputs are a flat set of named settings (:data:`SETTINGS`: focal lengths,
f-numbers, focus distances, baseline and convergence angle, fringe period, pixel size and
the two thresholds) laid over a scanner config; :func:`rig_view` turns a config and the
thresholds into everything the page draws - the view pyramids, the focus planes, the
circle-of-confusion band, the total and usable volume, the W curve, the depth of field
and the numbers - by the one model chain (:mod:`scanqa.design.tools`, :mod:`scanqa.model.optics`).
The usable volume is :func:`scanqa.design.tools.usable_volume` at its default 1 mm voxels, so
the page's number is ``scanqa design volume``'s.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection

from scanqa.design import tools
from scanqa.errors import InputError
from scanqa.io.schema import Field, within
from scanqa.model import geometry, optics
from scanqa.model.config import ScannerConfig, config_from_dict


@dataclass(frozen=True)
class Setting(Field):
    """One input of the design page: a declared number (its meaning is the label, its
    limits the slider's range) and the slider's step."""

    type: str = "number"
    step: float = 1.0


#: The page's inputs, in display order.
SETTINGS: dict[str, Setting] = {s.name: s for s in (
    Setting("camera_focal_mm", unit="mm", check=within(8, 200), doc="camera focal length"),
    Setting("camera_f_number", check=within(1.4, 32), doc="camera f-number", step=0.1),
    Setting("camera_focus_mm", unit="mm", check=within(150, 1500), doc="camera focus distance"),
    Setting("camera_pixel_um", unit="um", check=within(1, 20), doc="camera pixel size",
            step=0.1),
    Setting("projector_focal_mm", unit="mm", check=within(8, 100),
            doc="projector focal length", step=0.5),
    Setting("projector_f_number", check=within(1, 16), doc="projector f-number", step=0.05),
    Setting("projector_focus_mm", unit="mm", check=within(150, 1500),
            doc="projector focus distance"),
    Setting("baseline_mm", unit="mm", check=within(20, 500), doc="baseline (projector X)"),
    Setting("angle_deg", unit="deg", check=within(0, 45), doc="convergence angle", step=0.1),
    # any period the decoder orders (a Gray code, a coarser set or a beat), from two
    # projector pixels (the finest period a panel can show) to the widest panels (8K)
    Setting("period_px", unit="px", check=within(2, 8192), doc="fringe period", step=0.25),
    Setting("level", check=within(0.05, 0.95), doc="combined attenuation threshold A_c A_p",
            step=0.01),
    Setting("coc_max_mm", unit="mm", check=within(0.005, 0.2),
            doc="camera circle of confusion threshold c_c", step=0.001))}


def settings_from_config(config: ScannerConfig, level: float = 0.49,
                         coc_max_mm: float = 0.030) -> dict[str, float]:
    """The page's settings of a config (and the two thresholds, Fig. 6's by default).

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    level : float
        Combined attenuation threshold [-].
    coc_max_mm : float
        Camera image-side circle of confusion threshold [mm].

    Returns
    -------
    dict of float
        One value per key of :data:`SETTINGS`; the angle is the projector axis' angle to
        the camera axis in the XZ plane [deg].
    """
    cam, proj = config.camera, config.projector
    axis = np.subtract(proj.look_at_mm, proj.position_mm)
    return {"camera_focal_mm": cam.focal_mm, "camera_f_number": cam.f_number,
            "camera_focus_mm": cam.focus_mm, "camera_pixel_um": cam.pixel_um,
            "projector_focal_mm": proj.focal_mm,
            "projector_f_number": proj.focal_mm / proj.aperture_mm,
            "projector_focus_mm": proj.focus_mm, "baseline_mm": float(proj.position_mm[0]),
            "angle_deg": math.degrees(math.atan2(-axis[0], axis[2])),
            "period_px": config.fringes.working_period_px, "level": level,
            "coc_max_mm": coc_max_mm}


def apply_settings(config: ScannerConfig, settings: dict) -> ScannerConfig:
    """The config with the page's settings laid over it, validated again.

    The projector keeps its Y and Z position; it sits at X = baseline and looks at the
    camera axis at the convergence angle (at Z = baseline / tan(angle)), or straight
    ahead at 0 degrees. The working period replaces the finest one of the config.

    Raises
    ------
    InputError
        On an unknown setting or one outside its range.
    ConfigError
        When the result is not a valid config (a focus inside the focal length).
    """
    values = check_settings(settings)
    data = config.to_dict()
    cam, proj = data["camera"], data["projector"]
    cam.update(focal_mm=values["camera_focal_mm"], f_number=values["camera_f_number"],
               focus_mm=values["camera_focus_mm"], pixel_um=values["camera_pixel_um"])
    proj.update(focal_mm=values["projector_focal_mm"], focus_mm=values["projector_focus_mm"],
                aperture_mm=values["projector_focal_mm"] / values["projector_f_number"])
    _, y0, z0 = config.projector.position_mm
    b, theta = values["baseline_mm"], math.radians(values["angle_deg"])
    proj["position_mm"] = [b, y0, z0]
    reach = b / math.tan(theta) if theta > 0 else 1000.0
    proj["look_at_mm"] = [b - reach * math.tan(theta), y0, z0 + reach]
    periods = [p for p in config.fringes.periods_px if p > values["period_px"]]
    data["fringes"]["periods_px"] = [values["period_px"], *periods]
    return config_from_dict(_drop_none(data), source=config.source or "<design page>")


def check_settings(settings: dict) -> dict[str, float]:
    """Every setting present, a finite number, within its range; messages name the key."""
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        raise InputError(f"unknown setting {unknown[0]!r} (known: {', '.join(SETTINGS)})")
    out = {}
    for key, spec in SETTINGS.items():
        if key not in settings:
            raise InputError(f"missing setting {key!r}")
        try:
            value = float(settings[key])
        except (TypeError, ValueError):
            raise InputError(f"{key} must be a number, got {settings[key]!r}") from None
        if not spec.check.test(value):  # type: ignore[union-attr]
            raise InputError(f"{key} must be {spec.check.text} {spec.unit}, "  # type: ignore
                             f"got {value!r}")
        out[key] = value
    return out


def _drop_none(data: dict) -> dict:
    """Nested dict without None values (TOML has no null; absent means default)."""
    return {k: _drop_none(v) if isinstance(v, dict) else v for k, v in data.items()
            if v is not None}


def config_toml_dict(config: ScannerConfig) -> dict:
    """The config as the TOML tables every command reads (``--config``)."""
    return _drop_none(config.to_dict())


@dataclass(frozen=True)
class RigView:
    """Everything the design page shows for one config and thresholds.

    Points are (n, 3) arrays in the scanner frame [mm]. ``total_mesh`` (the convex
    intersection of the pyramids and the near and far planes) and ``usable_mesh`` (the
    boundary of the usable voxels of a coarse grid) are (vertices (n, 3) [mm], triangles
    (m, 3)) for the picture; the numbers come from ``volume``, the 1 mm grid of
    ``scanqa design volume``.
    """

    level: float
    coc_max_mm: float
    coc_cuts_volume: bool
    volume: tools.UsableVolume
    camera_pyramid: np.ndarray
    projector_pyramid: np.ndarray
    camera_focus_plane: np.ndarray
    projector_focus_plane: np.ndarray
    coc_planes: np.ndarray
    clip_planes: np.ndarray
    axes_crossing: np.ndarray
    total_mesh: tuple[np.ndarray, np.ndarray]
    usable_mesh: tuple[np.ndarray, np.ndarray]
    curve: dict
    camera_dof: tools.DepthOfField
    projector_dof: tools.DepthOfField
    numbers: dict


def rig_view(config: ScannerConfig, level: float = 0.49, coc_max_mm: float = 0.030,
             coc_cuts_volume: bool = False, picture_voxels: int = 20_000) -> RigView:
    """Compute what the design page draws (Fig. 6) for one config.

    Parameters
    ----------
    config : ScannerConfig
        Scanner config.
    level : float
        Combined attenuation threshold A_c A_p [-]; Fig. 6 uses 0.49.
    coc_max_mm : float
        Camera image-side circle of confusion threshold c_c (Eq. 14) [mm]; Fig. 6 draws
        c_c < 0.030 mm as a band (red dotted lines).
    coc_cuts_volume : bool
        Also cut the usable volume to the band (Fig. 6 does not).
    picture_voxels : int
        About how many voxels the picture's coarse grid of the usable volume has [-].

    Returns
    -------
    RigView
        The drawing's geometry, the W curve, the depth of field and the numbers.
    """
    cut = coc_max_mm if coc_cuts_volume else None
    vol = tools.usable_volume(config, level, coc_max_mm=cut)
    z_lo, z_hi = vol.z_min_mm, vol.z_max_mm
    curve = tools.axis_curve(config, z_lo, z_hi, 0.5)
    cam_dof = tools.camera_dof(config, level, config.fringes.working_period_px)
    proj_dof = tools.projector_dof(config, level, config.fringes.working_period_px)
    band = tools.coc_band(config, coc_max_mm)
    total_mesh = _hull_mesh(config, z_lo, z_hi)
    usable_mesh = _usable_mesh(config, vol, cut, picture_voxels)
    return RigView(
        level, coc_max_mm, coc_cuts_volume, vol,
        _pyramid(config, "camera", z_hi), _pyramid(config, "projector", z_hi),
        _camera_plane(config, config.camera.focus_mm), _projector_plane(config),
        np.stack([_camera_plane(config, min(z, z_hi)) for z in band]),
        np.stack([_camera_plane(config, z) for z in (z_lo, z_hi)]),
        config.axes_crossing_mm, total_mesh, usable_mesh, curve, cam_dof, proj_dof,
        _numbers(config, vol, curve, level, cut, band))


def _sensor_corners(width: int, height: int, f_px: float, c: tuple) -> np.ndarray:
    """(4, 3) rays through a sensor's corner pixels, scaled to unit Z [-]."""
    u = np.array([-0.5, width - 0.5, width - 0.5, -0.5]) - c[0]
    v = np.array([-0.5, -0.5, height - 0.5, height - 0.5]) - c[1]
    return np.stack([u / f_px, v / f_px, np.ones(4)], axis=-1)


def _camera_plane(config: ScannerConfig, z: float) -> np.ndarray:
    """(4, 3) corners of the camera's field of view at range z [mm]."""
    cam = config.camera
    return z * _sensor_corners(cam.width_px, cam.height_px, cam.principal_distance_px,
                               cam.principal_point_px)


def _projector_corners(config: ScannerConfig, z_p: float) -> np.ndarray:
    """(4, 3) corners of the projector's image at projector depth z_p, scanner frame [mm]."""
    proj = config.projector
    rays = _sensor_corners(proj.width_px, proj.height_px, proj.principal_distance_px,
                           proj.principal_point_px)
    return np.asarray(proj.position_mm) + (z_p * rays) @ proj.rotation


def _projector_plane(config: ScannerConfig) -> np.ndarray:
    return _projector_corners(config, config.projector.focus_mm)


def _pyramid(config: ScannerConfig, device: str, z_far: float) -> np.ndarray:
    """(5, 3) apex then the four base corners of a device's view pyramid [mm]."""
    if device == "camera":
        return np.vstack([np.zeros(3), _camera_plane(config, z_far)])
    reach = float(geometry.projector_depth(np.array([0.0, 0.0, z_far]), config))
    return np.vstack([config.projector.position_mm, _projector_corners(config, reach)])


def _hull_mesh(config: ScannerConfig, z_lo: float, z_hi: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """The total volume as a triangle mesh: the intersection of both view pyramids and
    the near and far planes, a convex polyhedron (vertices (n, 3) [mm], triangles (m, 3)).
    """
    planes = [_side_planes(np.zeros(3), _camera_plane(config, 1.0)),
              _side_planes(np.asarray(config.projector.position_mm, dtype=float),
                           _projector_corners(config, 1.0))]
    halfspaces = np.vstack([*planes, [[0, 0, -1, z_lo], [0, 0, 1, -z_hi]]])
    norms = np.linalg.norm(halfspaces[:, :3], axis=1)
    res = linprog([0, 0, 0, -1], A_ub=np.hstack([halfspaces[:, :3], norms[:, None]]),
                  b_ub=-halfspaces[:, 3], bounds=[(None, None)] * 3 + [(0, None)])
    if not res.success or res.x[3] <= 1e-6:  # the pyramids do not meet in the range
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=int)
    verts = HalfspaceIntersection(halfspaces, res.x[:3]).intersections
    return verts, ConvexHull(verts).simplices


def pyramid_halfspaces(config: ScannerConfig, z_far: float) -> list[np.ndarray]:
    """The camera's and the projector's view pyramids up to the far plane z_far, each as
    (5, 4) halfspaces n . q + d <= 0 (four sides and the far plane) [mm]."""
    cam = _side_planes(np.zeros(3), _camera_plane(config, 1.0))
    proj_pos = np.asarray(config.projector.position_mm, dtype=float)
    proj = _side_planes(proj_pos, _projector_corners(config, 1.0))
    far = [0.0, 0.0, 1.0, -z_far]
    return [np.vstack([cam, far]), np.vstack([proj, far])]


def _side_planes(apex: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(4, 4) halfspaces n . q + d <= 0 of a pyramid's sides, normals pointing out."""
    out = []
    centre = apex + (corners - apex).mean(axis=0)
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        n = np.cross(a - apex, b - apex)
        n = n if n @ (centre - apex) < 0 else -n
        out.append([*n, -n @ apex])
    return np.asarray(out)


def _voxel_surface(mask: np.ndarray, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The boundary faces of a (nz, ny, nx) voxel mask as a triangle mesh [mm]."""
    pad = np.pad(mask, 1)
    step = (xs[1] - xs[0]) if xs.size > 1 else 1.0
    origin = np.array([xs[0], ys[0], zs[0]]) - 1.5 * step  # of the padded grid's corner
    quads = []
    for axis in range(3):  # faces between neighbours along z, y, x of the (z, y, x) grid
        diff = np.diff(pad.astype(np.int8), axis=axis)
        for idx in np.argwhere(diff != 0):
            quads.append(_face(idx, axis))
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=int)
    corners = np.asarray(quads, dtype=float)[..., ::-1]  # (z, y, x) -> (x, y, z)
    corners, index = np.unique(corners.reshape(-1, 3), axis=0, return_inverse=True)
    k = index.reshape(-1, 4)  # shared corners once: a quarter of the vertices to send
    tris = np.vstack([k[:, [0, 1, 2]], k[:, [0, 2, 3]]])
    return origin + step * corners, tris


def _face(idx: np.ndarray, axis: int) -> list:
    """The four corners (z, y, x in padded voxel units) of the face after voxel idx."""
    base = idx.astype(float)
    base[axis] += 1.0
    a, b = [d for d in range(3) if d != axis]
    out = []
    for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
        c = base.copy()
        c[a] += da
        c[b] += db
        out.append(c)
    return out


def _usable_mesh(config: ScannerConfig, vol: tools.UsableVolume, cut: float | None,
                 voxels: int) -> tuple[np.ndarray, np.ndarray]:
    """The usable volume on a coarse grid of about ``voxels`` cubes, as its boundary mesh."""
    x_lo, x_hi = vol.slice_x_mm[0], vol.slice_x_mm[-1]
    half_y = tools.field_half_extent(config, vol.z_max_mm)[1]
    box = (x_hi - x_lo) * 2 * half_y * (vol.z_max_mm - vol.z_min_mm)
    step = (box / voxels) ** (1 / 3)
    xs = np.arange(x_lo, x_hi + step, step)
    ys = np.arange(-half_y, half_y + step, step)
    zs = np.arange(vol.z_min_mm, vol.z_max_mm + step, step)
    inside, good = tools.volume_masks(xs[None, None, :], ys[None, :, None],
                                       zs[:, None, None], config, vol.level, None, cut)
    return _voxel_surface(inside & good, xs, ys, zs)


def _numbers(config: ScannerConfig, vol: tools.UsableVolume, curve: dict, level: float,
             cut: float | None, band: tuple[float, float]) -> dict:
    """The page's numbers: volumes, the usable depth on the camera axis, sigma [um]."""
    z = curve["z_mm"]
    good = curve["attenuation_camera"] * curve["attenuation_projector"] >= level
    if cut is not None:
        good &= tools.camera_image_blur(z, config) <= cut
    focus = config.camera.focus_mm
    near, far = _run_around(z, good, focus)
    sigma = tools.axis_curve(config, focus, focus + 1.0, 1.0)["sigma_um"][0]
    at_ends = [_sigma_at(config, zz) for zz in (near, far)]
    return {"total_cm3": vol.total_mm3 / 1e3, "usable_cm3": vol.usable_mm3 / 1e3,
            "usable_fraction": vol.fraction, "usable_near_mm": near, "usable_far_mm": far,
            "usable_depth_mm": far - near, "sigma_focus_um": float(sigma),
            "sigma_near_um": at_ends[0], "sigma_far_um": at_ends[1],
            "coc_near_mm": band[0], "coc_far_mm": band[1]}


def _run_around(z: np.ndarray, good: np.ndarray, centre: float) -> tuple[float, float]:
    """Ends of the run of ``good`` samples that holds the one nearest ``centre`` [mm];
    NaN when that sample is not good."""
    i = int(np.argmin(np.abs(z - centre)))
    if not good[i]:
        return float("nan"), float("nan")
    bad = np.flatnonzero(~good)
    lo = bad[bad < i].max() + 1 if (bad < i).any() else 0
    hi = bad[bad > i].min() - 1 if (bad > i).any() else z.size - 1
    return float(z[lo]), float(z[hi])


def _sigma_at(config: ScannerConfig, z: float) -> float:
    """sigma on the camera axis at range z [um]; NaN for NaN z."""
    if not math.isfinite(z):
        return float("nan")
    pred = optics.predict(np.array([0.0, 0.0, z]), config)
    return float(pred.sigma) * 1e3
