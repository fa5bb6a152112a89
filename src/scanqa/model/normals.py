"""Surface normals of a scan: from its pixel grid, or from nearest neighbours.

An annotated scan is organised: each point comes from one camera pixel, so its
neighbours on the surface are the points of the pixels beside it. :func:`grid_normals`
takes the cross product of the grid's two tangents,

    t_u = P(u + 1, v) - P(u - 1, v),   t_v = P(u, v + 1) - P(u, v - 1),

(one-sided, P(u + 1, v) - P(u, v) or P(u, v) - P(u - 1, v), where one neighbour is
missing), normalised and turned towards the camera, which sits at the origin of the
scanner frame. That is 4 neighbours and no search: cheap, and it follows the scan's own
structure (no neighbour from across a gap in the image). A neighbour farther than
:data:`JUMP_FOOTPRINTS` pixel footprints (``z / f`` [mm]: the spacing of points on a
surface facing the camera) is across a depth jump and is not used. A point with no
usable neighbour along a row or a column gets the normal (0, 0, 0): PLY readers load
zeros as they are (CloudCompare keeps them as "no normal", Open3D as zeros), whereas
CloudCompare turns NaN normals into an arbitrary direction.

:func:`knn_normals` serves clouds without a pixel grid (Open3D's ``estimate_normals``
on the k nearest neighbours, oriented the same way).
"""

from __future__ import annotations

import numpy as np

from scanqa.compiled import HAVE_NUMBA, njit

#: Neighbour distance, in pixel footprints, beyond which a neighbour is taken to be
#: across a depth jump [-]: a surface tilted by 83 deg from facing the camera still has
#: its neighbours within it (1 / cos 83 deg = 8.2).
JUMP_FOOTPRINTS = 8.0
#: What the cloud's metadata says of normals from :func:`grid_normals`.
GRID_METHOD = ("estimated from the pixel grid: cross product of the row and column "
               "tangents between the 4 neighbouring pixels (one-sided where one is "
               f"missing; none farther than {JUMP_FOOTPRINTS:g} pixel footprints), "
               "oriented towards the camera; (0, 0, 0) where a row or column has no "
               "usable neighbour")


def pixel_index(keep: np.ndarray) -> np.ndarray:
    """The record index of each pixel of an organised cloud.

    Parameters
    ----------
    keep : (H, W) bool
        The pixels that have a point; the points are in row-major pixel order.

    Returns
    -------
    (H, W) int32
        The point of each pixel, -1 where there is none.
    """
    index = np.full(keep.shape, -1, dtype=np.int32)
    index[keep] = np.arange(int(keep.sum()), dtype=np.int32)
    return index


def grid_normals(xyz: np.ndarray, index: np.ndarray, focal_px: float,
                 rows: tuple[int, int] | None = None) -> np.ndarray:
    """Unit normals of the points of an organised cloud, from their pixel neighbours.

    Parameters
    ----------
    xyz : (n, 3) float
        The points, in the scanner frame with the camera at the origin [mm].
    index : (H, W) int
        :func:`pixel_index` of the cloud.
    focal_px : float
        The camera's principal distance [px]: a pixel's footprint is ``z / focal_px``.
    rows : (int, int), optional
        Only the points of image rows ``r0 <= v < r1`` (a band; their neighbours may lie
        outside it); default all.

    Returns
    -------
    (m, 3) float32
        The normals of the points of those rows, in their order (row-major); (0, 0, 0)
        where a row or a column has no usable neighbour (module notes).
    """
    r0, r1 = rows if rows is not None else (0, index.shape[0])
    r0, r1 = max(int(r0), 0), min(int(r1), index.shape[0])
    if HAVE_NUMBA:
        return _compiled_normals(xyz, index, float(focal_px), r0, r1)
    vv, uu = np.nonzero(index[r0:r1] >= 0)
    vv += r0
    ids = index[vv, uu]
    p = np.asarray(xyz[ids], dtype=float)
    with np.errstate(invalid="ignore"):
        limit = JUMP_FOOTPRINTS * np.abs(p[:, 2]) / float(focal_px)
    tangents = []
    for dv, du in ((0, 1), (1, 0)):
        ahead, ok_a = _neighbour(xyz, index, vv + dv, uu + du, p, limit)
        behind, ok_b = _neighbour(xyz, index, vv - dv, uu - du, p, limit)
        both = ok_a & ok_b
        t = np.where(both[:, None], ahead - behind, np.where(ok_a[:, None], ahead, -behind))
        t[~(ok_a | ok_b)] = 0.0
        tangents.append(t)
    normal = np.cross(tangents[0], tangents[1])
    length = np.sqrt(np.einsum("ij,ij->i", normal, normal))
    towards = np.einsum("ij,ij->i", normal, p) > 0  # away from the camera at the origin
    scale = np.divide(np.where(towards, -1.0, 1.0), length, out=np.zeros_like(length),
                      where=length > 0)
    return (normal * scale[:, None]).astype(np.float32)


