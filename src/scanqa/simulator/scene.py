"""Scenes of the virtual scanner: triangle meshes in the world frame, ray cast with open3d.

open3d's :class:`RaycastingScene` finds the hit triangle in float32; :meth:`Scene.cast`
then recomputes the hit distance in float64 against that triangle's plane, so that the
ground truth of a planar face is exact to rounding (about 1e-13 mm), not to float32.
For a mesh of axis-aligned boxes (the gauge blocks) :mod:`scanqa.simulator.boxcast`
finds the same triangles without holding the GIL, leaving to open3d the rays near an
edge.

Built-in scenes: a flat target (:func:`flat_target`), the gauge-block artefact of
Sect. 4.3 (:func:`gauge_block_artefact`, layout in :func:`paper_gauge_layout`), the
VDI/VDE 2634-2 artefacts (:func:`sphere_artefact`, :func:`ball_bar_artefact`,
:func:`flat_artefact`; :func:`measuring_volume` and :func:`ball_bar_positions` place
them), and any STL/PLY/OBJ mesh (:func:`load_mesh`).

Spheres are icospheres (trimesh) whose subdivision is chosen so that the mesh departs
from the ideal sphere by at most ``tolerance_mm`` (the flat faces lie inside it, the
vertices on it): :func:`sphere_mesh_deviation` measures it and the truth files record it.
Ray hits on a sphere are exact on its mesh, so the ideal sphere's truth is off by at
most that deviation (0.13 um for a 12 mm ball at the default 0.2 um tolerance, against
a single-point noise of several um).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from scanqa import compiled
from scanqa.errors import InputError
from scanqa.io.mesh import read_mesh
from scanqa.simulator import boxcast

#: Gauge-block heights of Table 3, block 1 (tallest) first [mm].
GAUGE_HEIGHTS_MM = (50.80, 25.40, 12.70, 7.62, 6.35, 5.08, 3.18, 2.54)
#: Largest accepted departure of a sphere's mesh from the ideal sphere [mm].
SPHERE_TOLERANCE_MM = 2e-4
#: Rays per open3d call when the cast runs inside a pool of threads [-]. open3d's
#: ``cast_rays`` holds the GIL for the whole call (0.1-0.2 us per ray on one core), so a
#: tile casting 0.8 M rays at once stalls the other core's thread at its next Python
#: step for ~0.1 s; in chunks of this size the GIL is let go every ~1 ms. Each ray is
#: cast on its own, so the hits do not depend on the chunking. Measured on a 768 x 768
#: window of the 5 MP gauge scan (``profile_simulate.py --timeline``): the tile threads
#: slept 14 % of their time in one call, 10 % in chunks of 16384, 5 % in chunks of 4096,
#: for ~50 us of CPU per call (casting 0.81 M rays: 64, 70 and 74 ms of CPU).
CAST_CHUNK_RAYS = 4096
#: Ball diameter of the simulated test sphere and ball bar [mm] (0.14 of the sample
#: scanner's measuring-volume diagonal).
BALL_DIAMETER_MM = 12.0
#: Diameter of the simulated ball bar's bar [mm].
BAR_DIAMETER_MM = 4.0
#: Depth of the simulated measuring volume [mm]: where the sample scanner's model is
#: valid on the camera axis (432-468 mm at f/11).
VOLUME_DEPTH_MM = 36.0
#: Tilts of the simulated flat about X and Y [deg] (not parallel to the calibration
#: planes) and its size [mm].
FLAT_TILT_DEG = (10.0, 15.0)
FLAT_SIZE_MM = (50.0, 40.0)
#: The seven ball-bar positions (:func:`ball_bar_positions`): label and direction of
#: the bar in the measuring volume's half-extents (x, y, z) [-].
BALL_BAR_POSITIONS = (
    ("diagonal +x+y+z", (1, 1, 1)), ("diagonal -x+y+z", (-1, 1, 1)),
    ("diagonal +x-y+z", (1, -1, 1)), ("diagonal -x-y+z", (-1, -1, 1)),
    ("face diagonal xy", (1, 1, 0)), ("face diagonal xz", (1, 0, 1)),
    ("face diagonal yz", (0, 1, 1)))


@dataclass(frozen=True)
class Hits:
    """Result of casting rays: float64 distances, hit mask, unit normals, face ids.

    ``t`` is the ray parameter (distance in units of the direction's length), NaN where
    nothing is hit; ``normals`` are the hit faces' unit normals (NaN where no hit; None
    when not asked for).
    """

    t: np.ndarray
    hit: np.ndarray
    normals: np.ndarray | None
    face: np.ndarray


class Scene:
    """A triangle mesh in the world frame with an open3d ray-casting structure.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The scene geometry [mm].
    name : str
        Label used in manifests and messages.
    """

    def __init__(self, mesh: trimesh.Trimesh, name: str = "mesh") -> None:
        import open3d as o3d

        if len(mesh.faces) == 0:
            raise InputError(f"scene {name!r} has no triangles")
        self.mesh = mesh
        self.name = name
        #: A printed texture (:class:`scanqa.simulator.texture.PrintedTarget`) or None.
        self.texture = None
        self._v = np.asarray(mesh.vertices, dtype=np.float64)
        self._f = np.asarray(mesh.faces, dtype=np.int64)
        normals = np.cross(self._v[self._f[:, 1]] - self._v[self._f[:, 0]],
                           self._v[self._f[:, 2]] - self._v[self._f[:, 0]])
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        self._n = normals / np.where(norm > 0, norm, 1.0)
        self._v0 = np.ascontiguousarray(self._v[self._f[:, 0]])
        self._raycast = o3d.t.geometry.RaycastingScene()
        self._raycast.add_triangles(o3d.core.Tensor(self._v.astype(np.float32)),
                                    o3d.core.Tensor(self._f.astype(np.uint32)))
        #: The mesh as axis-aligned boxes (:func:`~scanqa.simulator.boxcast.box_table`),
        #: cast without open3d where the hit is unambiguous; None for other meshes.
        self.boxes = boxcast.box_table(self._v, self._f)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) axis-aligned bounding box [mm]."""
        return np.array([self._v.min(axis=0), self._v.max(axis=0)])

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals of the faces [-]."""
        return self._n

    @property
    def face_origins(self) -> np.ndarray:
        """(F, 3) float64 first vertex of every face [mm]."""
        return self._v0

    def face_offsets(self, origin: np.ndarray) -> np.ndarray:
        """(F,) float64 ``n . (v0 - origin)`` per face, as :meth:`cast` computes it for
        one shared origin (the hit distance is this over ``n . d``) [mm]."""
        return np.einsum("ij,ij->i", self._n, self._v0 - origin[None, :])

    def first_hits(self, rays: np.ndarray, threads: int = 0
                   ) -> tuple[np.ndarray, np.ndarray]:
        """The hit triangles of (n, 6) float32 rays (origin, direction): open3d's float32
        cast, in chunks of :data:`CAST_CHUNK_RAYS` when ``threads`` is 1 (a caller's pool
        of threads); for a scene of boxes the same triangles found by
        :mod:`~scanqa.simulator.boxcast` without the GIL, open3d casting only the rays
        near an edge (its ray parameters then differ from open3d's in the last bits).

        Returns
        -------
        prim, t : (n,) uint32, float32
            Hit triangle (``2**32 - 1`` for none) and its ray parameter (inf for none).
        """
        if self.boxes is None or not compiled.HAVE_NUMBA:  # no Python loop over rays
            return self._open3d_hits(rays, threads)
        code, t = boxcast.first_triangles(rays, self.boxes, boxcast.AMBIGUOUS_MM)
        prim = np.where(code >= 0, code, np.iinfo(np.uint32).max).astype(np.uint32)
        near = np.flatnonzero(code == boxcast.AMBIGUOUS)
        if near.size:
            prim[near], t[near] = self._open3d_hits(rays[near], threads)
        return prim, t

    def _open3d_hits(self, rays: np.ndarray, threads: int = 0
                     ) -> tuple[np.ndarray, np.ndarray]:
        """open3d's cast of :meth:`first_hits` (chunked when ``threads`` is 1)."""
        import open3d as o3d

        n = rays.shape[0]
        if threads != 1 or n <= CAST_CHUNK_RAYS:
            ans = self._raycast.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=threads)
            return ans["primitive_ids"].numpy(), ans["t_hit"].numpy()
        prim, t = np.empty(n, np.uint32), np.empty(n, np.float32)
        for a in range(0, n, CAST_CHUNK_RAYS):
            b = min(a + CAST_CHUNK_RAYS, n)
            ans = self._raycast.cast_rays(o3d.core.Tensor.from_numpy(rays[a:b]), nthreads=1)
            prim[a:b], t[a:b] = ans["primitive_ids"].numpy(), ans["t_hit"].numpy()
        return prim, t

    def cast(self, origins: np.ndarray, directions: np.ndarray, normals: bool = True,
             threads: int = 0) -> Hits:
        """Cast rays and return float64 hits.

        Parameters
        ----------
        origins, directions : (..., 3) float
            Ray origins [mm] and directions (any length) in the world frame.
        normals : bool
            Return the hit faces' normals (False: ``Hits.normals`` is None, which saves
            two passes when only the distances are needed).
        threads : int
            Threads of open3d's ray casting (0: every core; 1 from callers that already
            run one cast per core) [-].

        Returns
        -------
        Hits
            Arrays of shape (...,) and (..., 3).
        """
        shape = np.shape(directions)[:-1]
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        origins = np.asarray(origins, dtype=np.float64)
        single = origins.ndim == 1 or not any(origins.strides[:-1])  # one shared origin
        o = origins[(0,) * (origins.ndim - 1)][None, :] if single else np.broadcast_to(
            origins, np.shape(directions)).reshape(-1, 3)
        rays = np.empty((d.shape[0], 6), np.float32)
        rays[:, :3], rays[:, 3:] = o, d
        prim, t_hit = self.first_hits(rays, threads)
        hit = np.isfinite(t_hit) & (prim != np.iinfo(np.uint32).max)
        del t_hit, rays
        safe = np.where(hit, prim, 0)
        n = self._n[safe]  # the rows of misses are discarded below
        with np.errstate(divide="ignore", invalid="ignore"):
            if single and len(self._f) < len(d):  # n . (v0 - o) once per face, not per ray
                offset = np.einsum("ij,ij->i", self._n, self._v[self._f[:, 0]] - o)
                num = offset[safe]
            else:
                num = np.einsum("ij,ij->i", n, self._v[self._f[safe, 0]] - o)
            t = num / np.einsum("ij,ij->i", n, d)
        t = np.where(hit, t, np.nan)
        face = np.where(hit, safe.astype(np.int64), -1)
        n = np.where(hit[:, None], n, np.nan).reshape(*shape, 3) if normals else None
        return Hits(t.reshape(shape), hit.reshape(shape), n, face.reshape(shape))


