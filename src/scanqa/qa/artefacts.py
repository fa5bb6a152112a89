"""VDI/VDE 2634-2 tests on an annotated cloud: find each artefact, select its points and
compute PF, PS (sphere), SD (ball bar) and F (flat) with :mod:`scanqa.qa.vdi2634`.

Artefacts come from a layout file (:func:`load_artefact_layout`, format in
:mod:`scanqa.io.artefacts`: nominal sizes and approximate positions) or are found by
RANSAC (:func:`auto_layout`: spheres of a nominal diameter, a ball bar of a nominal
distance, the largest plane).

Point selection, in this order (every count is reported):

1. *Search.* A sphere's points lie within 2 R of its approximate centre (R the nominal
   radius); RANSAC with the radius prior then finds the ball among them (a stem, the
   bar or a neighbour does not pull it). A flat's points lie in its rectangle (or the
   RANSAC plane's inliers) within ``shell_mm`` of its plane.
2. *Segmentation.* Points within ``shell_mm`` (default 5 % of the diameter) of the
   surface found. The shell only separates the artefact from other surfaces; points of
   the artefact with large errors stay (they are what PF and F measure).
3. *Grazing view* (scanqa's rule, not the guideline's). Points seen at an incidence
   above ``max_incidence_deg`` (default 70 deg: angle between the surface normal and the
   line of sight) are removed. At the silhouette of a sphere the camera blur mixes the
   ball with what lies behind it: simulated, the points at 70-75 deg are 5-25 um off the
   sphere on average and those beyond 75 deg up to 90 um, against a noise of ~6 um.
   A flat's edges are removed by an edge margin (``margin_mm``) instead.
4. *Mounting* (ball bars). The part of each ball within a cone around the bar's axis
   is removed: half-opening asin(d / D) + ``mount_margin_deg`` (d the bar's diameter,
   D/3 when the layout does not give it).
5. *The guideline's rule.* Up to 0.3 % of the points (PF, PS, F; :mod:`scanqa.qa.vdi2634`).

Per-point sigma, the oblique-view factor, the table's shared error and the noise
correlation of an artefact's points: :mod:`scanqa.qa.artefact_sigma`.
"""

from __future__ import annotations

import math
import os

import numpy as np

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud, random_sigma_name
from scanqa.io.artefacts import read_artefact_layout
from scanqa.io.spec import Spec
from scanqa.qa.artefact_sigma import (
    FRONTAL_DEG,
    incidence_cos,
    oblique_factor,
    point_sigma,
    table_uncertainty,
    tile_correlation,
)
from scanqa.qa.ballbar import find_ball_bar
from scanqa.qa.correlation import noise_correlation
from scanqa.qa.planes import fit_plane, plane_design
from scanqa.qa.ransac import find_spheres, ransac_plane, ransac_sphere
from scanqa.qa.results import (
    OBLIQUE,
    ArtefactLayout,
    ArtefactQAResult,
    ArtefactResult,
    ArtefactSpec,
    Options,
    Selection,
)
from scanqa.qa.sphere import MIN_POINTS, algebraic_sphere
from scanqa.qa.vdi2634 import flatness_error, probing_errors, sphere_spacing_error

__all__ = ["FRONTAL_DEG", "KINDS", "OBLIQUE", "ArtefactLayout", "ArtefactQAResult",
           "ArtefactResult", "ArtefactSpec", "Options", "Selection", "auto_layout",
           "evaluate_ball_bar", "evaluate_flat", "evaluate_sphere", "load_artefact_layout",
           "oblique_factor", "point_sigma", "run_artefact_qa", "select_ball_bar", "select_flat",
           "select_sphere", "table_uncertainty", "tile_correlation"]

#: Kinds of artefact, as in layouts and ``--artefact``.
KINDS = ("sphere", "ball_bar", "flat")
#: How far a flat may lie from its approximate plane and rectangle [mm].
FLAT_SEARCH_MM = 5.0


# --------------------------------------------------------------------------- layouts

def load_artefact_layout(path: str | os.PathLike) -> ArtefactLayout:
    """Read an artefact layout file (:mod:`scanqa.io.artefacts`)."""
    data = read_artefact_layout(path)
    arts = []
    for e in data["sphere"]:
        arts.append(ArtefactSpec("sphere", e["id"], e["diameter_mm"],
                                 centre_mm=e["centre_mm"], scan=e["scan"]))
    for e in data["ball_bar"]:
        arts.append(ArtefactSpec("ball_bar", e["id"], e["diameter_mm"], e["distance_mm"],
                                 e["centre_a_mm"], e["centre_b_mm"],
                                 bar_diameter_mm=e.get("bar_diameter_mm", math.nan),
                                 scan=e["scan"]))
    for e in data["flat"]:
        arts.append(ArtefactSpec("flat", e["id"], centre_mm=e["centre_mm"],
                                 normal=e["normal"], size_mm=e["size_mm"], scan=e["scan"]))
    return ArtefactLayout(data["name"], tuple(arts), data["source"])