def _compiled_normals(xyz: np.ndarray, index: np.ndarray, focal_px: float, r0: int,
                      r1: int) -> np.ndarray:
    """:func:`grid_normals` through :func:`_normals_kernel`: the points of rows
    ``r0 - 1 .. r1`` (one contiguous run of records) copied into one aligned array."""
    height = index.shape[0]
    first = _first_point(index, r0, height)  # a band with no points: the next one's first
    out = np.zeros((_first_point(index, r1, height) - first, 3), dtype=np.float32)
    lo = _first_point(index, max(r0 - 1, 0), height)
    hi = _first_point(index, min(r1 + 1, height), height)
    near = np.ascontiguousarray(xyz[lo:hi], dtype=np.float64)
    _normals_kernel(near, lo, np.ascontiguousarray(index, dtype=np.int32), focal_px,
                    JUMP_FOOTPRINTS, r0, r1, first, out)
    return out


def _first_point(index: np.ndarray, row: int, height: int) -> int:
    """The first point at or after image row ``row`` (the number of points before it)."""
    for r in range(row, height):
        found = index[r][index[r] >= 0]
        if found.size:
            return int(found[0])
    return int(index.max()) + 1 if index.size else 0


@njit(cache=True, nogil=True)
def _normals_kernel(near: np.ndarray, lo: int, index: np.ndarray, focal_px: float,
                    jump: float, r0: int, r1: int, first: int, out: np.ndarray) -> None:
    """The normals of the points of rows ``r0 .. r1 - 1`` into ``out`` (row ``i - first``
    for point ``i``); ``near`` holds points ``lo ..`` (those of the rows beside too)."""
    height, width = index.shape
    t = np.empty((2, 3))
    for v in range(r0, r1):
        for u in range(width):
            i = index[v, u]
            if i < 0:
                continue
            px, py, pz = near[i - lo, 0], near[i - lo, 1], near[i - lo, 2]
            limit2 = (jump * abs(pz) / focal_px) ** 2
            usable = True
            for axis in range(2):
                dv, du = (0, 1) if axis == 0 else (1, 0)
                ok_a = ok_b = False
                ax = ay = az = bx = by = bz = 0.0
                va, ua, vb, ub = v + dv, u + du, v - dv, u - du
                if va < height and ua < width and index[va, ua] >= 0:
                    j = index[va, ua] - lo
                    ax, ay, az = near[j, 0] - px, near[j, 1] - py, near[j, 2] - pz
                    ok_a = ax * ax + ay * ay + az * az <= limit2
                if vb >= 0 and ub >= 0 and index[vb, ub] >= 0:
                    j = index[vb, ub] - lo
                    bx, by, bz = near[j, 0] - px, near[j, 1] - py, near[j, 2] - pz
                    ok_b = bx * bx + by * by + bz * bz <= limit2
                if ok_a and ok_b:
                    t[axis, 0], t[axis, 1], t[axis, 2] = ax - bx, ay - by, az - bz
                elif ok_a:
                    t[axis, 0], t[axis, 1], t[axis, 2] = ax, ay, az
                elif ok_b:
                    t[axis, 0], t[axis, 1], t[axis, 2] = -bx, -by, -bz
                else:
                    usable = False
            if not usable:
                continue
            nx = t[0, 1] * t[1, 2] - t[0, 2] * t[1, 1]
            ny = t[0, 2] * t[1, 0] - t[0, 0] * t[1, 2]
            nz = t[0, 0] * t[1, 1] - t[0, 1] * t[1, 0]
            length = (nx * nx + ny * ny + nz * nz) ** 0.5
            if not length > 0:
                continue
            if nx * px + ny * py + nz * pz > 0:  # away from the camera at the origin
                length = -length
            k = i - first
            out[k, 0], out[k, 1], out[k, 2] = nx / length, ny / length, nz / length


def _neighbour(xyz: np.ndarray, index: np.ndarray, vv: np.ndarray, uu: np.ndarray,
               p: np.ndarray, limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets to the points of pixels (uu, vv) from ``p`` [mm] and whether each is
    usable (inside the image, a point, finite, within ``limit`` [mm])."""
    inside = (vv >= 0) & (vv < index.shape[0]) & (uu >= 0) & (uu < index.shape[1])
    j = np.full(vv.shape, -1, dtype=np.int64)
    j[inside] = index[vv[inside], uu[inside]]
    d = np.asarray(xyz[np.maximum(j, 0)], dtype=float) - p
    with np.errstate(invalid="ignore"):
        ok = (j >= 0) & (np.einsum("ij,ij->i", d, d) <= limit**2)
    return d, ok


def knn_normals(xyz: np.ndarray, k: int = 16) -> np.ndarray:
    """Unit normals of an unorganised cloud from its ``k`` nearest neighbours (Open3D's
    ``estimate_normals``: the plane of least variance), oriented towards the camera at
    the origin.

    Parameters
    ----------
    xyz : (n, 3) float
        The points [mm].
    k : int
        Neighbours per point [-].

    Returns
    -------
    (n, 3) float32
        The normals; (0, 0, 0) for points that are not finite.
    """
    import open3d as o3d

    xyz = np.asarray(xyz, dtype=float)
    finite = np.isfinite(xyz).all(axis=1)
    out = np.zeros(xyz.shape, dtype=np.float32)
    if finite.sum() < 3:
        return out
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[finite]))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=int(k)))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    out[finite] = np.asarray(pcd.normals)
    return out


def knn_method(k: int) -> str:
    """What the cloud's metadata says of normals from :func:`knn_normals`."""
    return (f"estimated from the {k} nearest neighbours (Open3D estimate_normals), "
            "oriented towards the camera")