def flat_target(centre_mm, normal, size_mm: tuple[float, float] = (160.0, 130.0),
                name: str = "flat") -> Scene:
    """A rectangular flat target (two triangles), its face towards the scanner.

    Parameters
    ----------
    centre_mm : (3,) float
        Centre of the flat [mm].
    normal : (3,) float
        Normal pointing towards the scanner (any length) [-].
    size_mm : (2,) float
        Extent along the flat's in-plane axes [mm] (the first is closest to world X).
    """
    n = np.asarray(normal, dtype=float)
    n /= np.linalg.norm(n)
    a = np.cross([0.0, 1.0, 0.0], n)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    c = np.asarray(centre_mm, dtype=float)
    hx, hy = size_mm[0] / 2.0, size_mm[1] / 2.0
    corners = [c - hx * a - hy * b, c + hx * a - hy * b, c + hx * a + hy * b, c - hx * a + hy * b]
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = trimesh.Trimesh(np.array(corners), faces, process=False)
    _orient_towards(mesh, n)
    return Scene(mesh, name)


def _orient_towards(mesh: trimesh.Trimesh, normal: np.ndarray) -> None:
    """Flip faces whose normal points away from ``normal``."""
    flip = mesh.face_normals @ normal < 0
    if flip.any():
        faces = mesh.faces.copy()
        faces[flip] = faces[flip][:, ::-1]
        mesh.faces = faces


