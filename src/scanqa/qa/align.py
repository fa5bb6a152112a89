"""Best fit of a reference onto a scan before the comparison: a rigid transform found by
point-to-plane ICP with a robust loss, and its uncertainty.

The reference (a cloud or a trimesh mesh) is moved into the scan's frame, never the scan:
the scan's per-point sigmas and lines of sight belong to the scanner frame. The transform
``x_scan = R x_ref + t`` is fitted to the scan's points (all, or those in a region) by
Gauss-Newton on the point-to-plane distances d_i = (p_i - c_i) . n_i to the moved
reference (c_i the foot on it, n_i its normal):

* each iteration re-pairs every scan point with the moved reference (the nearest
  reference point and the plane of its ``neighbours`` nearest, or the closest point on
  the mesh and its face normal), drops pairs farther than ``max_distance_mm``, and
  solves for a small motion (omega, v) [rad, mm] applied on the left in the scan frame:
  d_i(omega, v) = d_i - [p_i x n_i, n_i] . (omega, v);
* the loss is Tukey's biweight of d_i / u_i (u_i the scan point's sigma_total along the
  normal, with the reference's sigma), its scale 1.4826 x the median absolute normalised
  distance and its cut at 4.685 scales: pairs on parts that differ from the reference
  (the deviations a comparison is for) stop pulling the fit;
* the covariance of (omega, v) is (J^T W J)^-1 with W = w_i / u_i^2, times the reduced
  chi-square when it exceeds 1 (the points scatter more than their sigmas say).

A deviation then carries the alignment's own uncertainty: u_align,i^2 = J_i Sigma J_i^T
with J_i = [p_i x n_i, n_i] (:meth:`Alignment.deviation_sigma_mm`), added in quadrature to
the point's u by :func:`scanqa.qa.compare.compare_to_cloud` and ``compare_to_mesh``.
Neighbouring scan points are not independent (the calibration's errors are correlated
over ``table_corr_mm``), so Sigma from independent points is a lower bound; the fit uses
at most :data:`MAX_FIT_POINTS` points, evenly spread, which also keeps it cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.numeric import robust_std

#: Scan points used by the fit at most (every k-th of those in the region) [-].
MAX_FIT_POINTS = 100000
#: Tukey biweight cut and Huber's corner, in robust scales (95 % efficiency for normal
#: residuals) [-].
TUKEY_C, HUBER_K = 4.685, 1.345
#: Convergence: the last step's rotation [rad] and translation [mm] below these, or
#: every component of the step below this fraction of its standard uncertainty [-].
STEP_ROTATION_RAD, STEP_TRANSLATION_MM, STEP_FRACTION = 1e-9, 1e-7, 0.01
#: Farthest any scan point moves in one Gauss-Newton step [mm].
TRUST_MM = 0.2
#: The six motions of the fit, in the order of its covariance.
MOTIONS = ("rotation x", "rotation y", "rotation z", "translation x", "translation y",
           "translation z")


@dataclass(frozen=True)
class Region:
    """A box of the scan frame seen along Z: x and y limits [mm], and a name."""

    name: str
    x_mm: tuple[float, float]
    y_mm: tuple[float, float]

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Points inside the box (limits inclusive)."""
        return ((xyz[:, 0] >= self.x_mm[0]) & (xyz[:, 0] <= self.x_mm[1])
                & (xyz[:, 1] >= self.y_mm[0]) & (xyz[:, 1] <= self.y_mm[1]))


def parse_region(text: str) -> Region:
    """A region ``[NAME=]X0,X1,Y0,Y1`` [mm] (x and y limits of a box seen along Z).

    Raises
    ------
    InputError
        Not four finite numbers with X0 < X1 and Y0 < Y1.
    """
    name, _, box = text.rpartition("=")
    try:
        x0, x1, y0, y1 = (float(v) for v in box.split(","))
    except ValueError:
        raise InputError(f"region {text!r}: expected [NAME=]X0,X1,Y0,Y1 in mm, e.g. "
                         "'base=-45,45,-37.5,37.5'") from None
    if not all(math.isfinite(v) for v in (x0, x1, y0, y1)) or x0 >= x1 or y0 >= y1:
        raise InputError(f"region {text!r}: needs finite X0 < X1 and Y0 < Y1 [mm]")
    return Region(name.strip() or f"x {x0:g}..{x1:g}, y {y0:g}..{y1:g} mm", (x0, x1),
                  (y0, y1))


