"""Finding the blocks of a gauge-block artefact without a layout (``scanqa qa --auto``)."""

from __future__ import annotations

import numpy as np

from scanqa.errors import InputError
from scanqa.qa.layout import BlockSpec, Layout
from scanqa.qa.planes import fit_plane
from scanqa.qa.ransac import check_positive


def detect_blocks(xyz: np.ndarray, nominal: dict[int, float], voxel_mm: float = 0.3,
                  match_tol_mm: float = 0.5, min_points: int = 50) -> Layout:
    """Find the blocks without a layout: planar patches at distinct heights above the base.

    Open3D's RANSAC plane segmentation finds the base plate (the largest plane); every
    point gets its height above it. Peaks of the height histogram are the block tops
    (all parallel to the base), and Open3D's DBSCAN splits each height band into
    connected patches. Each nominal height is matched to the largest patch whose height
    is within ``match_tol_mm`` of it.

    Parameters
    ----------
    xyz : (n, 3) float
        Points [mm].
    nominal : dict of int to float
        Block id -> nominal height [mm].
    voxel_mm : float
        Voxel size of the down-sampling that keeps the search fast [mm].
    match_tol_mm : float
        Largest accepted |height - nominal| [mm].
    min_points : int
        Smallest patch (after down-sampling) accepted as a block top.

    Returns
    -------
    Layout
        The blocks found; regions are the bounding boxes of their patches [mm].

    Notes
    -----
    h_i = (p_i - c_base) . n_base, the height above the base plane (RANSAC, M. A. Fischler
    and R. C. Bolles (1981)); peaks of the histogram of h are the tops; DBSCAN (M. Ester et
    al. (1996)) splits each band into patches; a nominal height H matches the largest patch
    with |h - H| <= ``match_tol_mm`` (scanqa's own rule, docs/qa.rst).
    """
    import open3d as o3d

    check_positive("finding blocks", voxel_size=voxel_mm, match_tolerance=match_tol_mm,
                   **{f"nominal_height_of_block_{b}": h for b, h in nominal.items()})
    o3d.utility.random.seed(0)  # RANSAC: the same scan finds the same blocks
    pts = np.asarray(xyz, dtype=float)
    pts = pts[np.isfinite(pts).all(axis=1)]
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(voxel_mm)
    if len(pcd.points) < 3 * min_points:
        raise InputError("finding blocks: too few points to find a base plate and blocks")
    _, inliers = pcd.segment_plane(distance_threshold=0.1, ransac_n=3, num_iterations=2000)
    base_fit = fit_plane(np.asarray(pcd.points)[inliers], "base plate")
    arr = np.asarray(pcd.points)
    height = (arr - base_fit.centroid) @ base_fit.normal
    patches = []
    for peak in _height_peaks(height[height > 0.5], min_points):
        band = np.flatnonzero(np.abs(height - peak) <= 0.15)
        sub = pcd.select_by_index(band)
        labels = np.asarray(sub.cluster_dbscan(eps=3 * voxel_mm, min_points=5))
        for lab in np.unique(labels[labels >= 0]):
            members = band[labels == lab]
            if members.size >= min_points:
                patches.append((float(np.median(height[members])), arr[members]))
    blocks, used = [], set()
    for bid, h_nom in sorted(nominal.items()):
        # the largest patch within the tolerance: a block top, not a sliver of a side
        # wall that happens to lie at that height
        cands = [(-len(p), abs(h - h_nom), i) for i, (h, p) in enumerate(patches)
                 if i not in used and abs(h - h_nom) <= match_tol_mm]
        if cands:
            i = min(cands)[2]
            used.add(i)
            p = patches[i][1]
            region = (float(p[:, 0].min()), float(p[:, 0].max()), float(p[:, 1].min()),
                      float(p[:, 1].max()))
            blocks.append(BlockSpec(bid, h_nom, region, float(np.median(p[:, 2]))))
    if not blocks:
        raise InputError("finding blocks: no planar patch matches a nominal height (within "
                         f"{match_tol_mm} mm)")
    return Layout("auto", tuple(blocks), "auto")


def _height_peaks(h: np.ndarray, min_points: int, bin_mm: float = 0.02) -> list[float]:
    """Heights where the histogram has a local maximum of at least min_points [mm]."""
    h = h[h < 2000.0]  # a block top lies within 2 m of its base (bounds the histogram)
    if h.size == 0:
        return []
    edges = np.arange(h.min() - bin_mm, h.max() + 2 * bin_mm, bin_mm)
    counts, _ = np.histogram(h, edges)
    smooth = np.convolve(counts, np.ones(7), mode="same")  # +-0.06 mm window
    peaks = []
    for i in np.argsort(smooth)[::-1]:
        if smooth[i] < min_points:
            break
        centre = 0.5 * (edges[i] + edges[i + 1])
        if all(abs(centre - p) > 0.3 for p in peaks):
            peaks.append(float(centre))
    return peaks
