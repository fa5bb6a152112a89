"""The GUM uncertainty budget of a gauge-block step (JCGM 100:2008; docs/qa.rst).

A step's measured height difference d is compared with its reference value, the
nominal difference corrected for the blocks' thermal expansion. Its standard
uncertainty u combines, as a sum of squares of contributions |c_i| u_i:

Type A (evaluated from the data):

* the noise of block a's plane at block b's centroid and of block b's mean height,
  from the points' predicted sigmas scaled by each block's measured noise-correlation
  factor; the variance of that factor, measured over K tiles, has K - 3 degrees of
  freedom (K the block's tile count), and so has the noise term;
* the calibration's own error, one row named by where the cloud's
  ``sigma_calibration_um`` comes from (its ``sigma_source`` "calibration",
  :func:`calibration_rows`): a table's node fits' covariance scaled by their reduced
  chi-square (the calibration's residuals over its planes), with M - 4 degrees of
  freedom for a table from M planes; a parametric calibration's covariance (carried to
  the step by the "calibration geometry" line when the calibration is given, else each
  block's per-point term as its own shift); a stated std (Type B); or none, listed at 0.

Type B (from a budget file, :mod:`scanqa.io.budget`; infinite degrees of freedom):

* gauge-block certificates: u_i = (U_0 + U_1 L_i) / k_cert per block, independent,
  sensitivity 1 each (combined in quadrature);
* temperature: the reference is d_nom (1 + alpha dT); the deviation's uncertainty enters
  with c = alpha d_nom, the expansion coefficient's with c = d_nom dT;
* stage scale: a relative scale error s of the stage scales every calibrated length,
  c = d_nom per unit of s;
* flatness F of the calibration flat: the table inherits the flat's form; each block sees
  a deviation uniform within [0, F], independently, so their difference has
  u = F / sqrt(6), c = 1.

U = k u with a stated k, or k from the effective degrees of freedom
nu_eff = u^4 / sum((c_i u_i)^4 / nu_i) (Welch-Satterthwaite, GUM G.4) as the 97.5 %
quantile of Student's t (a 95 % interval).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Protocol

from scipy.stats import t as student_t

from scanqa.errors import RangeError
from scanqa.io.budget import WELCH_SATTERTHWAITE, BudgetInputs, read_budget_file
from scanqa.numeric import json_ready

#: Coverage probability of U when k comes from the degrees of freedom.
COVERAGE = 0.95


class StepGeometry(Protocol):
    """What a step's budget needs of a calibration's geometric uncertainty (e.g.
    :class:`scanqa.calibration.uncertainty.GeometryCovariance`): a name for the line's
    source, its degrees of freedom, and the std of a step between two sets of points.
    Declared here so that QA needs nothing of the calibration package."""

    name: str
    dof: float

    def step_sigma_mm(self, points_a, points_b) -> float:
        """Std of the step from the plane of ``points_a`` to the centroid of
        ``points_b`` (both (n, 3) [mm]) due to the calibration's geometry [mm]."""


@dataclass(frozen=True)
class Component:
    """One line of a budget: input standard uncertainty u in ``unit``, sensitivity c in
    um per ``unit``, degrees of freedom (inf for Type B)."""

    name: str
    kind: str
    source: str
    u: float
    unit: str
    c: float
    dof: float = math.inf

    @property
    def contribution_um(self) -> float:
        """|c| u [um]."""
        return abs(self.c) * self.u

    def row(self) -> dict:
        return {"component": self.name, "type": self.kind, "source": self.source,
                "u": self.u, "unit": self.unit, "c_um_per_unit": self.c,
                "contribution_um": self.contribution_um,
                "dof": json_ready(self.dof)}