def auto_layout(kind: str, spec: Spec | None, diameter_mm: float | None = None,
                distance_mm: float | None = None) -> ArtefactLayout:
    """A layout of one artefact to be found by RANSAC, sizes from the spec's certificates
    unless given.

    Parameters
    ----------
    kind : {"sphere", "ball_bar", "flat"}
        The artefact in the scan.
    spec : Spec, optional
        Its certificate gives the nominal diameter / distance.
    diameter_mm, distance_mm : float, optional
        Nominal ball diameter and centre distance [mm], overriding the spec's.
    """
    kind = kind.replace("-", "_")
    if kind not in KINDS:
        raise InputError(f"kind must be one of sphere, ball-bar, flat, got {kind!r}")
    if kind == "flat":
        return ArtefactLayout("found by RANSAC", (ArtefactSpec("flat", "flat"),))
    cert = None if spec is None else (spec.sphere if kind == "sphere" else spec.ball_bar)
    d = diameter_mm or (None if cert is None else cert.diameter_mm)
    if not d:
        raise InputError(f"finding a {kind.replace('_', ' ')} needs its nominal diameter: "
                         "give diameter_mm or a spec whose certificate has diameter_mm")
    if kind == "sphere":
        return ArtefactLayout("found by RANSAC", (ArtefactSpec("sphere", "sphere", d),))
    dist = distance_mm or (None if cert is None else cert.distance_mm)
    if not dist:
        raise InputError("finding a ball bar needs its nominal distance: give distance_mm "
                         "or a spec with a [ball_bar] certificate")
    return ArtefactLayout("found by RANSAC", (ArtefactSpec("ball_bar", "ball bar", d, dist),))


# ------------------------------------------------------------------ point selection