@dataclass(frozen=True)
class Alignment:
    """The rigid motion that takes the reference into the scan's frame, and its
    uncertainty.

    Attributes
    ----------
    rotation : (3, 3) ndarray
        R of ``x_scan = R x_ref + t`` [-].
    translation_mm : (3,) ndarray
        t [mm].
    covariance : (6, 6) ndarray
        Of a small motion applied after it in the scan frame: a turn omega [rad] about
        ``centre_mm`` and a shift v [mm].
    points : int
        Scan points that carried the fit (non-zero weight) [-].
    rms_um : float
        Weighted RMS of their point-to-plane distances after the fit [um].
    iterations : int
        Gauss-Newton iterations [-].
    region : str
        The region the fit used ("" for the whole scan).
    free : tuple of str
        Motions (:data:`MOTIONS`) the surface barely fixes: their uncertainty is more
        than half the prior's, and the fit kept them near where they were.
    centre_mm : (3,) ndarray
        The point the rotations of the covariance turn about (the fit points' centroid)
        [mm].
    """

    rotation: np.ndarray
    translation_mm: np.ndarray
    covariance: np.ndarray
    points: int
    rms_um: float
    iterations: int
    region: str = ""
    free: tuple[str, ...] = ()
    centre_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, xyz: np.ndarray) -> np.ndarray:
        """Reference points [mm] moved into the scan's frame."""
        return np.asarray(xyz, float) @ self.rotation.T + self.translation_mm

    def matrix(self) -> np.ndarray:
        """The 4 x 4 homogeneous transform (reference -> scan) [-, mm]."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.rotation, self.translation_mm
        return m

    def deviation_sigma_mm(self, xyz: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Standard uncertainty the alignment gives a deviation at each scan point
        along its normal [mm]: sqrt(J Sigma J^T), J = [(p - centre) x n, n] (module
        notes).

        Parameters
        ----------
        xyz : (n, 3) ndarray
            Scan points [mm].
        normals : (n, 3) ndarray
            Unit normals of the reference there (either sign) [-].
        """
        jac = np.concatenate([np.cross(np.asarray(xyz, float) - self.centre_mm, normals),
                              normals], axis=1)
        return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, self.covariance, jac), 0))

    def centre_shift_mm(self) -> np.ndarray:
        """How far the fit moved the reference point that lands on ``centre_mm`` [mm]."""
        return self.centre_mm - (self.centre_mm - self.translation_mm) @ self.rotation

    def rotation_vector_deg(self) -> np.ndarray:
        """The rotation as axis times angle [deg]."""
        from scipy.spatial.transform import Rotation

        return np.degrees(Rotation.from_matrix(self.rotation).as_rotvec())

    def summary(self) -> dict:
        """JSON-ready: the transform, its standard uncertainties and the fit."""
        std = np.sqrt(np.diag(self.covariance))
        return {"method": "point-to-plane ICP, Tukey biweight, sigma-weighted",
                "region": self.region or "whole scan",
                "translation_mm": [float(v) for v in self.translation_mm],
                "centre_mm": [float(v) for v in self.centre_mm],
                "centre_shift_mm": [float(v) for v in self.centre_shift_mm()],
                "u_translation_um": [float(1e3 * v) for v in std[3:]],
                "rotation_vector_deg": [float(v) for v in self.rotation_vector_deg()],
                "rotation_angle_deg": float(np.linalg.norm(self.rotation_vector_deg())),
                "u_rotation_mdeg": [float(1e3 * np.degrees(v)) for v in std[:3]],
                "matrix": [[float(v) for v in row] for row in self.matrix()],
                "covariance_rad_mm": [[float(v) for v in row] for row in self.covariance],
                "points": self.points, "rms_um": self.rms_um,
                "iterations": self.iterations, "free_motions": list(self.free)}

    def note(self) -> str:
        """One line for the report."""
        t = self.centre_shift_mm()
        return (f"reference best-fitted onto the scan ({self.region or 'whole scan'}, "
                f"{self.points} points): its centre moved by ({t[0]:.4f}, {t[1]:.4f}, "
                f"{t[2]:.4f}) mm "
                f"and turned {np.linalg.norm(self.rotation_vector_deg()):.4f} deg; its "
                "uncertainty is part of every point's u"
                + (f"; the surface barely fixes its {', '.join(self.free)} (kept near "
                   "where they were, with a large uncertainty)" if self.free else ""))


