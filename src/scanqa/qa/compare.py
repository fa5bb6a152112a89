"""Does a part deviate from its reference more than the scan's own uncertainty?

For every point of an annotated cloud, the deviation from a reference surface along the
surface normal, the combined standard uncertainty of that deviation from both sides'
sigma, and its significance |deviation| / U with U = k u (the "level of detection" of
M3C2 with precision maps, here with the scanner's own per-point sigma):

* a reference **cloud** (e.g. another scan, or the truth of a simulated one): the plane
  fitted to the point's ``neighbours`` nearest reference points gives the normal and the
  foot; its uncertainty is the reference points' sigma (their ``sigma_total_um``, if
  they carry one, else ``reference_sigma_mm``) over sqrt(neighbours). A neighbourhood
  that is not a plane (an edge, a gap: RMS about its plane above ``max_roughness_mm``)
  gives no deviation (NaN): there is no surface to compare with;
* a reference **mesh** (trimesh): the closest point and its face normal, with
  ``reference_sigma_mm`` (the mesh's own form uncertainty; 0 for a nominal CAD).

The point's own sigma along the normal is ``sigma_total_um`` x |cos| of its line of sight
to the normal. Points beyond ``max_distance_mm`` from the reference are left out (NaN).

What U is made of (:func:`u_by_term`): the scan's sigma_total splits into its random part
(``sigma_random_um``), its calibration term (``sigma_calibration_um``) and the rest (the
config's systematic term), each projected on the normal like the total, beside the
reference's u_ref; the summary gives each one's median expanded uncertainty k u over
the judged points, the dominant one, and the smallest deviation the comparison can call
significant (U at the median point, and at the best 5 % of points).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.numeric import json_ready
from scanqa.qa.blocks import refuse_bad_sigmas
from scanqa.qa.verdict import decide

#: Attributes a comparison adds to the cloud (units in the names).
COMPARE_ATTRIBUTES = ("deviation_um", "u_deviation_um", "U_deviation_um", "significance",
                      "significant")


@dataclass(frozen=True)
class Comparison:
    """Per-point deviations from a reference and their summary.

    Attributes
    ----------
    cloud : AnnotatedCloud
        The scan with :data:`COMPARE_ATTRIBUTES` added (and ``in_tolerance`` with a
        tolerance).
    k : float
        Coverage factor of U [-].
    tolerance_mm : float or None
        The spec's tolerance on |deviation| [mm].
    reference : str
        What the reference was (its file and kind).
    """

    cloud: AnnotatedCloud
    k: float
    tolerance_mm: float | None
    reference: str
    notes: tuple[str, ...] = field(default=())
    alignment: dict | None = None  # the best fit (scanqa.qa.align), when there was one
    u_terms: dict = field(default_factory=dict)

    def deviation_limit_um(self, percentile: float = 99.0) -> float:
        """Colour-scale limit of the deviation map: the ``percentile`` of |deviation| over
        the compared points [um], 1.0 when all are 0 (NaN when none was compared).

        Parameters
        ----------
        percentile : float
            Percentile of |deviation| [%].
        """
        dev = np.asarray(self.cloud.attributes["deviation_um"], float)
        dev = dev[np.isfinite(dev)]
        return float(np.percentile(np.abs(dev), percentile)) or 1.0 if dev.size else math.nan

    def summary(self) -> dict:
        """JSON-ready statistics of the compared points [um]."""
        a = self.cloud.attributes
        dev = np.asarray(a["deviation_um"], float)
        ok = np.isfinite(dev)
        judged = np.isfinite(np.asarray(a["significance"], float))
        sig = np.asarray(a["significant"])[judged] > 0
        out = {"format": "scanqa-compare/1", "reference": self.reference, "k": self.k,
               "points": int(dev.size), "compared": int(ok.sum()),
               "not_compared": int((~ok).sum()),
               "compared_without_sigma": int((ok & ~judged).sum()),
               "median_deviation_um": json_ready(np.median(dev[ok])) if ok.any() else None,
               "rms_deviation_um": json_ready(np.sqrt(np.mean(dev[ok] ** 2))) if ok.any() else None,
               "p95_abs_deviation_um": json_ready(np.percentile(np.abs(dev[ok]), 95))
               if ok.any() else None,
               "median_U_um": json_ready(np.median(np.asarray(a["U_deviation_um"])[judged]))
               if judged.any() else None,
               "significant_fraction": json_ready(sig.mean()) if judged.any() else None,
               "sigma_source": self.cloud.sigma_source, "notes": list(self.notes)}
        if self.alignment is not None:
            out["alignment"] = self.alignment
        out.update(self.u_terms)
        if self.tolerance_mm is not None:
            inside = np.asarray(a["in_tolerance"])[ok]
            out["tolerance_um"] = 1e3 * self.tolerance_mm
            out["out_of_tolerance_fraction"] = json_ready(1 - inside.mean()) if ok.any() else None
            out["verdict"] = _verdict(dev[judged], np.asarray(a["U_deviation_um"])[judged],
                                      1e3 * self.tolerance_mm)
        return out


def _verdict(dev_um: np.ndarray, big_u_um: np.ndarray, tol_um: float) -> str:
    """ISO 14253-1 (:func:`scanqa.qa.verdict.decide`) on the worst points: fail when the
    point farthest beyond T + U fails, pass when the point nearest to T - U passes (then
    every point does), else undecided; a non-finite point is never a pass."""
    if dev_um.size == 0:
        return "not evaluated"
    dev_um, big_u_um = np.broadcast_arrays(np.asarray(dev_um, float),
                                           np.asarray(big_u_um, float))
    ok = np.isfinite(dev_um) & np.isfinite(big_u_um)
    if ok.any():
        worst = np.flatnonzero(ok)[np.argmax(np.abs(dev_um[ok]) - big_u_um[ok])]
        if decide(dev_um[worst], big_u_um[worst], tol_um) == "fail":
            return "fail"
    if not ok.all():
        return "undecided"
    nearest = int(np.argmax(np.abs(dev_um) + big_u_um))
    return "pass" if decide(dev_um[nearest], big_u_um[nearest], tol_um) == "pass" \
        else "undecided"


def compare_to_cloud(cloud: AnnotatedCloud, reference: AnnotatedCloud, k: float = 2.0,
                     neighbours: int = 16, reference_sigma_mm: float = 0.0,
                     max_distance_mm: float = 1.0, max_roughness_mm: float | None = None,
                     tolerance_mm: float | None = None, name: str = "reference cloud",
                     alignment=None) -> Comparison:
    """Deviations of ``cloud`` from a reference cloud (module notes).

    Parameters
    ----------
    cloud, reference : AnnotatedCloud
        The scan (with ``sigma_total_um``) and the reference [mm].
    k : float
        Coverage factor [-].
    neighbours : int
        Reference points per local plane [-].
    reference_sigma_mm : float
        Sigma of each reference point when it carries none [mm].
    max_distance_mm : float
        Farther from the nearest reference point: not compared [mm].
    max_roughness_mm : float, optional
        RMS of the neighbours about their plane above which the neighbourhood is no
        surface [mm]; default 3 x the reference points' sigma + 5 um.
    tolerance_mm : float, optional
        Tolerance on |deviation| for the verdict [mm].
    name : str
        The reference, for the summary.
    alignment : scanqa.qa.align.Alignment, optional
        The best fit that moved ``reference`` into the scan's frame: its uncertainty
        joins each point's u (:meth:`~scanqa.qa.align.Alignment.deviation_sigma_mm`).

    Notes
    -----
    d_i = (p_i - c_i) . n_i to the plane of the ``neighbours`` nearest reference points;
    u_i^2 = (sigma_i |l_i . n_i|)^2 + u_ref,i^2 with u_ref,i the reference sigma over
    sqrt(neighbours) (GUM 5.1.2, Eq. 10), U_i = k u_i and significance |d_i| / U_i, the
    level of detection of M3C2 with precision maps (docs/compare.rst).
    """
    from scipy.spatial import cKDTree

    _check(cloud, k, neighbours, reference_sigma_mm, max_distance_mm, tolerance_mm)
    ref = np.asarray(reference.xyz, float)
    ref_ok = np.isfinite(ref).all(axis=1)
    ref = ref[ref_ok]
    if len(ref) < neighbours:
        raise InputError(f"{name} has {len(ref)} finite points, fewer than the {neighbours} "
                         "a local plane needs")
    ref_sigma = _reference_sigma(reference, ref_ok, reference_sigma_mm)
    rough = max_roughness_mm if max_roughness_mm is not None else \
        3.0 * float(np.nanmedian(ref_sigma)) + 0.005
    pts = np.asarray(cloud.xyz, float)
    finite = np.isfinite(pts).all(axis=1)
    dist, nn = cKDTree(ref).query(np.where(finite[:, None], pts, 0.0), k=neighbours,
                                  workers=-1)
    local = ref[nn]                                               # (n, k, 3)
    centre = local.mean(axis=1)
    _, svals, vt = np.linalg.svd(local - centre[:, None, :], full_matrices=False)
    normal = vt[:, 2, :]
    normal *= -np.sign(np.einsum("ij,ij->i", normal, centre))[:, None]  # towards the camera
    rms = svals[:, 2] / math.sqrt(neighbours)
    dev = np.einsum("ij,ij->i", pts - centre, normal)
    # a neighbourhood of coincident or collinear points defines no plane: no normal
    planar = svals[:, 1] > 1e-6 * np.maximum(svals[:, 0], 1e-12)
    near = finite & (dist[:, 0] <= max_distance_mm) & (rms <= rough) & planar
    u_ref = np.sqrt(np.mean(ref_sigma[nn] ** 2, axis=1) / neighbours)
    notes = [] if ref_sigma.any() else ["the reference carries no sigma: taken as exact "
                                        "(give --reference-sigma-um)"]
    return _finish(cloud, np.where(near, dev, np.nan), normal, u_ref, k, tolerance_mm,
                   f"{name} ({len(ref)} points, planes of {neighbours})", notes, alignment)


def compare_to_mesh(cloud: AnnotatedCloud, mesh, k: float = 2.0,
                    reference_sigma_mm: float = 0.0, max_distance_mm: float = 1.0,
                    tolerance_mm: float | None = None, name: str = "reference mesh",
                    alignment=None) -> Comparison:
    """Deviations of ``cloud`` from a trimesh mesh along the closest face's normal.

    Notes
    -----
    d_i = (p_i - f_i) . n_i to the closest face (foot f_i, face normal n_i);
    u_i^2 = (sigma_i |l_i . n_i|)^2 + sigma_ref^2 (GUM 5.1.2, Eq. 10), U_i = k u_i,
    significance |d_i| / U_i (docs/compare.rst). ``alignment`` as in
    :func:`compare_to_cloud`.
    """
    import open3d as o3d  # its ray-casting scene: closest points on millions of faces

    _check(cloud, k, 3, reference_sigma_mm, max_distance_mm, tolerance_mm)
    pts = np.asarray(cloud.xyz, float)
    finite = np.isfinite(pts).all(axis=1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    query = o3d.core.Tensor(np.where(finite[:, None], pts, 0.0).astype(np.float32))
    found = scene.compute_closest_points(query)
    face = found["primitive_ids"].numpy().astype(np.int64)
    normal = np.asarray(mesh.face_normals)[face]
    # the foot in float64 from the face's plane (the ray caster works in float32)
    foot = np.asarray(mesh.vertices)[np.asarray(mesh.faces)[face, 0]]
    dev = np.einsum("ij,ij->i", pts - foot, normal)
    dist = np.linalg.norm(pts - found["points"].numpy(), axis=1)
    # a degenerate face (zero area) has no normal
    near = finite & (dist <= max_distance_mm) & (np.linalg.norm(normal, axis=1) > 0.5)
    return _finish(cloud, np.where(near, dev, np.nan), normal,
                   np.full(len(pts), reference_sigma_mm), k, tolerance_mm,
                   f"{name} ({len(mesh.faces)} faces)", [], alignment)


def _reference_sigma(reference: AnnotatedCloud, ok: np.ndarray, given_mm: float
                     ) -> np.ndarray:
    """Each reference point's sigma [mm]: its sigma_total_um, else ``given_mm``."""
    a = reference.attributes
    if "sigma_total_um" in a:
        sig = 1e-3 * np.asarray(a["sigma_total_um"], float)[ok]
        return np.where(np.isfinite(sig), sig, given_mm)
    return np.full(int(ok.sum()), given_mm)


