"""VDI/VDE 2634 Part 2 acceptance quantities with their uncertainties and decisions.

Quantities (test values E, all in mm here, um in reports):

- PF, probing error form: the range (max - min) of the radial distances of the points
  from the least-squares (Gaussian) sphere with free radius.
- PS, probing error size: the least-squares diameter minus the sphere's calibrated
  diameter (same fit, same points as PF).
- SD, sphere-spacing error: the measured centre distance of a ball bar (least-squares
  spheres with free radii) minus the calibrated distance, one value per bar position.
- F, flatness measurement error: the range of the signed orthogonal distances of the
  points from the least-squares plane.

Point selection. The guideline lets up to 0.3 % of the points be removed before a form
range is taken. Here that rule is on by default for PF, PS and F (``drop_fraction`` =
0.003; 0 turns it off): the floor(0.003 n) points with the largest |residual| from the
least-squares fit of all n points are removed and the fit is repeated on the rest, whose
range is the test value; PS comes from that second fit. SD uses every point of both
spheres by default (the rule is stated for the form quantities); ``drop_fraction`` lets
the same rule be applied. The minimum-zone sphere and plane of the kept points are
computed beside (never instead of) the least-squares ones.

Per-point sigmas. A scan's sigma is along the line of sight (from the scanner's origin,
the camera); the fits need it along the surface normal: sigma_n = sigma |l . n| with l
the unit line of sight and n the normal (the radial direction of a sphere). Pass
``view_origin=None`` when the sigmas are already along the normal. Missing sigmas (NaN)
are replaced by the RMS residual.

Standard uncertainty u (GUM, first order) and U = k u (k = 2 by default; plus |b| below):

- PS: u^2 = 4 u(R)^2 + (U_cert / k_cert)^2; u(R) from the sphere's covariance (per-point
  sigmas, noise-correlation factor included; :mod:`scanqa.qa.sphere`); U_cert the
  certificate's expanded uncertainty of the diameter at its coverage factor k_cert.
- SD: u^2 = u(L)^2 + (U_cert / k_cert)^2 with u(L) from both centres' covariances
  (:mod:`scanqa.qa.ballbar`).
- PF, F: a range has no first-order propagation; u is the standard deviation of the test
  value over repeated scans predicted from the per-point sigmas (sampling of the extreme
  residuals, :func:`~scanqa.qa.form_range.predicted_range`), its variance multiplied by
  the noise-correlation factor (the largest of the sphere's), combined with the
  artefact's certified form deviation f as a rectangular contribution of half-width f:
  u^2 = kappa u_s^2 + f^2 / 3.

PS and SD also carry the predicted bias b of the least-squares spheres from noise along
the line of sight (:func:`scanqa.qa.sphere.sight_noise_bias`; 2 b_R for PS, the centres'
biases along the bar for SD). The test value is left as the guideline defines it
(uncorrected), and the bias is added to the expanded uncertainty: U = k u + |b|
(conservative; b is a fraction of u unless the points number tens of thousands).
Errors shared by the points of an artefact (a calibration table's own error field) enter
PS and SD when the caller gives their size (``u_table``); thermal expansion and other
Type B terms belong to the caller's uncertainty budget.

Predicted form error (PF and F) from the per-point sigmas: the expected range of the
kept residuals and its standard deviation u_s,
:func:`scanqa.qa.form_range.predicted_range` (re-exported here).

Two uncertainties, two uses. U above is the uncertainty of the test value as a
measurement of the scanner's characteristic: how far this scan's PF, PS, SD or F may lie
from the value the scanner gives on average (its own noise, predicted from the points)
and from the artefact's true value (certificate, form). It is what the closed loops
against simulator truth check. An acceptance decision is different: the scanner's noise
is part of what is tested - a noisy scan that exceeds the MPE is a failed test, not an
uncertain one - so the uncertainty of the *test* holds only what does not belong to the
scanner, the artefact's calibration and form (VDI/VDE 2634-2 names the calibration of
the test artefact as the main contribution; ISO/TS 23165 likewise leaves the
instrument's own errors out of the test uncertainty):

    U_test = k u_artefact,   u_artefact = (U_cert / k_cert) for PS and SD,
                             f / sqrt(3) for PF and F (certified form f).

Decisions (ISO 14253-1) against an MPE use U_test by default ("pass" when
|E| <= MPE - U_test, "fail" when |E| > MPE + U_test, otherwise "undecided");
``decide_with="total"`` uses U instead (a lab's guard band that also covers the
scan-to-scan spread). "not evaluated" when E or the MPE is missing (the quantity could
not be measured, or the spec gives no MPE or certificate for it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from scanqa.errors import InputError
from scanqa.io.spec import Spec
from scanqa.qa.ballbar import BallBarFit, centre_distance
from scanqa.qa.flat import ZonePlane, minimum_zone_plane
from scanqa.qa.form_range import predicted_range
from scanqa.qa.planes import PlaneFit, fit_plane
from scanqa.qa.sphere import (
    MIN_COVERAGE,
    Correlation,
    MinimumZoneSphere,
    SphereFit,
    check_points,
    fit_sphere,
    minimum_zone_sphere,
    sight_noise_bias,
)
from scanqa.qa.verdict import decide

#: Fraction of the points the guideline lets be removed before a form range [-].
DROP_FRACTION = 0.003
#: Which expanded uncertainty the decisions use (module notes).
DECIDE_WITH = ("test", "total")
#: The quantities and their names.
#: The note of a quantity measured without a spec (no MPE, no certificate).
NO_SPEC = "no spec: not evaluated"
QUANTITIES = {"PF": "probing error form", "PS": "probing error size",
              "SD": "sphere-spacing error", "F": "flatness measurement error"}


@dataclass(frozen=True)
class Quantity:
    """One VDI/VDE 2634-2 test value with its uncertainty and decision (lengths in mm).

    Attributes
    ----------
    name : str
        "PF", "PS", "SD" or "F".
    value : float
        Test value E [mm]; NaN when not measured.
    u : float
        Standard uncertainty [mm] (module notes).
    k : float
        Coverage factor of U [-].
    mpe : float
        Maximum permissible error [mm]; NaN when the spec gives none.
    decision : str
        One of :data:`scanqa.qa.verdict.DECISIONS`.
    predicted : float
        Predicted value from the per-point sigmas [mm] (PF, F), else NaN.
    length : float
        Calibrated length the MPE was taken at (SD) [mm], else NaN.
    n_points, n_dropped : int
        Points measured and points removed by the 0.3 % rule [-].
    bias : float
        Predicted bias of the test value from noise along the line of sight, not
        corrected, added to U [mm] (PS, SD; module notes).
    note : str
        Why the quantity is not evaluated, or what it rests on.
    u_artefact : float
        The artefact's part of u (certificate, form): the test uncertainty [mm].
    decided_with : str
        "test" (the decision used U_test) or "total" (it used U).
    measured : float
        The fitted size E compares with the certificate (PS: the least-squares
        diameter D_a) [mm], measured with or without a certificate; else NaN.
    """

    name: str
    value: float
    u: float
    k: float
    mpe: float
    decision: str
    predicted: float = math.nan
    length: float = math.nan
    n_points: int = 0
    n_dropped: int = 0
    bias: float = 0.0
    note: str = ""
    u_artefact: float = 0.0
    decided_with: str = "test"
    measured: float = math.nan

    @property
    def expanded(self) -> float:
        """Expanded uncertainty U = k u + |bias| of the test value [mm] (module notes)."""
        return self.k * self.u + abs(self.bias)

    @property
    def expanded_test(self) -> float:
        """Test uncertainty U_test = k u_artefact, used by the decision [mm]."""
        return self.k * self.u_artefact

    @property
    def u_points(self) -> float:
        """The points' part of u: the predicted scan-to-scan std [mm]."""
        return math.sqrt(max(self.u**2 - self.u_artefact**2, 0.0))

    def row(self) -> dict:
        """The values for a report table, lengths in um."""
        def um(v: float) -> float:
            return round(1e3 * v, 3) if math.isfinite(v) else math.nan

        return {"quantity": self.name, "name": QUANTITIES[self.name],
                "value_um": um(self.value), "U_um": um(self.expanded),
                "U_test_um": um(self.expanded_test), "u_points_um": um(self.u_points),
                "k": self.k, "mpe_um": um(self.mpe), "decision": self.decision,
                "decided_with": self.decided_with,
                "predicted_um": um(self.predicted), "bias_um": um(self.bias),
                "length_mm": self.length, "measured_mm": self.measured,
                "n_points": self.n_points, "n_dropped": self.n_dropped, "note": self.note}