def _rodrigues(omega: np.ndarray) -> np.ndarray:
    """The rotation matrix of a rotation vector [rad]."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(omega).as_matrix()


class _CloudTarget:
    """Feet and normals on a reference cloud: the nearest point and the plane of its
    ``neighbours`` nearest (normals computed once, in the reference's frame)."""

    def __init__(self, xyz: np.ndarray, neighbours: int) -> None:
        from scipy.spatial import cKDTree

        self.xyz = xyz
        self.tree = cKDTree(xyz)
        dist, nn = self.tree.query(xyz, k=neighbours, workers=-1)
        self.spacing = float(np.median(dist[:, 1]))
        local = xyz[nn] - xyz[nn].mean(axis=1, keepdims=True)
        self.normals = np.linalg.svd(local, full_matrices=False)[2][:, 2, :]

    def pairs(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dist, j = self.tree.query(query, workers=-1)
        return self.xyz[j], self.normals[j], dist


class _MeshTarget:
    """Feet and normals on a mesh: the closest point and its face's normal."""

    def __init__(self, mesh) -> None:
        import open3d as o3d

        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                                 o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        self.vertices = np.asarray(mesh.vertices, float)
        self.faces = np.asarray(mesh.faces)
        self.face_normals = np.asarray(mesh.face_normals, float)
        self.spacing = 0.0  # a mesh is a continuous surface

    def pairs(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        import open3d as o3d

        found = self.scene.compute_closest_points(o3d.core.Tensor(query.astype(np.float32)))
        face = found["primitive_ids"].numpy().astype(np.int64)
        dist = np.linalg.norm(query - found["points"].numpy(), axis=1)
        return self.vertices[self.faces[face, 0]], self.face_normals[face], dist


def fit_alignment(cloud: AnnotatedCloud, reference, region: Region | None = None,
                  max_distance_mm: float = 5.0, neighbours: int = 16,
                  reference_sigma_mm: float = 0.0, max_iterations: int = 30) -> Alignment:
    """Fit the rigid motion that takes ``reference`` onto ``cloud`` (module notes).

    Parameters
    ----------
    cloud : AnnotatedCloud
        The scan, with ``sigma_total_um`` [mm, um].
    reference : AnnotatedCloud or trimesh.Trimesh
        The reference, in roughly the scan's frame [mm].
    region : Region, optional
        Fit on the scan's points inside it only.
    max_distance_mm : float
        Pairs farther apart are not used [mm]; larger than the misplacement.
    neighbours : int
        Reference points per local plane (cloud references) [-].
    reference_sigma_mm : float
        The reference's sigma, added to the scan's in the weights [mm].
    max_iterations : int
        Gauss-Newton iterations at most, per loss (Huber, then Tukey) [-].

    Returns
    -------
    Alignment

    Raises
    ------
    InputError
        No sigma_total_um, or too few points in reach or in the region. A surface that
        does not fix all six motions (a single plane, a sphere) is not an error: those
        motions are held and reported (``free``).

    Notes
    -----
    Point-to-plane ICP: each step solves the linearised weighted least squares
    min sum_i w_i ((R p_i + t - q_i) . n_i)^2 / sigma_i^2 for a small rotation and shift,
    with robust weights w_i (Huber, then Tukey); the covariance of the six motions is the
    inverse normal matrix scaled by the weighted residual variance (GUM 5.1.2 for the
    propagation; docs/compare.rst, "Best fit first").
    """
    if "sigma_total_um" not in cloud.attributes:
        raise InputError("the cloud has no sigma_total_um: the alignment weighs each point "
                         "by its own sigma (annotate it with scanqa annotate)")
    pts = np.asarray(cloud.xyz, float)
    sigma = 1e-3 * np.asarray(cloud.attributes["sigma_total_um"], float)
    if not (np.isfinite(sigma) & (sigma > 0)).any():
        raise InputError("the cloud's sigma_total_um is nowhere a positive number: the "
                         "alignment weighs each point by its own sigma")
    # a point outside the model's validity (NaN sigma) still has a place: the median sigma
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma,
                     np.median(sigma[np.isfinite(sigma) & (sigma > 0)]))
    use = np.isfinite(pts).all(axis=1)
    if region is not None:
        use &= region.contains(pts)
    idx = np.flatnonzero(use)
    if idx.size < 50:
        where = f"in region {region.name!r}" if region is not None else "in the scan"
        raise InputError(f"only {idx.size} scan points {where}: too few to align on")
    idx = idx[:: max(1, math.ceil(idx.size / MAX_FIT_POINTS))]
    p, sig = pts[idx], sigma[idx]
    ray = p / np.linalg.norm(p, axis=1, keepdims=True)
    if hasattr(reference, "faces"):
        target = _MeshTarget(reference)
    else:
        ref = np.asarray(reference.xyz, float)
        ref = ref[np.isfinite(ref).all(axis=1)]
        if len(ref) < neighbours:
            raise InputError(f"the reference has {len(ref)} finite points: too few to "
                             "align on")
        target = _CloudTarget(ref, neighbours)
    # the pairs' uncertainty across the line of sight: the sampling of the scan and of
    # the reference (a uniform spacing h: h / sqrt(12) each)
    lateral = math.hypot(target.spacing, _spacing(p) * math.sqrt(idx.size / use.sum())
                         ) / math.sqrt(12)
    centre = p.mean(axis=0)
    # the prior: the reference lies within about half the pairing distance of its place,
    # turned by as much at the fit's extent; a motion the surface barely fixes (a block
    # scene seen from above barely fixes its in-plane place) stays near where it was
    prior_mm = 0.5 * max_distance_mm
    extent = math.sqrt(float(np.mean(np.sum((p - centre) ** 2, axis=1))))
    prior = np.diag(np.r_[np.full(3, (extent / prior_mm) ** 2), np.full(3, prior_mm**-2)])
    rot, trans, total = np.eye(3), np.zeros(3), np.zeros(6)
    iteration = 0
    # Huber first (no pair loses all its weight while far off: the few walls that fix a
    # block scene's in-plane motion keep pulling), then Tukey from there
    for loss in ("huber", "tukey"):
        for _ in range(max_iterations):
            iteration += 1
            jac, d, w, u = _linearise(target, p, sig, lateral, ray, centre, rot, trans,
                                      max_distance_mm, reference_sigma_mm, loss)
            info = (jac * (w / u**2)[:, None]).T @ jac + prior
            step = np.linalg.solve(info, (jac * (w / u**2)[:, None]).T @ d - prior @ total)
            # a trust region: no point moves farther than TRUST_MM in one step
            reach = float(np.max(np.linalg.norm(np.cross(step[:3], p - centre) + step[3:],
                                                axis=1)))
            step *= min(1.0, TRUST_MM / reach) if reach > 0 else 1.0
            small = _rodrigues(step[:3])
            rot, trans = small @ rot, small @ (trans - centre) + centre + step[3:]
            total += step
            # converged: the step is far inside the motion's own uncertainty, or tiny
            spread = np.sqrt(np.diag(np.linalg.inv(info)))
            if (np.abs(step) < STEP_FRACTION * spread).all() or (
                    np.linalg.norm(step[:3]) < STEP_ROTATION_RAD
                    and np.linalg.norm(step[3:]) < STEP_TRANSLATION_MM):
                break
    jac, d, w, u = _linearise(target, p, sig, lateral, ray, centre, rot, trans,
                              max_distance_mm, reference_sigma_mm, "tukey")
    weights = w / u**2
    used = int((w > 0).sum())
    chi2 = float(np.sum(weights * d**2)) / max(1.0, float(w.sum()) - 6.0)
    cov = np.linalg.inv((jac * weights[:, None]).T @ jac / max(1.0, chi2) + prior)
    free = tuple(name for name, var, var0 in zip(MOTIONS, np.diag(cov),
                                                 1 / np.diag(prior), strict=True)
                 if var > 0.25 * var0)
    rms = 1e3 * math.sqrt(float(np.sum(w * d**2) / w.sum()))
    return Alignment(rot, trans, cov, used, rms, iteration,
                     region.name if region is not None else "", free, centre)


def _spacing(p: np.ndarray) -> float:
    """Median distance of points to their nearest neighbour [mm]."""
    from scipy.spatial import cKDTree

    return float(np.median(cKDTree(p).query(p, k=2, workers=-1)[0][:, 1]))


def _linearise(target, p: np.ndarray, sig: np.ndarray, lateral: float, ray: np.ndarray,
               centre: np.ndarray, rot: np.ndarray, trans: np.ndarray, max_distance: float,
               ref_sigma: float, loss: str):
    """Jacobian rows [(p - centre) x n, n], distances d, robust weights and sigmas u of the pairs of
    the scan points with the reference moved by (rot, trans)."""
    query = (p - trans) @ rot                      # scan points in the reference's frame
    foot, n_ref, dist = target.pairs(query)
    n = n_ref @ rot.T                              # normals in the scan frame
    d = np.einsum("ij,ij->i", query - foot, n_ref)
    cos = np.abs(np.einsum("ij,ij->i", ray, n))
    u = np.sqrt((sig * cos) ** 2 + lateral**2 * (1 - np.minimum(cos, 1) ** 2) + ref_sigma**2)
    u = np.maximum(u, 1e-6)
    near = (dist <= max_distance) & np.isfinite(d)
    if near.sum() < 50:
        raise InputError(f"only {int(near.sum())} scan points lie within {max_distance:g} mm "
                         "of the reference: bring it closer first or raise the alignment's "
                         "max distance")
    z = np.where(near, d / u, 0.0)
    scale = robust_std(z[near], centre=0.0)
    w = np.where(near, 1.0, 0.0)
    if scale > 0 and loss == "tukey":
        t = z / (TUKEY_C * scale)
        w = np.where(near & (np.abs(t) < 1), (1 - t**2) ** 2, 0.0)
    elif scale > 0:
        w = np.where(near, np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(z), 1e-300)),
                     0.0)
    jac = np.concatenate([np.cross(p - centre, n), n], axis=1)
    return jac, np.where(near, d, 0.0), w, u


def align_reference(cloud: AnnotatedCloud, reference, region: Region | None = None,
                    max_distance_mm: float = 5.0, neighbours: int = 16,
                    reference_sigma_mm: float = 0.0):
    """The reference moved into the scan's frame by its best fit, and the fit.

    Parameters
    ----------
    cloud : AnnotatedCloud
        The scan.
    reference : AnnotatedCloud or trimesh.Trimesh
        The reference.
    region, max_distance_mm, neighbours, reference_sigma_mm
        As :func:`fit_alignment`.

    Returns
    -------
    moved : AnnotatedCloud or trimesh.Trimesh
        The reference in the scan's frame (a copy).
    fit : Alignment

    Notes
    -----
    The reference's points (or vertices) x are moved to R x + t with the fit of
    :func:`fit_alignment` (docs/compare.rst, "Best fit first").
    """
    fit = fit_alignment(cloud, reference, region, max_distance_mm, neighbours,
                        reference_sigma_mm)
    if hasattr(reference, "faces"):
        moved = reference.copy()
        moved.apply_transform(fit.matrix())
        return moved, fit
    return AnnotatedCloud(fit.apply(reference.xyz), dict(reference.attributes),
                          dict(reference.counts), dict(reference.metadata)), fit