def _finish(cloud: AnnotatedCloud, dev: np.ndarray, normal: np.ndarray, u_ref: np.ndarray,
            k: float, tolerance_mm: float | None, reference: str, notes: list,
            alignment=None) -> Comparison:
    pts = np.asarray(cloud.xyz, float)
    if alignment is not None:  # the best fit's own uncertainty (scanqa.qa.align)
        u_ref = np.hypot(u_ref, alignment.deviation_sigma_mm(pts, normal))
        notes = [*notes, alignment.note()]
    ray = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", ray, normal))
    own = 1e-3 * np.asarray(cloud.attributes["sigma_total_um"], float) * cos
    u = np.sqrt(own**2 + u_ref**2)
    big_u = k * u
    with np.errstate(invalid="ignore", divide="ignore"):
        significance = np.abs(dev) / big_u
    extra = {"deviation_um": 1e3 * dev, "u_deviation_um": 1e3 * u,
             "U_deviation_um": 1e3 * big_u, "significance": significance,
             "significant": np.where(np.isfinite(significance), significance > 1, np.nan)}
    if tolerance_mm is not None:
        extra["in_tolerance"] = np.where(np.isfinite(dev), np.abs(dev) <= tolerance_mm,
                                         np.nan)
    extra = {n: np.asarray(v, np.float32) for n, v in extra.items()}
    if not np.isfinite(dev).any():
        raise InputError(f"no point of the cloud lies within reach of a surface of the "
                         f"{reference} (check that both share one frame, in mm, that the "
                         "reference is a surface - not coincident, collinear points or "
                         "zero-area faces - or raise max_distance_mm)")
    if not np.isfinite(significance).any():
        raise InputError(f"none of the {int(np.isfinite(dev).sum())} compared points has a "
                         "usable uncertainty (their sigma_total_um is NaN, or 0 against an "
                         "exact reference): annotate the cloud with scanqa annotate inside "
                         "the calibrated volume, or give the reference's sigma")
    return Comparison(cloud.with_attributes(**extra), k, tolerance_mm, reference,
                      tuple(notes), alignment.summary() if alignment is not None else None,
                      u_by_term(cloud, cos, u_ref, k, np.isfinite(significance)))