@dataclass(frozen=True)
class Budget:
    """Components, the combined and the expanded uncertainty of one step."""

    components: tuple[Component, ...]
    k_rule: float | str = 2.0
    type_b_included: bool = False
    correction_um: float = 0.0

    @property
    def u_um(self) -> float:
        """Combined standard uncertainty [um]."""
        return math.sqrt(sum(c.contribution_um**2 for c in self.components))

    @property
    def nu_eff(self) -> float:
        """Effective degrees of freedom (Welch-Satterthwaite) [-]."""
        return welch_satterthwaite([(c.contribution_um, c.dof) for c in self.components])

    @property
    def k(self) -> float:
        """The stated k, or Student's t at 97.5 % with nu_eff degrees of freedom."""
        if self.k_rule == WELCH_SATTERTHWAITE:
            return coverage_factor(self.nu_eff)
        return float(self.k_rule)

    @property
    def expanded_um(self) -> float:
        return self.k * self.u_um

    def summary(self) -> dict:
        nu = self.nu_eff
        return {"components": [c.row() for c in self.components], "u_um": self.u_um,
                "nu_eff": json_ready(nu), "k": self.k,
                "k_rule": "welch-satterthwaite" if self.k_rule == WELCH_SATTERTHWAITE
                else "stated", "U_um": self.expanded_um,
                "type_b_included": self.type_b_included,
                "reference_correction_um": self.correction_um}


#: A step's calibration row by the cloud's ``sigma_source`` "calibration" (where its
#: ``sigma_calibration_um`` comes from): (row name, GUM type, source in words).
CALIBRATION_ROWS = {
    "table": ("calibration table", "A", "node fits over the calibration planes, scaled by "
              "their reduced chi-square"),
    "covariance": ("calibration term (covariance)", "A", "the calibration's parameter "
                   "covariance at each point (sigma_calibration_um), each block's as its "
                   "own shift"),
    "stated": ("calibration term (stated)", "B", "a std stated for the calibration "
               "(sigma_calibration_um), each block's as its own shift"),
    "none": ("calibration term (none)", "B", "the calibration carries no term of its own "
             "(sigma_source): 0 here, and U leaves the calibration's error out"),
}
#: The row of a cloud that does not say where its calibration term comes from.
UNKNOWN_CALIBRATION_ROW = ("calibration table", "A", "the cloud's sigma_calibration_um "
                           "(its source not stated), each block's as its own shift")


def calibration_rows(kind: str | None, u_um: float, dof: float,
                     geometry: Component | None = None) -> list[Component]:
    """The calibration's rows of a step's budget.

    Parameters
    ----------
    kind : str or None
        The cloud's ``sigma_source`` "calibration": "table", "covariance", "stated",
        "none" (:data:`CALIBRATION_ROWS`), None when the cloud does not say.
    u_um : float
        The step's std from the blocks' ``sigma_calibration_um`` [um] (0 for "none").
    dof : float
        Its degrees of freedom (a table's M - 4; a Type B row has infinite dof) [-].
    geometry : Component, optional
        The "calibration geometry" line: the calibration's parameter covariance carried
        to the step (:func:`scanqa.qa.blocks.geometry_component`).

    Returns
    -------
    list of Component
        The calibration row and the geometry line. For "covariance" with the geometry
        line, that line alone: it carries the very covariance that gave
        ``sigma_calibration_um``, with its correlation between the blocks, and the
        per-point row would count it twice.

    Notes
    -----
    A table's or a stated calibration std is a component with sensitivity c = 1 (GUM
    5.1.3): Type A with the table's dof for a table (GUM 4.2), Type B with infinite dof
    for a stated std (GUM 4.3); "none" is listed at u = 0 so the budget shows that the
    term is missing rather than hiding it (docs/uncertainty_budget.rst).
    """
    if kind == "covariance" and geometry is not None:
        return [geometry]
    name, gum, source = CALIBRATION_ROWS.get(kind or "", UNKNOWN_CALIBRATION_ROW)
    row = Component(name, gum, source, 0.0 if kind == "none" else u_um, "um", 1.0,
                    dof if gum == "A" else math.inf)
    return [row] + ([geometry] if geometry is not None else [])


