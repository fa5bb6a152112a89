"""Geometry of the virtual scanner's samples: camera rays, hits, projector coordinates
and lighting, per sample or per row of tiles (:mod:`scanqa.simulator.render` forms the
images from it).

Every sample is cast and lit on its own (float64, with open3d's float32 ray casting to
find the face), so the geometry of a set of samples does not depend on the batch it was
computed in: a tile's part of its row of tiles is exactly the tile's own geometry.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from scanqa.model.config import ScannerConfig
from scanqa.simulator import devices
from scanqa.simulator.devices import Pose, Window
from scanqa.simulator.scene import Scene


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
class Points:
    """Geometry of rays of one grid: camera Z, projector x_p and blur, lighting."""

    hit: np.ndarray
    world: np.ndarray
    z_c: np.ndarray
    x_p: np.ndarray
    y_p: np.ndarray
    z_p: np.ndarray
    lit: np.ndarray
    shade: np.ndarray


def sample_geometry(config: ScannerConfig, acq: Acquisition, u: np.ndarray, v: np.ndarray,
                    threads: int = 0) -> Points:
    """Cast camera rays through sensor coordinates and light the hits.

    Parameters
    ----------
    config : ScannerConfig
        Devices.
    acq : Acquisition
        Scene and poses.
    u, v : (...) float
        Sensor coordinates, pixel centres at integers [px].
    threads : int
        open3d's threads per cast (1 inside a pool that runs one cast per core) [-].

    Returns
    -------
    Points
        Per sample: hit, world point [mm], camera Z [mm], projector x_p, y_p [projector
        px] and z_p [mm], lit, cos of the incidence [-].
    """
    origins, dirs = devices.camera_rays(config, acq.camera, u, v)
    hits = acq.scene.cast(origins, dirs, threads=threads)
    world = origins + hits.t[..., None] * dirs
    z_c = (world - acq.camera.centre) @ acq.camera.rotation[2]  # device Z only
    x_p, y_p, z_p = devices.project_to_projector(config, acq.projector, world)
    lit, shade = _lighting(config, acq, world, hits.normals, hits.hit, x_p, y_p, z_p,
                           threads)
    return Points(hits.hit, world, z_c, x_p, y_p, z_p, lit, shade)


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


def supersample_grid(config: ScannerConfig, win: Window, tile: tuple, halo: int
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor coordinates of the supersamples of a tile with its halo [px]."""
    s = config.simulator.supersampling
    r0, r1, c0, c1 = tile
    sub = (np.arange(s) + 0.5) / s - 0.5
    rows = (np.arange(win.v0 + r0 - halo, win.v0 + r1 + halo)[:, None] + sub).ravel()
    cols = (np.arange(win.u0 + c0 - halo, win.u0 + c1 + halo)[:, None] + sub).ravel()
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    return uu, vv


def strips(tiles: list[tuple[int, int, int, int]]) -> list[list[int]]:
    """Indices of the tiles of each row of tiles (a strip), in order.

    Parameters
    ----------
    tiles : list of (int, int, int, int)
        (row0, row1, col0, col1) of the tiles, row by row [px].

    Returns
    -------
    list of list of int
        Per strip, the indices into ``tiles``.

    Examples
    --------
    >>> strips([(0, 2, 0, 2), (0, 2, 2, 4), (2, 3, 0, 2), (2, 3, 2, 4)])
    [[0, 1], [2, 3]]
    """
    rows: dict[int, list[int]] = {}
    for n, tile in enumerate(tiles):
        rows.setdefault(tile[0], []).append(n)
    return list(rows.values())


class StripGeometry:
    """The geometry of the supersamples of a whole row of tiles with its halo.

    Every sample is cast and lit on its own (the same numbers whatever the batch), so a
    tile's part of a strip is exactly the geometry of the tile with its halo; cast once
    per strip, the horizontal halos are cast once instead of by both neighbours. One
    set of buffers serves every strip of a window (allocated by the first, the tallest):
    fresh memory is expensive to fault in, and a strip of a 5 MP scan holds ~0.45 GB.
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}
        self._rows = 0

    def cast(self, config: ScannerConfig, acq: Acquisition, win: Window, tile: tuple,
             halo: int, pool: ThreadPoolExecutor, threads: int) -> None:
        """Cast the strip of ``tile``'s rows over the whole window width, with the halo
        [px] on every side, in column blocks of about a tile on ``pool`` (``threads``:
        open3d's threads per cast); the tiles of the previous strip must be done."""
        uu, vv = supersample_grid(config, win, (tile[0], tile[1], 0, win.width), halo)
        shape = uu.shape
        if not self._buffers or self._buffers["hit"].shape[0] < shape[0]:
            self._buffers = {name: np.empty(shape + ((3,) if name == "world" else ()),
                                            bool if name in ("hit", "lit") else float)
                             for name in Points.__dataclass_fields__}
        self._rows = shape[0]
        span = (tile[1] - tile[0] + 2 * halo) * config.simulator.supersampling
        blocks = max(2 * (os.cpu_count() or 1), round(shape[1] / max(span, 1)))
        edges = np.linspace(0, shape[1], blocks + 1).astype(int)

        def block(j: int) -> None:
            cols = slice(edges[j], edges[j + 1])
            pts = sample_geometry(config, acq, np.ascontiguousarray(uu[:, cols]),
                                  np.ascontiguousarray(vv[:, cols]), threads)
            for name, values in self._buffers.items():
                values[:self._rows, cols] = getattr(pts, name)

        list(pool.map(block, range(blocks)))

    def tile(self, config: ScannerConfig, win: Window, tile: tuple, halo: int
             ) -> tuple[np.ndarray, np.ndarray, Points]:
        """The samples (uu, vv) [px] and the geometry of ``tile`` (of the strip last
        cast) with its halo [px], contiguous copies."""
        s = config.simulator.supersampling
        cols = slice(tile[2] * s, (tile[3] + 2 * halo) * s)
        pts = Points(**{name: np.ascontiguousarray(values[:self._rows, cols])
                        for name, values in self._buffers.items()})
        uu, vv = supersample_grid(config, win, tile, halo)
        return uu, vv, pts
