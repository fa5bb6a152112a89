"""Image formation of the virtual scanner: from a scene and poses to fringe images.

Per pattern, in this order (docs/simulator.rst):

1. geometry: camera rays through a supersampled pixel grid hit the scene (open3d, then
   float64 against the hit face); a point is lit when it faces the projector, lies on
   the panel and the projector's ray reaches it unblocked (shadows are hard, decided
   by the chief ray); unlit points get only the ambient light;
2. projector defocus: the pattern reaching a point is the panel pattern averaged over
   the point's blur disc on the panel, by a fixed disc quadrature
   (:class:`~scanqa.simulator.optics_kernels.DiscAverage`), with Lambertian incidence;
3. scene/projector-side temporal noise, i.i.d. per pattern and object cell, added to
   the supersampled radiance before the camera blur (so the blur filters it);
4. camera defocus: each sample spreads over its own disc (depth-dependent) - samples
   are split between the two nearest of a fine ladder of blur diameters, each layer is
   convolved with its disc convolved with the Airy PSF, and the layers are summed
   (no partial occlusion of the aperture at depth edges; :mod:`scanqa.simulator.blur`);
5. pixel integration (mean of the s x s supersamples), then the sensor: Poisson shot
   noise in electrons, Gaussian read noise, full-well saturation, quantisation.

The window is processed in tiles of ``TILE_PX`` pixels with a halo wide enough for the
largest blur, so memory is bounded, on a pool of threads (one per core); every random
stream is keyed by (seed, stream key, pattern, tile), so the output does not depend on
anything but the inputs (nor on the order in which the threads finish). The radiance and
the blur are float32 (rounding ~1e-3 e- against a shot noise of ~140 e-); the geometry
and the fringe's phase are float64. The per-sample passes (hits, projections, lighting,
the fringe's contrast and angle, the noise cells, the blur's sort into layers) are
compiled loops (:mod:`scanqa.simulator.raykernels`) that repeat numpy's arithmetic; a
scene of boxes is cast by another (:mod:`scanqa.simulator.boxcast`), so that the tile
threads do not wait for each other's cast.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from scanqa import compiled
from scanqa.chunks import row_bands, run_bands
from scanqa.decoding.coding import PatternDescription, PhaseSet
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig
from scanqa.simulator import devices, raykernels
from scanqa.simulator.blur import BlurPlan, blur, blur_plan
from scanqa.simulator.devices import Pose, Window
from scanqa.simulator.optics_kernels import DiscAverage, airy_kernel, disc_average
from scanqa.simulator.scene import Scene

#: Tile size of the chunked renderer [camera px] (256: the halo of a 5 MP scan, 22 px,
#: adds 37 % to a tile's samples instead of 80 % at 128).
TILE_PX = 256
#: Largest halo around a tile; blur beyond it is clipped [camera px].
MAX_HALO_PX = 64
#: Windows from this size on say so when numba is missing (a scan of seconds) [px].
NOTE_NUMPY_PX = 1 << 20

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Acquisition:
    """Everything one scan needs: scene, device poses and the stream key of its noise.

    ``key`` is a tuple of small non-negative integers (e.g. position and repeat
    indices) that, with the config's seed, selects independent noise.
    """

    scene: Scene
    camera: Pose
    projector: Pose
    key: tuple[int, ...] = ()


@dataclass(frozen=True)
class Truth:
    """Ground truth at pixel centres of the window, in the acquisition's camera frame.

    ``x, y, z`` [mm] are NaN where the pixel sees nothing; ``xp``/``yp`` [projector px]
    and ``zp`` [mm] are the hit point's projector coordinates; ``valid`` is True where
    the point is seen by the camera and lit by the projector.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    xp: np.ndarray
    yp: np.ndarray
    zp: np.ndarray
    valid: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """Arrays keyed as in the truth npz files (X, Y, Z, xp_true, yp_true, zp, valid)."""
        return {"X": self.x, "Y": self.y, "Z": self.z, "xp_true": self.xp,
                "yp_true": self.yp, "zp": self.zp, "valid": self.valid}


# ------------------------------------------------------------------ geometry of points

@dataclass(frozen=True)
class _Points:
    """Geometry of rays of one grid: camera Z, projector x_p and blur, lighting."""

    hit: np.ndarray
    world: np.ndarray
    z_c: np.ndarray
    x_p: np.ndarray
    y_p: np.ndarray
    z_p: np.ndarray
    lit: np.ndarray
    shade: np.ndarray