@dataclass(frozen=True)
class SphereTest:
    """PF and PS of one sphere: the fits on the kept points and the two quantities."""

    fit: SphereFit
    zone: MinimumZoneSphere
    kept: np.ndarray  # (n,) bool over the input points
    pf: Quantity
    ps: Quantity


@dataclass(frozen=True)
class BallBarTest:
    """SD at one ball-bar position."""

    bar: BallBarFit
    sd: Quantity


@dataclass(frozen=True)
class FlatTest:
    """F of one flat: the least-squares plane and the minimum zone of the kept points."""

    plane: PlaneFit
    zone: ZonePlane
    kept: np.ndarray  # (n,) bool over the input points
    f: Quantity


def quantity(name: str, value: float, u: float, mpe: float, k: float = 2.0,
             bias: float = 0.0, note: str = "", u_artefact: float = 0.0,
             decide_with: str = "test", **extra) -> Quantity:
    """A :class:`Quantity` with its decision (lengths [mm]).

    ``u`` is the combined standard uncertainty (points and artefact), ``u_artefact``
    the artefact's part; the decision uses k u_artefact (``decide_with="test"``) or
    k u + |bias| ("total"). ``note`` says what is missing when it is not evaluated.

    Notes
    -----
    U = k u + |b| (GUM 6.2.1, with the uncorrected bias b added, module notes); the decision
    is the ISO 14253-1 rule of :func:`scanqa.qa.verdict.decide` with U_test = k u_artefact
    ("test", the test uncertainty of VDI/VDE 2634-2 and ISO/TS 23165) or U ("total").
    """
    if decide_with not in DECIDE_WITH:
        raise InputError(f"decide_with must be one of {', '.join(DECIDE_WITH)}, "
                         f"got {decide_with!r}")
    if not (math.isfinite(k) and k > 0):
        raise InputError(f"{name}: the coverage factor k must be finite and > 0, got {k!r}")
    for what, v in (("u", u), ("u_artefact", u_artefact)):
        if v < 0:  # NaN passes: a quantity that could not be measured
            raise InputError(f"{name}: the standard uncertainty {what} must be >= 0 mm, "
                             f"got {v!r}")
    used = k * u_artefact if decide_with == "test" else k * u + abs(bias)
    decision = decide(value, used if math.isfinite(u) else math.nan, mpe)
    if decision == "not evaluated" and not note:
        note = _why_not_evaluated(value, mpe)
    return Quantity(name, float(value), float(u), float(k), float(mpe), decision,
                    bias=float(bias), note=note, u_artefact=float(u_artefact),
                    decided_with=decide_with, **extra)