def _ball_points(xyz: np.ndarray, centre, diameter: float, shell: float, what: str,
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Indices of the points of one ball near ``centre``, its refined centre and counts."""
    r = diameter / 2.0
    near = np.flatnonzero(np.linalg.norm(xyz - np.asarray(centre), axis=1) <= 2.0 * r)
    counts = {"searched": int(near.size)}
    if near.size < MIN_POINTS:
        raise InputError(f"{what}: {near.size} points within {2 * r:g} mm of its "
                         f"approximate centre {_fmt(centre)} mm, a sphere fit needs at least "
                         f"{MIN_POINTS}: check the layout's centre and the scan")
    cand = ransac_sphere(xyz[near], r, 0.1 * r, threshold_mm=shell, min_inliers=MIN_POINTS)
    if cand is None:
        raise InputError(f"{what}: no sphere of diameter {diameter:g} mm found near "
                         f"{_fmt(centre)} mm ({near.size} points searched): check the "
                         "layout's diameter and centre")
    idx = near[np.abs(np.linalg.norm(xyz[near] - cand.centre, axis=1) - cand.radius) <= shell]
    counts["on_surface"] = int(idx.size)
    return idx, cand.centre, counts


def _drop_grazing(xyz: np.ndarray, idx: np.ndarray, centre: np.ndarray, options: Options,
                  counts: dict) -> tuple[np.ndarray, np.ndarray]:
    """Drop the points of a ball seen at more than ``max_incidence_deg``; returns the kept
    indices and the centre the incidences were taken from.

    The normals come from a least-squares sphere, refitted once on the points kept by a
    first cut (the mixed points at the silhouette pull a fit of all the points)."""
    pts = xyz[idx]
    limit = math.cos(math.radians(options.max_incidence_deg)) - 1e-12
    c = np.asarray(centre, dtype=float)
    for _ in range(2):
        n = (pts - c) / np.linalg.norm(pts - c, axis=1, keepdims=True)
        keep = incidence_cos(pts, n) >= limit
        if keep.sum() < MIN_POINTS:
            break
        c = _ls_centre(pts[keep], c)
    counts["grazing_removed"] = int(np.sum(~keep))
    return idx[keep], c


def _ls_centre(pts: np.ndarray, start: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Centre of the least-squares (orthogonal) sphere, by Gauss-Newton from ``start``."""
    c = np.asarray(start, dtype=float)
    r = float(np.mean(np.linalg.norm(pts - c, axis=1)))
    for _ in range(iterations):
        d = pts - c
        dist = np.linalg.norm(d, axis=1)
        jac = np.column_stack([-d / dist[:, None], -np.ones(len(d))])
        step, *_ = np.linalg.lstsq(jac, -(dist - r), rcond=None)
        c, r = c + step[:3], r + step[3]
        if np.max(np.abs(step)) < 1e-10:
            break
    return c


def select_sphere(xyz: np.ndarray, art: ArtefactSpec, options: Options) -> Selection:
    """The points PF and PS of a test sphere rest on (module notes, steps 1-3).

    Notes
    -----
    The point selection of the module notes (steps 1-3, docs/artefacts.rst): within 2 R of
    the approximate centre, |d_i - R| <= ``shell_mm`` of the RANSAC sphere, incidence
    acos|l_i . n_i| <= ``max_incidence_deg`` (scanqa's rule; VDI/VDE 2634-2's own 0.3 %
    rule follows in :mod:`scanqa.qa.vdi2634`).
    """
    what = f"sphere {art.id!r}"
    shell = options.shell_mm or 0.05 * art.diameter_mm
    centre = art.centre_mm
    if centre is None:
        centre = find_spheres(xyz, 1, art.diameter_mm / 2.0, what=what,
                              threshold_mm=shell)[0].centre
    idx, c, counts = _ball_points(xyz, centre, art.diameter_mm, shell, what)
    idx, _ = _drop_grazing(xyz, idx, c, options, counts)
    counts["used"] = int(idx.size)
    return Selection(idx, counts)


def select_ball_bar(xyz: np.ndarray, art: ArtefactSpec, options: Options
                    ) -> tuple[Selection, Selection]:
    """The points of each ball of a ball bar (module notes, steps 1-4).

    Notes
    -----
    Each ball as :func:`select_sphere`, less the mounting cone of half-opening
    asin(d / D) + ``mount_margin_deg`` around the bar's axis (module notes, steps 1-4,
    docs/artefacts.rst); the bar's two balls as VDI/VDE 2634-2 measures SD.
    """
    shell = options.shell_mm or 0.05 * art.diameter_mm
    if art.centre_mm is None:
        found = find_ball_bar(xyz, art.diameter_mm, art.distance_mm, threshold_mm=shell)
        centres = [algebraic_sphere(xyz[i])[0] for i in found]
    else:
        centres = [art.centre_mm, art.centre_b_mm]
    found = [_ball_points(xyz, c, art.diameter_mm, shell, f"ball bar {art.id!r}, ball {w}")
             for c, w in zip(centres, "ab", strict=True)]
    bar = art.bar_diameter_mm if math.isfinite(art.bar_diameter_mm) else art.diameter_mm / 3
    cone = math.asin(min(bar / art.diameter_mm, 1.0)) + math.radians(options.mount_margin_deg)
    cut = [_drop_grazing(xyz, idx, c, options, counts) for idx, c, counts in found]
    out = []
    for (idx, c), (_, other), (_, _, counts) in zip(cut, cut[::-1], found, strict=True):
        axis = (other - c) / np.linalg.norm(other - c)
        u = (xyz[idx] - c) / np.linalg.norm(xyz[idx] - c, axis=1, keepdims=True)
        mount = u @ axis > math.cos(cone)
        counts["mount_removed"] = int(mount.sum())
        counts["used"] = int(np.sum(~mount))
        out.append(Selection(idx[~mount], counts))
    return out[0], out[1]


def select_flat(xyz: np.ndarray, art: ArtefactSpec, options: Options) -> Selection:
    """The points F of a flat rests on (module notes, steps 1-3).

    Notes
    -----
    Points in the flat's rectangle (or the RANSAC plane's inliers) within ``shell_mm`` of
    its plane and ``margin_mm`` inside its edge (module notes, steps 1-3,
    docs/artefacts.rst), on which VDI/VDE 2634-2's F is measured.
    """
    shell = options.shell_mm or 0.5
    what = f"flat {art.id!r}"
    cand = np.arange(len(xyz))
    if art.centre_mm is not None and art.normal is not None:
        centre = np.asarray(art.centre_mm, float)
        normal = np.asarray(art.normal, float) / np.linalg.norm(art.normal)
        d = xyz - centre
        near = np.abs(d @ normal) <= FLAT_SEARCH_MM
        if art.size_mm is not None:  # in-plane axes as scanqa.simulator.scene.flat_target's
            e1 = np.cross([0.0, 1.0, 0.0], normal)
            e1 /= np.linalg.norm(e1)
            st = np.abs(d @ np.stack([e1, np.cross(normal, e1)]).T)
            near &= np.all(st <= np.asarray(art.size_mm) / 2 + FLAT_SEARCH_MM, axis=1)
        cand = np.flatnonzero(near)
    counts = {"searched": int(cand.size)}
    if cand.size < 10:
        raise InputError(f"{what}: {cand.size} points near its approximate plane, F needs "
                         "at least 10: check the layout's centre and normal")
    normal, offset, _ = ransac_plane(xyz[cand], threshold_mm=shell)
    idx = cand[np.abs(xyz[cand] @ normal - offset) <= shell]
    counts["on_surface"] = int(idx.size)
    if idx.size < 10:
        raise InputError(f"{what}: {idx.size} points within {shell:g} mm of its plane, F "
                         "needs at least 10")
    plane = fit_plane(xyz[idx], what)
    inside = _inside_hull((xyz[idx] - plane.centroid) @ plane.axes.T, options.margin_mm)
    counts["edge_removed"] = int(np.sum(~inside))
    idx = idx[inside]
    counts["used"] = int(idx.size)
    return Selection(idx, counts)


def _inside_hull(st: np.ndarray, margin: float) -> np.ndarray:
    """Points of a planar patch (in-plane coordinates) at least ``margin`` inside the
    convex hull of all of them."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(st)
    dist = -(st @ hull.equations[:, :2].T + hull.equations[:, 2])
    return dist.min(axis=1) >= margin


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.1f}" for x in np.asarray(v, float)) + "]"


# ---------------------------------------------------------------------- evaluation

def _normals_sphere(xyz: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Unit normals of a ball's points from a quick algebraic fit [-]."""
    c, _ = algebraic_sphere(xyz[idx])
    d = xyz[idx] - c
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _ball_inputs(cloud: AnnotatedCloud, sel: Selection, options: Options
                 ) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Points, per-point sigma (line of sight) and the table's u of one ball."""
    xyz = np.asarray(cloud.xyz, float)
    pts = xyz[sel.index]
    if len(pts) < MIN_POINTS:
        return pts, None, 0.0  # the fit raises the clear message
    normals = _normals_sphere(xyz, sel.index)
    sig = point_sigma(cloud, sel.index, normals, options)
    seen = math.pi * (0.5 * float(np.ptp(pts @ _plane_axes(normals), axis=0).mean())) ** 2
    return pts, sig, table_uncertainty(cloud, sel.index, seen)


def _plane_axes(normals: np.ndarray) -> np.ndarray:
    """(3, 2) two axes across the mean normal [-]."""
    n = normals.mean(axis=0)
    n /= np.linalg.norm(n)
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)], axis=1)