def _geometry(config: ScannerConfig, acq: Acquisition, u: np.ndarray, v: np.ndarray,
              threads: int = 0) -> _Points:
    """Cast camera rays through sensor coordinates (u, v) and light the hits (``threads``:
    open3d's threads per cast, 1 inside a pool that runs one cast per core)."""
    origins, dirs = devices.camera_rays(config, acq.camera, u, v)
    hits = acq.scene.cast(origins, dirs, threads=threads)
    world = origins + hits.t[..., None] * dirs
    z_c = (world - acq.camera.centre) @ acq.camera.rotation[2]  # device Z only
    x_p, y_p, z_p = devices.project_to_projector(config, acq.projector, world)
    lit, shade = _lighting(config, acq, world, hits.normals, hits.hit, x_p, y_p, z_p,
                           threads)
    return _Points(hits.hit, world, z_c, x_p, y_p, z_p, lit, shade)


def _points(config: ScannerConfig, acq: Acquisition, u: np.ndarray, v: np.ndarray,
            threads: int = 0) -> _Points:
    """:func:`_geometry` by the compiled loops of :mod:`~scanqa.simulator.raykernels`
    (the same numbers), or by numpy where those do not apply (a distorted projector)."""
    fast = raykernels.tile_geometry(config, acq.scene, acq.camera, acq.projector, u, v,
                                    threads)
    return _geometry(config, acq, u, v, threads) if fast is None else _Points(*fast)