def welch_satterthwaite(parts: list[tuple[float, float]]) -> float:
    """nu_eff = u^4 / sum(u_i^4 / nu_i) of (contribution [um], dof) pairs; inf when every
    contribution with a finite dof is zero; NaN when a dof is NaN (unknown).

    Notes
    -----
    nu_eff = u_c^4 / sum_i (c_i u_i)^4 / nu_i, the Welch-Satterthwaite formula of GUM G.4.1
    (Eq. G.2b); a term whose nu_i is infinite or not > 0 counts as infinite dof; an
    unknown (NaN) nu_i makes nu_eff unknown rather than optimistic.
    """
    if any(math.isnan(nu) for _, nu in parts):
        return math.nan
    u2 = sum(c * c for c, _ in parts)
    denom = sum(c**4 / nu for c, nu in parts if math.isfinite(nu) and nu > 0)
    return math.inf if denom == 0.0 else u2 * u2 / denom


def coverage_factor(nu: float, coverage: float = COVERAGE) -> float:
    """Student's t quantile for a two-sided ``coverage`` interval with nu dof [-].

    Notes
    -----
    k = t_p(nu), Student's t quantile at p = (1 + coverage) / 2 (GUM G.3, Table G.2);
    nu infinite gives the normal quantile, 1.96 at 95 %; an unknown (NaN) nu gives NaN,
    not the normal quantile; so does an unknown coverage. A coverage outside (0, 1) is
    refused.
    """
    if math.isnan(nu) or math.isnan(coverage):
        return math.nan
    if not 0.0 < coverage < 1.0:
        raise RangeError(f"coverage probability must lie in (0, 1), got {coverage!r}")
    q = 0.5 + 0.5 * coverage
    return float(student_t.ppf(q, nu)) if math.isfinite(nu) else float(student_t.ppf(q, 1e9))


def load_budget(path: str | os.PathLike) -> BudgetInputs:
    """The Type B inputs of a budget file (:func:`scanqa.io.budget.read_budget_file`)."""
    return read_budget_file(path)


def type_b(inputs: BudgetInputs | None, height_a_mm: float, height_b_mm: float
           ) -> tuple[list[Component], float]:
    """The Type B components of a step between blocks of nominal lengths L_a, L_b, and
    the thermal correction of its reference value [um] (module notes).

    Notes
    -----
    Type B standard uncertainties (GUM 4.3), each |c_i| u_i with infinite dof: the
    certificates' u_i = (U_0 + U_1 L_i) / k_cert (GUM 4.3.3), c = 1 per block; the
    temperature with c = alpha d_nom for dT and c = d_nom dT for alpha; the stage scale
    with c = d_nom; the calibration flat's form F as the difference of two uniforms on
    [0, F], u = F / sqrt(6) (GUM 4.3.7). The reference is corrected by d_nom alpha dT
    (module notes, docs/uncertainty_budget.rst).
    """
    if inputs is None:
        return [], 0.0
    d = height_a_mm - height_b_mm
    out = []
    if inputs.certificate_U_um is not None or inputs.certificate_U_per_mm_um is not None:
        u0, u1 = inputs.certificate_U_um or 0.0, inputs.certificate_U_per_mm_um or 0.0
        ua, ub = ((u0 + u1 * h) / inputs.certificate_k for h in (height_a_mm, height_b_mm))
        out.append(Component("gauge-block certificates (both blocks)", "B",
                             f"U = {u0:g} um + {u1:g} um/mm x L, k = {inputs.certificate_k:g}",
                             math.hypot(ua, ub), "um", 1.0))
    correction = 0.0
    if inputs.expansion_per_K is not None:
        alpha, dt = inputs.expansion_per_K, inputs.deviation_K or 0.0
        correction = 1e3 * d * alpha * dt
        out.append(Component("temperature of the blocks", "B",
                             f"deviation {dt:g} K from 20 degC", inputs.uncertainty_K or 0.0,
                             "K", 1e3 * alpha * d))
        out.append(Component("expansion coefficient", "B", f"alpha = {alpha:g} /K",
                             inputs.expansion_uncertainty_per_K or 0.0, "1/K", 1e3 * d * dt))
    if inputs.scale_uncertainty_ppm is not None:
        out.append(Component("calibration stage scale", "B", "budget file",
                             inputs.scale_uncertainty_ppm, "ppm", 1e-3 * d))
    if inputs.flatness_um is not None:
        out.append(Component("flatness of the calibration flat", "B",
                             f"F = {inputs.flatness_um:g} um, uniform per block",
                             inputs.flatness_um / math.sqrt(6.0), "um", 1.0))
    return out, correction