def u_by_term(cloud: AnnotatedCloud, cos: np.ndarray, u_ref: np.ndarray, k: float,
              judged: np.ndarray) -> dict:
    """What the expanded uncertainty U of the judged points is made of (module notes).

    Parameters
    ----------
    cloud : AnnotatedCloud
        The scan (``sigma_total_um``; ``sigma_random_um`` and ``sigma_calibration_um`` when
        it has them).
    cos : (n,) float
        |cos| of each point's line of sight to the normal [-].
    u_ref : (n,) float
        The reference's standard uncertainty at each point [mm].
    k : float
        Coverage factor [-].
    judged : (n,) bool
        The points with a significance.

    Returns
    -------
    dict
        ``median_U_by_term_um``: {"random", "calibration", "systematic", "reference"}:
        the median of k x each term [um] (None for a term the cloud does not carry);
        ``dominant_U_term``; ``smallest_significant_deviation_um``: {"median_point",
        "best_5_percent"}: the U of the median point and the 5th percentile of U [um].

    Notes
    -----
    U_i = k sqrt((sigma_total,i |cos_i|)^2 + u_ref,i^2) (GUM 6.2.1); each term's share is
    k |cos_i| times its own sigma, the systematic one what sigma_total leaves after the
    random and calibration terms, sqrt(sigma_total^2 - sigma_random^2 - sigma_calibration^2)
    (docs/formats.rst). A deviation below U_i cannot be called significant at that point.
    """
    if not judged.any():
        return {}
    a = cloud.attributes
    total = np.asarray(a["sigma_total_um"], float)[judged]
    parts = {name: np.asarray(a[attr], float)[judged] if attr in a else None
             for name, attr in (("random", "sigma_random_um"),
                                ("calibration", "sigma_calibration_um"))}
    known = sum(np.nan_to_num(p) ** 2 for p in parts.values() if p is not None)
    parts["systematic"] = np.sqrt(np.clip(total**2 - known, 0.0, None)) if any(
        p is not None for p in parts.values()) else None
    scale = k * np.asarray(cos, float)[judged]
    terms = {name: None if p is None else float(np.median(scale * np.nan_to_num(p)))
             for name, p in parts.items()}
    terms["reference"] = float(np.median(k * 1e3 * np.asarray(u_ref, float)[judged]))
    big_u = k * np.sqrt((1e-3 * total * cos[judged]) ** 2 + u_ref[judged] ** 2) * 1e3
    given = {n: v for n, v in terms.items() if v is not None}
    return {"median_U_by_term_um": terms,
            "dominant_U_term": max(given, key=given.get),
            "smallest_significant_deviation_um": {
                "median_point": float(np.median(big_u)),
                "best_5_percent": float(np.percentile(big_u, 5))}}


def _check(cloud: AnnotatedCloud, k: float, neighbours: int, ref_sigma: float,
           max_distance: float, tolerance: float | None) -> None:
    if "sigma_total_um" not in cloud.attributes:
        raise InputError("the cloud has no sigma_total_um: compare needs the scan's own "
                         "per-point sigma (annotate it with scanqa annotate)")
    refuse_bad_sigmas(cloud.attributes["sigma_total_um"], "sigma_total_um")
    checks = (("k", k, 0.0), ("max distance", max_distance, 0.0))
    for what, value, bound in checks:
        if not (math.isfinite(value) and value > bound):
            raise InputError(f"{what} must be > {bound:g}, got {value!r}")
    if not (math.isfinite(ref_sigma) and ref_sigma >= 0):
        raise InputError(f"reference sigma must be >= 0 mm, got {ref_sigma!r}")
    if not (isinstance(neighbours, int) and neighbours >= 3):
        raise InputError(f"neighbours must be a whole number >= 3, got {neighbours!r}")
    if tolerance is not None and not (math.isfinite(tolerance) and tolerance > 0):
        raise InputError(f"tolerance must be > 0 mm, got {tolerance!r}")