def _lighting(config: ScannerConfig, acq: Acquisition, world: np.ndarray,
              normals: np.ndarray, hit: np.ndarray, x_p: np.ndarray, y_p: np.ndarray,
              z_p: np.ndarray, threads: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Lit mask (on the panel, facing, unshadowed) and cos of the incidence angle."""
    proj = config.projector
    to_proj = acq.projector.centre - world
    dist = np.linalg.norm(to_proj, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        towards_cam = np.einsum("...i,...i->...", normals, acq.camera.centre - world)
        shade = np.einsum("...i,...i->...", normals, to_proj) / dist
        shade = np.where(towards_cam < 0, -shade, shade)  # two-sided (the normal flipped)
        on_panel = ((z_p > 0) & (x_p >= -0.5) & (x_p <= proj.width_px - 0.5)
                    & (y_p >= -0.5) & (y_p <= proj.height_px - 0.5))
    lit = hit & on_panel & (shade > 0)
    if lit.any():
        back = acq.scene.cast(acq.projector.centre, world[lit] - acq.projector.centre,
                              normals=False,
                              threads=threads)
        reach = np.zeros_like(lit)
        reach[lit] = np.nan_to_num(back.t, nan=np.inf) >= 1.0 - 1e-7
        lit &= reach
    return lit, np.where(lit, shade, 0.0)


# --------------------------------------------------------------------------- truth

#: Pixels per band of :func:`truth_for` (bounds its memory: ~300 B per pixel) [-].
TRUTH_BAND_PX = 1 << 18


def truth_for(config: ScannerConfig, acq: Acquisition) -> Truth:
    """Exact geometry at the pixel centres of the window (no images).

    Computed in bands of rows on every core (each pixel on its own: the same numbers
    as in one piece).
    """
    win = devices.sensor_window(config)
    out = {k: np.full((win.height, win.width), np.nan) for k in ("x", "y", "z", "xp", "yp", "zp")}
    out["valid"] = np.zeros((win.height, win.width), bool)

    bands = row_bands(win.height, win.width, TRUTH_BAND_PX)
    threads = 1 if len(bands) > 1 else 0

    def band(r0: int, r1: int) -> None:
        v, u = np.mgrid[win.v0 + r0:win.v0 + r1, win.u0:win.u0 + win.width]
        pts = _points(config, acq, u.astype(float), v.astype(float), threads)
        cam = acq.camera.to_device(pts.world)
        for name, values, keep in (("x", cam[..., 0], pts.hit), ("y", cam[..., 1], pts.hit),
                                   ("z", cam[..., 2], pts.hit), ("xp", pts.x_p, pts.lit),
                                   ("yp", pts.y_p, pts.lit), ("zp", pts.z_p, pts.hit)):
            out[name][r0:r1] = np.where(keep, values, np.nan)
        out["valid"][r0:r1] = pts.lit

    run_bands(band, bands)
    return Truth(out["x"], out["y"], out["z"], out["xp"], out["yp"], out["zp"], out["valid"])


# --------------------------------------------------------------------- noise streams

def _stream_key(config: ScannerConfig, key: Sequence[int]) -> int:
    """One 63-bit integer from the seed and a tuple of stream indices."""
    seq = np.random.SeedSequence([config.simulator.seed, *[int(k) for k in key]])
    return int(seq.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _noise_cells(config: ScannerConfig, pts: _Points, uu: np.ndarray, vv: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """Integer cell indices of every sample and the noise scale per cell [-].

    Cells are squares of ``scene_noise_cell_mm`` in world X, Y (fixed to the scene, so
    a moving camera sees the same cells); with cell 0, each supersample is a cell and
    the std is scaled by s so that it is ``scene_noise_rel`` per camera pixel.
    """
    sim = config.simulator
    cell = sim.scene_noise_cell_mm
    if cell == 0:
        s = sim.supersampling
        return (np.round(uu * s - 0.5).astype(np.int64),
                np.round(vv * s - 0.5).astype(np.int64), float(s))
    ix, iy = raykernels.noise_cells(pts.world.reshape(-1, 3), pts.hit.ravel(), float(cell))
    return ix.reshape(pts.hit.shape), iy.reshape(pts.hit.shape), 1.0


# --------------------------------------------------------------------------- sensor

def _sensor(config: ScannerConfig, electrons: np.ndarray, rng: np.random.Generator
            ) -> np.ndarray:
    """Shot noise, read noise, full well, quantisation: electrons -> DN (uint16)."""
    sim = config.simulator
    e = rng.poisson(np.clip(electrons, 0.0, None)).astype(np.float64)
    e += rng.normal(0.0, sim.read_noise_e, size=e.shape) if sim.read_noise_e > 0 else 0.0
    e = np.clip(e, 0.0, sim.full_well_e)
    dn = np.floor(e / sim.gain_e_per_dn + 0.5)
    return np.clip(dn, 0, 2 ** sim.bit_depth - 1).astype(np.uint16)


def sensor_saturation_dn(config: ScannerConfig) -> float:
    """Level at which the sensor saturates [DN] (full well or the ADC range)."""
    sim = config.simulator
    return float(min(math.floor(sim.full_well_e / sim.gain_e_per_dn + 0.5),
                     2 ** sim.bit_depth - 1))


# ------------------------------------------------------------------------ rendering

def halo_px(config: ScannerConfig, acq: Acquisition) -> int:
    """Halo of a tile: the largest blur radius over the scene's depth range [px]."""
    corners = np.array(np.meshgrid(*acq.scene.bounds.T)).reshape(3, -1).T
    z = acq.camera.to_device(corners)[:, 2]
    z = np.clip(z, config.camera.focal_mm * 1.05, None)
    blur = float(np.max(devices.camera_blur_px(config, z)))
    z_range = np.linspace(z.min(), z.max(), 64)
    blur = max(blur, float(np.max(devices.camera_blur_px(config, z_range))))
    airy = 2.44 * config.model.wavelength_nm * 1e-6 * config.camera.f_number * 2.0
    return int(min(MAX_HALO_PX, math.ceil(blur / 2 + airy / (config.camera.pixel_um * 1e-3)) + 2))


def _tiles(win: Window) -> list[tuple[int, int, int, int]]:
    """(row0, row1, col0, col1) of the tiles of a window, window-relative [px]."""
    return [(r, min(r + TILE_PX, win.height), c, min(c + TILE_PX, win.width))
            for r in range(0, win.height, TILE_PX) for c in range(0, win.width, TILE_PX)]


def _supersample_grid(config: ScannerConfig, win: Window, tile: tuple, halo: int
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor coordinates of the supersamples of a tile with its halo [px]."""
    s = config.simulator.supersampling
    r0, r1, c0, c1 = tile
    sub = (np.arange(s) + 0.5) / s - 0.5
    rows = (np.arange(win.v0 + r0 - halo, win.v0 + r1 + halo)[:, None] + sub).ravel()
    cols = (np.arange(win.u0 + c0 - halo, win.u0 + c1 + halo)[:, None] + sub).ravel()
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    return uu, vv


def render_images(config: ScannerConfig, acq: Acquisition, desc: PatternDescription,
           progress: Callable[[int, int], None] | None = None) -> list[np.ndarray]:
    """Render the camera images of every set of a pattern description.

    Parameters
    ----------
    config : ScannerConfig
        Optics and simulator settings.
    acq : Acquisition
        Scene, poses and noise stream.
    desc : PatternDescription
        Phase sets with vertical fringes (what the projector shows).
    progress : callable, optional
        Called as ``progress(done, total)`` after every tile.

    Returns
    -------
    list of (N, H, W) uint16
        One image stack per set, in ``desc.sets`` order [DN].

    Raises
    ------
    InputError
        For sets this renderer cannot form (Gray code, horizontal fringes), or when no
        pixel of the window sees a lit point of the scene.
    """
    _check_desc(desc)
    win = devices.sensor_window(config)
    if win.width * win.height >= NOTE_NUMPY_PX:
        compiled.note_numpy_path(log, "the simulator (about 1.15 x the CPU)")
    images = [np.zeros((s.steps, win.height, win.width), np.uint16) for s in desc.sets]
    if not _render_tiles(config, acq, desc, win, images, progress):
        raise InputError("zero valid pixels: no pixel of the camera sees a point of scene "
                         f"{acq.scene.name!r} lit by the projector (is the scene outside "
                         "both frusta, or behind the devices?)")
    return images


def _render_tiles(config: ScannerConfig, acq: Acquisition, desc: PatternDescription | None,
                  win: Window, images: list[np.ndarray],
                  progress: Callable[[int, int], None] | None = None) -> bool:
    """Render every tile into ``images`` on a pool of threads; True if any is lit.

    numpy, scipy's FFT and open3d release the GIL, tiles write disjoint slices and each
    tile's noise is keyed by its index, so the images do not depend on the scheduling.
    """
    halo = halo_px(config, acq)
    tiles = _tiles(win)
    table = disc_average(config.simulator.projector_samples)
    workers = min(os.cpu_count() or 1, len(tiles))
    threads = 1 if workers > 1 else 0  # open3d's threads per cast

    def work(n: int) -> bool:
        return _render_tile(config, acq, desc, win, tiles[n], halo, table, images, n,
                            threads)

    # the largest tiles first, so that the pool's last tiles are its smallest (the
    # window's last column and row): the threads finish closer together
    order = sorted(range(len(tiles)), key=lambda n: -(tiles[n][1] - tiles[n][0])
                   * (tiles[n][3] - tiles[n][2]))
    lit_any = False
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for n, lit in enumerate(pool.map(work, order)):
            lit_any |= lit
            if progress:
                progress(n + 1, len(tiles))
    return lit_any


def _check_desc(desc: PatternDescription) -> None:
    for s in desc.sets:
        if not isinstance(s, PhaseSet) or s.orientation != "vertical":
            raise InputError(f"the simulator renders vertical phase sets only, got set "
                             f"{s.name!r}")


def _render_tile(config: ScannerConfig, acq: Acquisition, desc: PatternDescription | None,
                 win: Window, tile: tuple, halo: int, table: DiscAverage,
                 images: list[np.ndarray], tile_index: int, threads: int = 0) -> bool:
    """Render every pattern of one tile into ``images`` (``desc`` None: the marker
    frame); True if any sample is lit."""
    sim, s = config.simulator, config.simulator.supersampling
    uu, vv = _supersample_grid(config, win, tile, halo)
    pts = _points(config, acq, uu, vv, threads)
    if not pts.hit.any():
        return False
    airy = airy_kernel(config.model.wavelength_nm * 1e-6, config.camera.f_number,
                       config.camera.pixel_um * 1e-3 / s)
    plan = blur_plan(np.nan_to_num(devices.camera_blur_px(config, pts.z_c)) * s, pts.hit,
                     airy, halo * s, s)
    m = sim.modulation_ratio
    albedo = _albedo(config, acq, pts, desc is None)
    alb = 1.0 if albedo is None else albedo
    ambient = sim.mean_signal_e * np.where(pts.hit, 1.0 - m, 0.0) * alb  # [e-]
    lit_level = sim.mean_signal_e * m * pts.shade * alb  # lit part at the mean level [e-]
    mean_level = ambient + lit_level
    frame = _Frame(config, acq.key, tile, plan,
                   _CellNoise.of(config, pts, uu, vv, mean_level), tile_index)
    rows, cols = slice(tile[0], tile[1]), slice(tile[2], tile[3])
    if desc is None:  # one uniformly lit frame (the mean level of the fringes)
        images[0][0, rows, cols] = frame.image(mean_level.astype(np.float32), [], 0.0,
                                               MARKER_STREAM)
        return bool(pts.lit.any())
    d_panel = np.where(pts.lit, devices.projector_blur_px(config, pts.z_p), 0.0)
    k_pattern = 0
    for set_index, pset in enumerate(desc.sets):
        base, terms = _fringe_terms(pts, d_panel, pset.period_px, table,
                                    sim.projector_gamma, ambient, lit_level)
        for k, delta in enumerate(pset.shifts_rad):
            images[set_index][k, rows, cols] = frame.image(base, terms, delta, k_pattern)
            k_pattern += 1
    return bool(pts.lit.any())


#: Pattern index of the marker frame's noise stream (beyond any pattern set).
MARKER_STREAM = 1_000_000


@dataclass(frozen=True)
class _CellNoise:
    """Where the scene noise of every sample of a tile comes from, and its std.

    ``gx, gy`` are the cells to hash (a grid over the tile's cells, or every sample's own
    cell when the grid would be large), ``index`` the flat index of each sample's cell in
    that grid (None: one cell per sample), ``scale`` the std per sample [e-] (None: no
    scene noise).
    """

    gx: np.ndarray
    gy: np.ndarray
    index: np.ndarray | None
    scale: np.ndarray | None

    @classmethod
    def of(cls, config: ScannerConfig, pts: _Points, uu: np.ndarray, vv: np.ndarray,
           mean_level: np.ndarray) -> _CellNoise:
        """The cells of a tile's samples and the noise std at each [e-]."""
        rel = config.simulator.scene_noise_rel
        if rel == 0:
            return cls(np.zeros(0), np.zeros(0), None, None)
        ix, iy, cell_scale = _noise_cells(config, pts, uu, vv)
        scale = (rel * cell_scale * mean_level).astype(np.float32)
        x0, y0 = ix.min(), iy.min()
        nx, ny = ix.max() - x0 + 1, iy.max() - y0 + 1
        if nx * ny > 4 * ix.size:
            return cls(ix, iy, None, scale)
        # only the cells some sample falls in are hashed (a cell's value depends on its
        # (ix, iy) alone, so the values are those of the whole grid): with cells smaller
        # than a sample's footprint most of the bounding grid is never sampled, and the
        # hash is most of a frame's CPU
        flat = ((iy - y0) * nx + (ix - x0)).ravel()
        used, index = np.unique(flat, return_inverse=True)
        return cls(used % nx + x0, used // nx + y0, index.reshape(ix.shape).astype(np.intp),
                   scale)

    def add_to(self, radiance: np.ndarray, key: int) -> None:
        """Add the noise of stream ``key`` to ``radiance`` in place (float32) [e-]."""
        if self.scale is None:
            return
        cells = raykernels.hash_normal(key, np.ascontiguousarray(self.gx),
                                        np.ascontiguousarray(self.gy))
        if self.index is None:  # one cell per sample
            cells *= self.scale
            radiance += cells
            return
        raykernels.add_cell_noise(radiance, cells, self.index, self.scale)


@dataclass(frozen=True)
class _Frame:
    """What every frame of a tile shares: blur layers, noise cells, the sensor."""

    config: ScannerConfig
    key: tuple
    tile: tuple
    plan: BlurPlan
    noise: _CellNoise
    tile_index: int

    def image(self, base: np.ndarray, terms: list, delta: float, pattern: int
              ) -> np.ndarray:
        """Scene noise, camera blur, pixel integration and sensor of one frame [DN].

        The light leaving each sample is ``base + sum_h Re(q_h exp(i h delta))`` plus
        the scene noise, with ``terms`` the (h, Re q_h, Im q_h) of the fringe [e-].
        """
        key = _stream_key(self.config, (*self.key, pattern))
        radiance = base.copy()
        for h, q_re, q_im in terms:
            raykernels.add_fringe(radiance, np.float32(math.cos(h * delta)), q_re,
                                  np.float32(math.sin(h * delta)), q_im)
        self.noise.add_to(radiance, key)
        pixels = blur(radiance, self.plan)  # the pixel means of the blurred light [e-]
        rng = np.random.Generator(np.random.PCG64(
            np.random.SeedSequence([key, self.tile_index, 7])))
        return _sensor(self.config, pixels, rng)


def _albedo(config: ScannerConfig, acq: Acquisition, pts: _Points, marker: bool
            ) -> np.ndarray | None:
    """Reflectance of the printed target at each sample, None for a plain scene."""
    texture = acq.scene.texture
    if texture is None or (not marker and texture.fringe_contrast == 0):
        return None
    s = config.simulator.supersampling
    footprint = np.abs(np.nan_to_num(pts.z_c, nan=1.0)) / (
        config.camera.principal_distance_px * s)
    world = np.where(pts.hit[..., None], pts.world, 0.0)
    return np.where(pts.hit, texture.albedo(world, footprint, fringe=not marker), 1.0)


def render_marker_frame(config: ScannerConfig, acq: Acquisition) -> np.ndarray:
    """The uniformly lit frame of the printed target (the marker frame), (H, W) [DN].

    The projector shows a flat field at the fringes' mean level; the target's print is
    seen at ``target_contrast``. Noise and sensor as for a fringe frame.
    """
    win = devices.sensor_window(config)
    images = [np.zeros((1, win.height, win.width), np.uint16)]
    _render_tiles(config, acq, None, win, images)
    return images[0][0]


def _phasor(pts: _Points, d_panel: np.ndarray, period: float, table: DiscAverage,
            harmonic: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Disc-averaged complex fringe M(pi d h / P) exp(i h 2 pi x_p / P) of lit samples,
    as its real and imaginary parts, float32 [-].

    The fringe's phase is reduced to one period in float64 before the float32 cosine
    (a phase error of ~1e-6 rad instead of ~1e-4 rad at the panel's edge).
    """
    contrast, angle = raykernels.phasor_parts(
        pts.lit.ravel(), d_panel.ravel(), pts.x_p.ravel(), harmonic, float(period),
        table.u, table.m)
    contrast, angle = contrast.reshape(pts.lit.shape), angle.reshape(pts.lit.shape)
    return contrast * np.cos(angle), contrast * np.sin(angle)


#: Harmonics of a gamma-distorted fringe that the renderer keeps.
GAMMA_HARMONICS = 8


def response_harmonics(gamma: float, harmonics: int = GAMMA_HARMONICS) -> np.ndarray:
    """Cosine-series coefficients of ``(0.5 + 0.5 cos t) ** gamma``.

    Parameters
    ----------
    gamma : float
        Projector response exponent [-].
    harmonics : int
        Highest harmonic kept [-].

    Returns
    -------
    (harmonics + 1,) float64
        c_0 .. c_H with ``(0.5 + 0.5 cos t) ** gamma = sum_h c_h cos(h t)`` [-]; for
        gamma = 1, (0.5, 0.5, 0, ...).

    Examples
    --------
    >>> response_harmonics(2.0, 3).round(6).tolist()
    [0.375, 0.5, 0.125, 0.0]
    """
    t = 2.0 * np.pi * np.arange(1024) / 1024
    spectrum = np.fft.rfft((0.5 + 0.5 * np.cos(t)) ** gamma) / 1024
    coef = 2.0 * spectrum.real[:harmonics + 1]
    coef[0] /= 2.0
    return coef


def _fringe_terms(pts: _Points, d_panel: np.ndarray, period: float, table: DiscAverage,
                  gamma: float, ambient: np.ndarray, lit_level: np.ndarray
                  ) -> tuple[np.ndarray, list]:
    """What a phase set's panel pattern puts on the scene, blurred by the projector.

    A linear projector (gamma 1) shows ``1 + Re(M e^(i(theta + delta)))`` relative to the
    mean lit level; with a response ``p**gamma`` every harmonic h of the distorted fringe
    is averaged over the blur disc at its own frequency, ``2 c_0 + 2 sum_h c_h Re(M_h
    e^(i h (theta + delta)))``. The light of frame ``delta`` is then ``base + sum_h
    Re(q_h e^(i h delta))``.

    Returns
    -------
    base : (H, W) float32
        Level of every sample without the fringe [e-].
    terms : list of (int, (H, W) float32, (H, W) float32)
        Harmonic h and the real and imaginary parts of q_h [e-].
    """
    if gamma == 1.0:
        coef, mean = [(1, 0.5)], 1.0
    else:
        c = response_harmonics(gamma)
        coef, mean = [(h, ch) for h, ch in enumerate(c) if h and abs(ch) > 1e-7], 2.0 * c[0]
    base = (ambient + mean * lit_level).astype(np.float32)
    terms = []
    for h, ch in coef:
        q_re, q_im = _phasor(pts, d_panel, period, table, h)
        amplitude = (2.0 * ch * lit_level).astype(np.float32)
        terms.append((h, q_re * amplitude, q_im * amplitude))
    return base, terms