def evaluate_sphere(cloud: AnnotatedCloud, art: ArtefactSpec, spec: Spec | None,
                    options: Options, scan: str = "") -> ArtefactResult:
    """PF and PS of one test sphere (module notes).

    Notes
    -----
    PF and PS of VDI/VDE 2634-2 (2012) by :func:`scanqa.qa.vdi2634.probing_errors` on the
    selected points with their :func:`point_sigma`, :func:`tile_correlation` and
    :func:`table_uncertainty` (docs/artefacts.rst).
    """
    sel = select_sphere(np.asarray(cloud.xyz, float), art, options)
    pts, sig, u_tab = _ball_inputs(cloud, sel, options)
    test = probing_errors(pts, sig, spec, options.k, options.drop_fraction,
                          tile_correlation(options.tile_mm), min_coverage=options.min_coverage,
                          decide_with=options.decide_with, u_table=u_tab,
                          where=f"sphere {art.id!r}")
    return ArtefactResult(art, scan, (test.pf, test.ps), (sel,), test, u_tab,
                          float(np.max(test.fit.correlation)), pts)


def evaluate_ball_bar(cloud: AnnotatedCloud, art: ArtefactSpec, spec: Spec | None,
                      options: Options, scan: str = "") -> ArtefactResult:
    """SD of a ball bar in one position (module notes).

    Notes
    -----
    SD of VDI/VDE 2634-2 (2012) by :func:`scanqa.qa.vdi2634.sphere_spacing_error` on the
    two balls' selected points (docs/artefacts.rst).
    """
    sel_a, sel_b = select_ball_bar(np.asarray(cloud.xyz, float), art, options)
    (pa, sa, ua), (pb, sb, ub) = (_ball_inputs(cloud, s, options) for s in (sel_a, sel_b))
    test = sphere_spacing_error(pa, pb, sa, sb, spec, options.k, options.sd_drop_fraction,
                                tile_correlation(options.tile_mm),
                                min_coverage=options.min_coverage,
                                decide_with=options.decide_with, u_table=max(ua, ub),
                                where=f"ball bar {art.id!r}")
    kappa = max(float(np.max(test.bar.sphere_a.correlation)),
                float(np.max(test.bar.sphere_b.correlation)))
    return ArtefactResult(art, scan, (test.sd,), (sel_a, sel_b), test, max(ua, ub), kappa,
                          np.vstack([pa, pb]))


