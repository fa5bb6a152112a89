"""The noise-correlation factor of a least-squares fit, one for every artefact family.

Neighbouring points of a scan are not independent: blur spreads one noise event over
several pixels, and at fine pixels the noise of a surface is correlated over ~0.5-1 mm.
A fit's covariance from the per-point sigmas (which assumes independence) is therefore
scaled by a factor kappa >= 1 per parameter, measured on the surface itself: the ratio of
the cluster-robust (sandwich) variance of each parameter, with tiles of ``tile_mm`` as
clusters, to the same estimate with every point its own cluster. kappa is the number of
points that share one noise event (1 for independent points); it also takes up any
residual structure of the surface (form, table errors) below the tile size.

Gauge blocks tile their plane's in-plane coordinates (squares), spheres and flats of the
VDI/VDE 2634-2 artefacts their points (cubes); the factor is the same function.
"""

from __future__ import annotations

import math

import numpy as np

from scanqa.errors import InputError

#: Tile size of the noise-correlation estimate [mm]: at least twice the correlation length
#: of the noise (~0.5-1 mm for the paper's scanner at 8 um pixels).
TILE_MM = 2.0
#: Fewest tiles (with 3 points or more) for a noise-correlation estimate [-].
MIN_TILES = 8


def tiles(coords: np.ndarray, tile_mm: float = TILE_MM) -> np.ndarray:
    """The tile of each point: cells of ``tile_mm`` from the coordinates' minimum.

    Parameters
    ----------
    coords : (n, d) float
        Coordinates of the points (in-plane for a plane, 3-D for a sphere) [mm].
    tile_mm : float
        Edge of a tile [mm].

    Returns
    -------
    (n,) int
        Tile labels 0 .. K - 1, in lexicographic order of the cells [-].

    Raises
    ------
    InputError
        No coordinates, a NaN or infinite one, or a tile edge that is not finite and > 0.

    Notes
    -----
    tile_i = cell of floor((x_i - min_j x_j) / t) per axis, t = ``tile_mm``: the clusters of
    the cluster-robust variance of :func:`noise_correlation` (Cameron and Miller (2015),
    J. Human Resources 50(2)).
    """
    coords = np.asarray(coords, dtype=float)
    if not (isinstance(tile_mm, (int, float, np.number)) and math.isfinite(tile_mm)
            and tile_mm > 0):
        raise InputError(f"noise correlation: the tile size must be finite and > 0 mm, "
                         f"got {tile_mm!r}")
    if coords.ndim != 2 or len(coords) == 0 or not np.isfinite(coords).all():
        raise InputError(f"noise correlation: the tile coordinates must be a non-empty "
                         f"(n, d) array of finite values [mm], got shape {coords.shape} with "
                         f"{int(np.sum(~np.isfinite(coords)))} not finite")
    key = np.floor((coords - coords.min(axis=0)) / tile_mm).astype(np.int64)
    _, tile = np.unique(key, axis=0, return_inverse=True)
    return tile.ravel()


def noise_correlation(jac: np.ndarray, residuals: np.ndarray, coords: np.ndarray,
                      tile_mm: float = TILE_MM, bread: np.ndarray | None = None
                      ) -> tuple[np.ndarray, int]:
    """Noise-correlation factor kappa of each fitted parameter [-] and the number of
    tiles with 3 points or more it was measured with [-].

    Parameters
    ----------
    jac : (n, p) float
        The fit's design (Jacobian of the residuals by the parameters) [-].
    residuals : (n,) float
        The fit's residuals [mm].
    coords : (n, d) float
        Coordinates the tiles are cut from [mm] (:func:`tiles`).
    tile_mm : float
        Edge of a tile [mm].
    bread : (p, p) float, optional
        inv(J^T J) when the caller has it [-].

    Returns
    -------
    kappa : (p,) float
        The factor per parameter, >= 1; NaN for every parameter when fewer than
        :data:`MIN_TILES` tiles hold 3 points or more, when a residual is NaN or infinite,
        or when every residual is 0 (no scatter to measure a factor on); the caller
        decides what stands in: gauge blocks take the points as independent and say so,
        the sphere fits use 1.
    n_tiles : int
        Tiles holding 3 points or more [-].

    Notes
    -----
    With the scores s_i = J_i r_i, B = (J^T J)^-1 and K tiles (clusters c),

        kappa_j = [B (K / (K - p)) sum_c S_c S_c^T B]_jj / [B sum_i s_i s_i^T B]_jj,

    S_c the sum of the scores of tile c, clipped at 1: the cluster-robust sandwich
    variance over the heteroscedasticity-robust one (both in [1]_). The
    small-sample factor K / (K - p) is scanqa's choice (the CR1 factor of [1]_ is
    K / (K - 1) (n - 1) / (n - p)).

    References
    ----------
    .. [1] A. C. Cameron and D. L. Miller, "A practitioner's guide to cluster-robust
       inference", J. Human Resources 50(2), 317-372 (2015).
    """
    tile = tiles(coords, tile_mm)
    counts = np.bincount(tile)
    n_tiles = int(np.sum(counts >= 3))
    p = jac.shape[1]
    if n_tiles < MIN_TILES or not np.isfinite(residuals).all():
        return np.full(p, np.nan), n_tiles
    bread = np.linalg.inv(jac.T @ jac) if bread is None else bread
    score = jac * residuals[:, None]
    per_tile = np.stack([np.bincount(tile, weights=score[:, j]) for j in range(p)], axis=1)
    meat_tiles = per_tile.T @ per_tile * counts.size / (counts.size - p)
    v_tiles = np.diag(bread @ meat_tiles @ bread)
    v_points = np.diag(bread @ (score.T @ score) @ bread)
    with np.errstate(invalid="ignore", divide="ignore"):  # all residuals 0: 0 / 0 = NaN
        return np.maximum(1.0, v_tiles / v_points), n_tiles