def _why_not_evaluated(value: float, mpe: float) -> str:
    """The note of a quantity nothing could be decided for."""
    if not math.isfinite(value):
        return "not measured"
    if not math.isfinite(mpe):
        return "no MPE for it in the spec"
    return "its uncertainty is not finite (NaN or infinite u, U_test or bias)"


def normal_sigma(points, sigma, normals, view_origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Per-point sigma along the surface normal.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    sigma : (n,) float or float
        Standard deviation along the line of sight from ``view_origin`` [mm].
    normals : (n, 3) or (3,) float
        Unit surface normals [-].
    view_origin : (3,) float or None
        Where the lines of sight start (the camera: the scanner frame's origin) [mm];
        None when ``sigma`` is already along the normal.

    Returns
    -------
    (n,) float
        sigma |l . n| [mm]; NaN where sigma, a point or a normal is NaN or infinite, or
        where a point sits at ``view_origin`` (no line of sight).

    Notes
    -----
    sigma_n,i = sigma_i |l_i . n_i|, l_i = (p_i - o) / |p_i - o|: the projection of a
    displacement along the line of sight onto the normal, the sensitivity coefficient of
    GUM 5.1.3 for a residual measured along n (module notes).
    """
    pts = np.asarray(points, dtype=float)
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (len(pts),))
    if view_origin is None:
        return sig.copy()
    los = pts - np.asarray(view_origin, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):  # a point at the origin: NaN
        los /= np.linalg.norm(los, axis=1, keepdims=True)
    return sig * np.abs(np.sum(los * normals, axis=1))


def _kept(residuals: np.ndarray, drop_fraction: float) -> np.ndarray:
    if not 0.0 <= drop_fraction < 0.5:
        raise InputError(f"drop_fraction must be in [0, 0.5), got {drop_fraction!r}")
    n_drop = math.floor(drop_fraction * residuals.size + 1e-9)
    keep = np.ones(residuals.size, dtype=bool)
    if n_drop:
        keep[np.argsort(-np.abs(residuals), kind="stable")[:n_drop]] = False
    return keep


def _sigmas(pts, sigma, normals, view_origin, residuals) -> np.ndarray | None:
    """Sigmas along the normals, NaN ones replaced by the RMS residual [mm]."""
    if sigma is None:
        return None
    sig = normal_sigma(pts, sigma, normals, view_origin)
    return np.where(np.isfinite(sig), sig, float(np.sqrt(np.mean(residuals**2))))


def _fit_kept_sphere(points, sigma, drop_fraction, correlation, view_origin, min_coverage,
                     where):
    """The sphere of the points kept by the 0.3 % rule, the sigmas of all points along
    the normals, and the fit's predicted bias from noise along the line of sight."""
    pts = check_points(points, where, 5)
    first = fit_sphere(pts, min_coverage=min_coverage, where=where)
    keep = _kept(first.residuals, drop_fraction)
    radial = (pts - first.centre) / np.linalg.norm(pts - first.centre, axis=1, keepdims=True)
    sig = _sigmas(pts, sigma, radial, view_origin, first.residuals)
    fit = fit_sphere(pts[keep], None if sig is None else sig[keep], correlation,
                     min_coverage=min_coverage, where=where)
    bias = np.zeros(4)
    if sigma is not None and view_origin is not None:
        los = np.broadcast_to(np.asarray(sigma, dtype=float), (len(pts),))[keep]
        los = np.where(np.isfinite(los), los, 0.0)
        bias = sight_noise_bias(pts[keep], fit.centre, fit.radius, los, view_origin)
    return pts, keep, sig, fit, bias


def _form(name, residuals, sig, keep, kappa, form_um, mpe, k, decide_with) -> Quantity:
    """PF or F: range of the kept residuals, its prediction and u (module notes)."""
    n, n_drop = keep.size, int(keep.size - keep.sum())
    rms = float(np.sqrt(np.mean(residuals**2)))
    base = np.full(n, rms) if sig is None else sig
    pred, u_s = predicted_range(base, n_drop)
    u_form = 0.0 if form_um is None else 1e-3 * form_um / math.sqrt(3.0)
    u = math.sqrt(kappa * u_s**2 + u_form**2)
    note = "u from the per-point sigmas" if sig is not None else \
        "no per-point sigma: u from the residuals' scatter, no prediction"
    return quantity(name, float(np.ptp(residuals)), u, mpe, k,
                    predicted=pred if sig is not None else math.nan,
                    n_points=n, n_dropped=n_drop, note=note, u_artefact=u_form,
                    decide_with=decide_with)


def _check_u_table(u_table: float, where: str) -> None:
    if not (math.isfinite(u_table) and u_table >= 0):
        raise InputError(f"{where}: the table's standard uncertainty u_table must be finite "
                         f"and >= 0 mm, got {u_table!r}")


def _mpe(spec: Spec | None, name: str, length_mm: float = 0.0) -> float:
    if spec is None or name not in spec.mpe:
        return math.nan
    return spec.mpe[name].at(length_mm)


def probing_errors(points, sigma=None, spec: Spec | None = None, k: float = 2.0,
                   drop_fraction: float = DROP_FRACTION,
                   correlation: Correlation | None = None, view_origin=(0.0, 0.0, 0.0),
                   min_coverage: float = MIN_COVERAGE, decide_with: str = "test",
                   u_table: float = 0.0, where: str = "sphere") -> SphereTest:
    """Probing errors form PF and size PS of one sphere (module notes).

    Parameters
    ----------
    points : (n, 3) float
        Points on the test sphere [mm].
    sigma : (n,) float, optional
        Per-point standard deviation along the line of sight [mm].
    spec : Spec, optional
        MPEs and the sphere's certificate; without a certificate PS is not evaluated.
    k : float
        Coverage factor of U [-].
    drop_fraction : float
        Fraction of the points removed before the range (the guideline's 0.3 %) [-].
    correlation : float, (4,) float or callable, optional
        Noise-correlation factor of the sphere fit [-] (:func:`scanqa.qa.sphere.fit_sphere`).
    view_origin : (3,) float or None
        Origin of the lines of sight [mm] (:func:`normal_sigma`).
    min_coverage : float
        Least cap coverage, fraction of a hemisphere [-].
    decide_with : {"test", "total"}
        The expanded uncertainty the decisions use (module notes).
    u_table : float
        Standard uncertainty of the radius from errors the points share (the
        calibration table's own), added to u(R) in quadrature [mm].
    where : str
        Name of the sphere in messages.

    Returns
    -------
    SphereTest

    Notes
    -----
    VDI/VDE 2634-2 (2012), probing error: PF = max_i r_i - min_i r_i and
    PS = D_a - D_cert from the least-squares sphere with free radius on the points kept by
    the 0.3 % rule. u(PS)^2 = 4 (u(R)^2 + u_table^2) + (U_cert / k_cert)^2 and
    u(PF)^2 = kappa u_s^2 + f^2 / 3 (GUM 5.1.2 Eq. 10; rectangular form f, GUM 4.3.7);
    u_s from :func:`~scanqa.qa.form_range.predicted_range`.
    """
    _check_u_table(u_table, where)
    pts, keep, sig, fit, bias = _fit_kept_sphere(points, sigma, drop_fraction, correlation,
                                                 view_origin, min_coverage, where)
    cert = None if spec is None else spec.sphere
    pf = _form("PF", fit.residuals, sig, keep, float(np.max(fit.correlation)),
               None if cert is None else cert.form_um, _mpe(spec, "PF"), k, decide_with)
    if cert is None:
        ps = quantity("PS", math.nan, math.nan, _mpe(spec, "PS"), k, n_points=keep.size,
                      note=NO_SPEC if spec is None else "no sphere certificate (calibrated "
                      "diameter) in the spec", decide_with=decide_with,
                      measured=fit.diameter)
    else:
        u_cert = 1e-3 * cert.diameter_uncertainty_um / cert.k
        ps = quantity("PS", fit.diameter - cert.diameter_mm,
                      math.hypot(2.0 * math.hypot(fit.u_radius, u_table), u_cert),
                      _mpe(spec, "PS"), k,
                      bias=2.0 * bias[3], length=cert.diameter_mm, n_points=keep.size,
                      n_dropped=int(keep.size - keep.sum()), u_artefact=u_cert,
                      decide_with=decide_with, measured=fit.diameter)
    if spec is None:  # say so first, and keep what else the note says
        rest = "" if pf.note == _why_not_evaluated(pf.value, pf.mpe) else pf.note
        pf = replace(pf, note="; ".join(n for n in (NO_SPEC, rest) if n))
    zone = minimum_zone_sphere(pts[keep], start=fit.centre, where=where)
    return SphereTest(fit, zone, keep, pf, ps)


def sphere_spacing_error(points_a, points_b, sigma_a=None, sigma_b=None,
                         spec: Spec | None = None, k: float = 2.0, drop_fraction: float = 0.0,
                         correlation: Correlation | None = None,
                         view_origin=(0.0, 0.0, 0.0),
                         min_coverage: float = MIN_COVERAGE, decide_with: str = "test",
                         u_table: float = 0.0, where: str = "ball bar") -> BallBarTest:
    """Sphere-spacing error SD at one ball-bar position (module notes).

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        Points of each ball [mm].
    sigma_a, sigma_b : (n,) float, optional
        Per-point standard deviation along the line of sight [mm].
    spec : Spec, optional
        MPE of SD and the bar's certificate; without a certificate SD is not evaluated.
    k : float
        Coverage factor of U [-].
    drop_fraction : float
        Fraction of each ball's points removed (default 0: every point) [-].
    correlation : float, (4,) float or callable, optional
        Noise-correlation factor of the sphere fits [-].
    view_origin : (3,) float or None
        Origin of the lines of sight [mm].
    min_coverage : float
        Least cap coverage of each ball, fraction of a hemisphere [-].
    decide_with : {"test", "total"}
        The expanded uncertainty the decision uses (module notes).
    u_table : float
        Standard uncertainty of each ball's centre along any direction from errors its
        points share (the calibration table's own; independent between the balls) [mm].
    where : str
        Name of the bar in messages.

    Returns
    -------
    BallBarTest

    Notes
    -----
    VDI/VDE 2634-2 (2012), sphere-spacing error: SD = L_a - L_cert, L the distance of two
    least-squares sphere centres. u(SD)^2 = u(L)^2 + 2 u_table^2 + (U_cert / k_cert)^2
    (GUM 5.1.2, Eq. 10; u(L) from :func:`scanqa.qa.ballbar.centre_distance`); the bias
    b = -g . (b_a - b_b) of the centres is added to U.
    """
    _check_u_table(u_table, where)
    both = sorted((_fit_kept_sphere(p, s, drop_fraction, correlation, view_origin,
                                    min_coverage, f"{where}, ball {w}")[3:]
                   for p, s, w in ((points_a, sigma_a, "a"), (points_b, sigma_b, "b"))),
                  key=lambda fb: fb[0].centre[0])
    (fa, ba), (fb, bb) = both
    bar = BallBarFit(fa, fb, *centre_distance(fa, fb))
    n = fa.n_points + fb.n_points
    cert = None if spec is None else spec.ball_bar
    if cert is None:
        sd = quantity("SD", math.nan, math.nan, _mpe(spec, "SD"), k, n_points=n,
                      note="no ball-bar certificate (calibrated distance) in the spec",
                      decide_with=decide_with)
    else:
        u_cert = 1e-3 * cert.distance_uncertainty_um / cert.k
        bias = float(-bar.direction @ (ba[:3] - bb[:3]))  # L = |c_a - c_b|, dL = g.(dc_a - dc_b)
        u_l = math.sqrt(bar.u_distance**2 + 2.0 * u_table**2 + u_cert**2)
        sd = quantity("SD", bar.distance - cert.distance_mm, u_l,
                      _mpe(spec, "SD", cert.distance_mm), k, bias=bias, length=cert.distance_mm,
                      n_points=n, u_artefact=u_cert, decide_with=decide_with)
    return BallBarTest(bar, sd)


def flatness_error(points, sigma=None, spec: Spec | None = None, k: float = 2.0,
                   drop_fraction: float = DROP_FRACTION, correlation: float | None = None,
                   view_origin=(0.0, 0.0, 0.0), decide_with: str = "test") -> FlatTest:
    """Flatness measurement error F of a flat (module notes).

    Parameters
    ----------
    points : (n, 3) float
        Points on the flat [mm].
    sigma : (n,) float, optional
        Per-point standard deviation along the line of sight [mm].
    spec : Spec, optional
        MPE of F and the flat's certificate (its flatness enters u).
    k : float
        Coverage factor of U [-].
    drop_fraction : float
        Fraction of the points removed before the range (the guideline's 0.3 %) [-].
    correlation : float, optional
        Noise-correlation factor kappa >= 1 of the flat's points [-].
    view_origin : (3,) float or None
        Origin of the lines of sight [mm].
    decide_with : {"test", "total"}
        The expanded uncertainty the decision uses (module notes).

    Returns
    -------
    FlatTest

    Notes
    -----
    VDI/VDE 2634-2 (2012), flatness measurement error: F = max_i r_i - min_i r_i from the
    least-squares plane of the points kept by the 0.3 % rule; u(F)^2 = kappa u_s^2 + f^2 / 3
    (rectangular form deviation f of the certificate, GUM 4.3.7; u_s from
    :func:`~scanqa.qa.form_range.predicted_range`). Every sigma 0 predicts nothing: u
    and the prediction are NaN and nothing is decided.
    """
    pts = check_points(points, "flat", 10)
    first = fit_plane(pts, "flat")
    keep = _kept(first.residuals, drop_fraction)
    plane = fit_plane(pts[keep], "flat")
    sig = _sigmas(pts, sigma, plane.normal, view_origin, first.residuals)
    kappa = 1.0 if correlation is None else float(correlation)
    if not (math.isfinite(kappa) and kappa > 0):
        raise InputError(f"flat: the noise-correlation factor must be > 0, got {correlation!r}")
    cert = None if spec is None else spec.flat
    f = _form("F", plane.residuals, sig, keep, kappa,
              None if cert is None else cert.flatness_um, _mpe(spec, "F"), k, decide_with)
    return FlatTest(plane, minimum_zone_plane(pts[keep], "flat"), keep, f)