def evaluate_flat(cloud: AnnotatedCloud, art: ArtefactSpec, spec: Spec | None,
                  options: Options, scan: str = "") -> ArtefactResult:
    """F of one flat (module notes).

    Notes
    -----
    F of VDI/VDE 2634-2 (2012) by :func:`scanqa.qa.vdi2634.flatness_error` on the selected
    points, with the flat's noise-correlation factor (docs/artefacts.rst).
    """
    xyz = np.asarray(cloud.xyz, float)
    sel = select_flat(xyz, art, options)
    pts = xyz[sel.index]
    plane = fit_plane(pts, f"flat {art.id!r}")
    normals = np.broadcast_to(plane.normal, pts.shape)
    sig = point_sigma(cloud, sel.index, normals, options)
    design = plane_design(pts, plane)
    kappa, _ = noise_correlation(design, plane.residuals, design[:, 1:], options.tile_mm)
    k0 = float(kappa[0]) if np.isfinite(kappa[0]) else 1.0
    test = flatness_error(pts, sig, spec, options.k, options.drop_fraction, k0,
                          decide_with=options.decide_with)
    return ArtefactResult(art, scan, (test.f,), (sel,), test, 0.0, k0, pts)


EVALUATE = {"sphere": evaluate_sphere, "ball_bar": evaluate_ball_bar, "flat": evaluate_flat}


def run_artefact_qa(clouds, layout: ArtefactLayout, spec: Spec | None = None,
                    options: Options | None = None) -> ArtefactQAResult:
    """VDI/VDE 2634-2 quantities of every artefact of a layout in every scan.

    Parameters
    ----------
    clouds : sequence of (str, AnnotatedCloud)
        Scan names (matched against each artefact's ``scan``) and their clouds [mm].
    layout : ArtefactLayout
        The artefacts (:func:`load_artefact_layout` or :func:`auto_layout`).
    spec : Spec, optional
        MPEs and certificates; without them the quantities are measured, not decided.
    options : Options, optional
        Point selection and evaluation settings.

    Returns
    -------
    ArtefactQAResult

    Raises
    ------
    InputError
        An artefact that is not found, has too few points or too small a cap, or a
        layout that matches none of the scans.

    Notes
    -----
    Every artefact in every scan by :func:`evaluate_sphere`, :func:`evaluate_ball_bar` and
    :func:`evaluate_flat`: the quantities of VDI/VDE 2634-2 (2012) with their U and
    ISO 14253-1 decisions against the spec's MPEs (docs/artefacts.rst).
    """
    options = options or Options()
    clouds = list(clouds)
    results, notes = [], []
    for name, cloud in clouds:
        arts = [a for a in layout.artefacts if a.applies_to(name)]
        if not arts:
            notes.append(f"scan {name!r}: no artefact of the layout applies to it")
        for art in arts:
            results.append(EVALUATE[art.kind](cloud, art, spec, options, name))
        if random_sigma_name(cloud.attributes) is None:
            notes.append(f"scan {name!r} has no per-point sigma: u and the predicted form "
                         "come from the residuals' scatter")
    if not results:
        raise InputError(f"{layout.source or 'the layout'}: none of its artefacts applies to "
                         "the scans given (check each artefact's 'scan' against the scan "
                         "names)")
    if spec is None:
        notes.append("no spec given: the quantities are measured, not decided (give --spec "
                     "with the MPEs and the artefacts' certificates)")
    sources = [c.metadata.get("sigma_source") for _, c in clouds]
    sources = [s for s in sources if s]
    source = next((s for s in sources if s.get("warning")), sources[0] if sources else None)
    return ArtefactQAResult(tuple(results), options, spec, layout, tuple(notes), source)