def plane_scene(z_mm: float, size_mm: tuple[float, float] = (200.0, 170.0)) -> Scene:
    """A flat target perpendicular to the camera axis at world Z = ``z_mm`` [mm]."""
    return flat_target([0.0, 0.0, z_mm], [0.0, 0.0, -1.0], size_mm, name=f"plane_z{z_mm:g}")


@dataclass(frozen=True)
class GaugeBlock:
    """One block of the artefact: id, nominal height and its top face region.

    ``region_mm`` is (x_min, x_max, y_min, y_max) in the scanner frame [mm]; the top face
    lies at Z = ``base_z_mm - height_mm``.
    """

    block_id: int
    height_mm: float
    region_mm: tuple[float, float, float, float]


@dataclass(frozen=True)
class GaugeLayout:
    """The gauge-block artefact: base plate (Z = ``base_z_mm``) and blocks on it."""

    base_z_mm: float
    base_region_mm: tuple[float, float, float, float]
    blocks: tuple[GaugeBlock, ...]
    base_thickness_mm: float = 10.0


def paper_gauge_layout(focus_mm: float = 450.0) -> GaugeLayout:
    """The 8 blocks of Sect. 4.3 in 2 rows x 4, focus between the tops of blocks 2 and 3.

    Blocks 1-4 (left to right) on the row Y < 0, blocks 5-8 on the row Y > 0; each top
    face is 12 x 18 mm. Block 1 is on the far left (-X) so that its shadow (the
    projector is at +X) falls off the artefact. The base plate lies at
    ``focus + (25.40 + 12.70) / 2`` so that focus is midway between tops 2 and 3.
    """
    base_z = focus_mm + (GAUGE_HEIGHTS_MM[1] + GAUGE_HEIGHTS_MM[2]) / 2.0
    xs, ys, hw, hh = (-24.0, -8.0, 8.0, 24.0), (-12.0, 12.0), 6.0, 9.0
    blocks = tuple(GaugeBlock(i + 1, h, (xs[i % 4] - hw, xs[i % 4] + hw,
                                         ys[i // 4] - hh, ys[i // 4] + hh))
                   for i, h in enumerate(GAUGE_HEIGHTS_MM))
    return GaugeLayout(base_z, (-45.0, 45.0, -37.5, 37.5), blocks)


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
    """Axis-aligned box mesh."""
    box = trimesh.creation.box(extents=[x1 - x0, y1 - y0, z1 - z0])
    box.apply_translation([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2])
    return box


def gauge_block_artefact(layout: GaugeLayout | None = None) -> Scene:
    """Scene of the base plate with its blocks (boxes; faces outward)."""
    layout = layout or paper_gauge_layout()
    z = layout.base_z_mm
    parts = [_box(*layout.base_region_mm, z, z + layout.base_thickness_mm)]
    parts += [_box(*b.region_mm, z - b.height_mm, z) for b in layout.blocks]
    return Scene(trimesh.util.concatenate(parts), "gauge_blocks")


def gauge_layout_toml(layout: GaugeLayout) -> str:
    """The layout file text (``calib/gauge_blocks_paper.toml``; docs/formats.rst documents it)."""
    def rect(r: tuple) -> str:
        return "[" + ", ".join(f"{v:.3f}" for v in r) + "]"

    lines = [
        "# Gauge-block artefact of Sect. 4.3 as simulated by scanqa.simulator",
        "# (paper_gauge_layout). Scanner frame: X right, Y down, Z along the camera",
        "# axis [mm]. Regions are rectangles [x_min, x_max, y_min, y_max] of the top",
        "# faces seen along Z; a block's top face lies at Z = base_z_mm - height.",
        'format = "scanqa-gauge-layout/1"',
        'name = "paper_gauge_blocks"',
        'frame = "scanner"',
        "paper_comparison = true   # the paper's artefact: its Tables 3 and 4 in the report",
        f"base_z_mm = {layout.base_z_mm:.3f}",
        "",
        "[base]",
        f"region_mm = {rect(layout.base_region_mm)}",
        "normal = [0.0, 0.0, -1.0]",
    ]
    for b in layout.blocks:
        lines += ["", "[[block]]", f"id = {b.block_id}",
                  f"nominal_height_mm = {b.height_mm:.2f}",
                  f"top_z_mm = {layout.base_z_mm - b.height_mm:.3f}",
                  f"region_mm = {rect(b.region_mm)}"]
    return "\n".join(lines) + "\n"


def load_mesh(path: str | os.PathLike, translate_mm=(0.0, 0.0, 0.0)) -> Scene:
    """Load an STL/PLY/OBJ mesh as a scene (coordinates in mm, world frame).

    Raises
    ------
    InputError
        When the file is missing, unreadable or holds no (or malformed) triangles
        (:func:`scanqa.io.mesh.read_mesh`).
    """
    p = Path(path)
    mesh = read_mesh(p)
    mesh.apply_translation(np.asarray(translate_mm, dtype=float))
    return Scene(mesh, p.stem)


# ------------------------------------------------------------- VDI/VDE 2634-2 artefacts

@dataclass(frozen=True)
class MeasuringVolume:
    """An axis-aligned box of the scanner frame: centre and full extents [mm]."""

    centre_mm: tuple[float, float, float]
    size_mm: tuple[float, float, float]

    @property
    def diagonal_mm(self) -> float:
        """Length of the space diagonal, L0 of VDI/VDE 2634-2 [mm]."""
        return float(np.linalg.norm(self.size_mm))


def measuring_volume(config, depth_mm: float = VOLUME_DEPTH_MM, fill: float = 0.9
                     ) -> MeasuringVolume:
    """The box the artefacts are placed in: centred on the camera axis at its focus.

    Parameters
    ----------
    config : ScannerConfig
        Camera intrinsics and focus.
    depth_mm : float
        Extent along Z [mm].
    fill : float
        Fraction of the camera's field of view at the box's near face that the box
        spans in X and Y [-].
    """
    cam = config.camera
    near = cam.focus_mm - depth_mm / 2.0
    scale = fill * near / cam.principal_distance_px  # object mm per pixel at the near face
    return MeasuringVolume((0.0, 0.0, float(cam.focus_mm)),
                           (cam.width_px * scale, cam.height_px * scale, float(depth_mm)))


def ball_bar_positions(volume: MeasuringVolume, distance_mm: float
                       ) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """The seven ball-bar positions: label and the two ball centres [mm].

    Four along the space diagonals of the measuring volume and three along the
    diagonals of its mid-planes (xy, xz, yz), every bar centred in the volume. VDI/VDE
    2634-2 asks for the bar in seven positions spread over the volume, the space
    diagonals among them; for the other three, a bar along the Z axis (the line of
    sight) would hide its far ball behind the near one, and a bar of at least 2/3 of
    the volume's diagonal does not fit along its shortest edge, so the mid-plane
    diagonals take their place.

    Parameters
    ----------
    volume : MeasuringVolume
        The box [mm].
    distance_mm : float
        Centre distance of the bar [mm].
    """
    half = np.asarray(volume.size_mm, dtype=float) / 2.0
    centre = np.asarray(volume.centre_mm, dtype=float)
    out = []
    for label, signs in BALL_BAR_POSITIONS:
        d = np.asarray(signs, dtype=float) * half
        d /= np.linalg.norm(d)
        out.append((label, centre - d * distance_mm / 2.0, centre + d * distance_mm / 2.0))
    return out


def ball_bar_distance(volume: MeasuringVolume, diameter_mm: float, step_mm: float = 1.0
                      ) -> float:
    """The longest centre distance (a multiple of ``step_mm``) that keeps both balls
    inside the measuring volume in all seven positions [mm]."""
    half = np.asarray(volume.size_mm, dtype=float) / 2.0 - diameter_mm / 2.0
    if np.any(half <= 0):
        raise InputError(f"balls of {diameter_mm:g} mm do not fit the measuring volume "
                         f"{volume.size_mm} mm")
    longest = np.inf
    for _, signs in BALL_BAR_POSITIONS:
        d = np.asarray(signs, dtype=float) * np.asarray(volume.size_mm) / 2.0
        d = np.abs(d / np.linalg.norm(d))
        longest = min(longest, 2.0 * float(np.min(half[d > 0] / d[d > 0])))
    return float(np.floor(longest / step_mm) * step_mm)


def sphere_mesh(centre_mm, diameter_mm: float, tolerance_mm: float = SPHERE_TOLERANCE_MM
                ) -> trimesh.Trimesh:
    """An icosphere of the coarsest subdivision within ``tolerance_mm`` of the sphere.

    Parameters
    ----------
    centre_mm : (3,) float
        Centre [mm].
    diameter_mm : float
        Diameter [mm].
    tolerance_mm : float
        Largest accepted departure of the faces from the ideal sphere [mm].
    """
    if not diameter_mm > 0:
        raise InputError(f"sphere diameter must be > 0 mm, got {diameter_mm!r}")
    for sub in range(3, 9):
        mesh = trimesh.creation.icosphere(subdivisions=sub, radius=diameter_mm / 2.0)
        if sphere_mesh_deviation(mesh, (0.0, 0.0, 0.0), diameter_mm / 2.0) <= tolerance_mm:
            break
    mesh.apply_translation(np.asarray(centre_mm, dtype=float))
    return mesh


def sphere_mesh_deviation(mesh: trimesh.Trimesh, centre_mm, radius_mm: float) -> float:
    """Largest radial departure of a sphere mesh's faces and vertices from the ideal
    sphere: the deepest face (its plane's distance from the centre) or the farthest
    vertex [mm]."""
    c = np.asarray(centre_mm, dtype=float)
    v = np.asarray(mesh.vertices, dtype=float) - c
    f = np.asarray(mesh.faces)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    depth = np.abs(np.einsum("ij,ij->i", n, v[f[:, 0]]))
    return float(max(radius_mm - depth.min(), np.abs(np.linalg.norm(v, axis=1)
                                                     - radius_mm).max()))


def sphere_artefact(centre_mm, diameter_mm: float, name: str = "sphere") -> Scene:
    """A free-standing test sphere (its stem, hidden behind it, is left out) [mm]."""
    return Scene(sphere_mesh(centre_mm, diameter_mm), name)


def ball_bar_artefact(centre_a_mm, centre_b_mm, diameter_mm: float,
                      bar_diameter_mm: float = 4.0, name: str = "ball_bar") -> Scene:
    """Two spheres joined by a cylindrical bar along the line of their centres [mm].

    The bar runs from ball to ball (its ends inside the balls); ``bar_diameter_mm`` 0
    leaves it out.
    """
    a, b = np.asarray(centre_a_mm, dtype=float), np.asarray(centre_b_mm, dtype=float)
    if not 0 <= bar_diameter_mm < diameter_mm:
        raise InputError(f"ball bar: bar_diameter_mm must be in [0, {diameter_mm:g}) mm "
                         f"(less than the balls), got {bar_diameter_mm!r}")
    parts = [sphere_mesh(a, diameter_mm), sphere_mesh(b, diameter_mm)]
    if bar_diameter_mm > 0:
        parts.append(trimesh.creation.cylinder(radius=bar_diameter_mm / 2.0,
                                               segment=np.stack([a, b]), sections=48))
    return Scene(trimesh.util.concatenate(parts), name)


def flat_artefact(centre_mm, normal, size_mm: tuple[float, float], name: str = "flat"
                  ) -> Scene:
    """A rectangular optical flat, its face towards the scanner (exact: two triangles)."""
    return flat_target(centre_mm, normal, size_mm, name=name)


def tilted_normal(tilt_x_deg: float, tilt_y_deg: float) -> np.ndarray:
    """Unit normal facing the camera (-Z) rotated by ``tilt_x_deg`` about X, then by
    ``tilt_y_deg`` about Y [-]."""
    ax, ay = np.radians(tilt_x_deg), np.radians(tilt_y_deg)
    n = np.array([0.0, np.sin(ax), -np.cos(ax)])
    rot = np.array([[np.cos(ay), 0.0, np.sin(ay)], [0.0, 1.0, 0.0],
                    [-np.sin(ay), 0.0, np.cos(ay)]])
    return rot @ n
