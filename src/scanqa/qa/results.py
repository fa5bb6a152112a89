"""The QA result types of both artefact families: frozen dataclasses that hold every
number the QA computed, for the report layer to render.

- gauge blocks (:mod:`scanqa.qa.blocks`): :class:`BlockResult` per block,
  :class:`StepResult` per pair of successive blocks, :class:`QAResult` for the scan;
- VDI/VDE 2634-2 artefacts (:mod:`scanqa.qa.artefacts`): :class:`ArtefactSpec` and
  :class:`ArtefactLayout` (what to look for), :class:`Options` and :class:`Selection`
  (how the points were chosen), :class:`ArtefactResult` per artefact and scan,
  :class:`ArtefactQAResult` for the run.

Both families decide with the one ISO 14253-1 rule (:func:`scanqa.qa.verdict.decide`),
count their decisions with :func:`scanqa.qa.verdict.verdict`, and write NaN and inf as
JSON null (:func:`finite`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.io.spec import Spec
from scanqa.numeric import json_ready
from scanqa.qa.budget import Budget
from scanqa.qa.correlation import TILE_MM
from scanqa.qa.planes import PlaneFit
from scanqa.qa.sphere import MIN_COVERAGE
from scanqa.qa.vdi2634 import (
    DROP_FRACTION,
    BallBarTest,
    FlatTest,
    Quantity,
    SphereTest,
)
from scanqa.qa.verdict import DECISIONS, decide, verdict

#: How per-point sigmas are scaled for oblique views (:mod:`scanqa.qa.artefacts`).
OBLIQUE = ("decoder", "modulation", "none")


# ------------------------------------------------------------------------ gauge blocks

@dataclass(frozen=True)
class BlockResult:
    """Per-block QA numbers (lengths in mm, standard deviations in um)."""

    block_id: int
    nominal_height_mm: float
    n_points: int = 0
    measured_std_um: float = math.nan
    predicted_std_um: float = math.nan
    flatness_um: float = math.nan
    mean_attenuation: float = math.nan
    in_volume_fraction: float = math.nan
    model_valid_fraction: float = math.nan
    mean_z_mm: float = math.nan
    outliers: int = 0
    status: str = "no_points"
    message: str = ""
    fit: PlaneFit | None = field(default=None, repr=False)
    index: np.ndarray | None = field(default=None, repr=False)
    u_plane: np.ndarray | None = field(default=None, repr=False)  # (3, 3) covariance
    sigma_n: np.ndarray | None = field(default=None, repr=False)
    table_sigma_um: float = math.nan
    table_corr_mm: float = math.nan  # correlation length of the table's errors [mm]
    spread_mm: tuple = (math.nan, math.nan)  # std of the points along the plane axes [mm]
    #: noise-correlation factor of the plane's (offset, slope_1, slope_2) variances [-]
    noise_corr: tuple = (math.nan, math.nan, math.nan)
    n_tiles: int = 0

    @property
    def ratio(self) -> float:
        """Measured / predicted std [-] (NaN without a positive prediction)."""
        if not self.predicted_std_um > 0:
            return math.nan
        return self.measured_std_um / self.predicted_std_um

    @property
    def noise_dof(self) -> float:
        """Degrees of freedom of the block's noise terms: K - 3 for K tiles, or n - 3 for
        n independent points when the correlation factor could not be measured [-]."""
        n = self.n_tiles if math.isfinite(self.noise_corr[0]) else self.n_points
        return float(max(n - 3, 1))

    @property
    def std_u_um(self) -> float:
        """Standard uncertainty of the measured std (Type A): s / sqrt(2 nu) with nu the
        effective count of independent points n / kappa, less 3 for the plane [um]."""
        kappa = self.noise_corr[0] if math.isfinite(self.noise_corr[0]) else 1.0
        nu = max(self.n_points / kappa - 3.0, 1.0)
        return self.measured_std_um / math.sqrt(2.0 * nu)

    def row(self) -> dict:
        return {"block_id": self.block_id, "nominal_height_mm": self.nominal_height_mm,
                "n_points": self.n_points, "measured_std_um": self.measured_std_um,
                "measured_std_u_um": self.std_u_um,
                "predicted_std_um": self.predicted_std_um, "ratio": self.ratio,
                "flatness_um": self.flatness_um, "mean_attenuation": self.mean_attenuation,
                "in_volume_fraction": self.in_volume_fraction,
                "model_valid_fraction": self.model_valid_fraction, "status": self.status,
                "noise_corr_factor": self.noise_corr[0], "n_tiles": self.n_tiles}


@dataclass(frozen=True)
class StepResult:
    """Height difference between two blocks (mm and um as named).

    ``u_um`` and ``k`` are the budget's (:mod:`scanqa.qa.budget`); ``evaluated`` is False
    when a block of the pair is flagged (``note`` says which), and then the step gets no
    decision. The error is measured - reference, the reference being the nominal
    difference with the budget's thermal correction.
    """

    block_a: int
    block_b: int
    nominal_diff_mm: float
    measured_diff_mm: float
    u_um: float
    k: float
    tolerance_um: float
    budget: Budget | None = field(default=None, repr=False, compare=False)
    evaluated: bool = True
    note: str = ""

    @property
    def error_um(self) -> float:
        correction = self.budget.correction_um if self.budget is not None else 0.0
        return 1e3 * (self.measured_diff_mm - self.nominal_diff_mm) - correction

    @property
    def expanded_um(self) -> float:
        return self.k * self.u_um

    @property
    def within_u(self) -> bool:
        """|error| <= U (only meaningful for an evaluated step)."""
        return abs(self.error_um) <= self.expanded_um

    @property
    def decision(self) -> str:
        """ISO 14253-1 (:func:`scanqa.qa.verdict.decide`, the one rule): "pass", "fail"
        or "undecided"; "not evaluated" for a step with a flagged block or a NaN."""
        if not self.evaluated:
            return "not evaluated"
        return decide(self.error_um, self.expanded_um, self.tolerance_um)

    def row(self) -> dict:
        """The step's table row: ``decision`` (ISO 14253-1 against T) and ``within_U``
        (|error| <= U, a check of the uncertainty statement) are separate columns."""
        nu = self.budget.nu_eff if self.budget is not None else math.nan
        return {"block_a": self.block_a, "block_b": self.block_b,
                "nominal_diff_mm": self.nominal_diff_mm,
                "measured_diff_mm": self.measured_diff_mm, "error_um": self.error_um,
                "u_um": self.u_um, "nu_eff": nu, "U_um": self.expanded_um, "k": self.k,
                "tolerance_um": self.tolerance_um, "decision": self.decision,
                "within_U": ("yes" if self.within_u else "no") if self.evaluated else "",
                "evaluated": self.evaluated}


#: A residual map has at most this many cells along its longer side (its axes are
#: ~450 px wide).
MAP_CELLS = 400


def map_cell_mm(x: np.ndarray, y: np.ndarray, cells: int = MAP_CELLS) -> float:
    """Cell of a map of points drawn as an image: 1.5 times the median distance of a point
    to its nearest neighbour in XY (so a region sampled on a grid leaves no cell empty),
    and at least the longer side over ``cells`` [mm]; 1 mm for one point, NaN for none.

    Parameters
    ----------
    x, y : ndarray
        The points' coordinates [mm].
    cells : int
        Most cells along the longer side [-].

    Notes
    -----
    A display rule, scanqa's own (docs/formats.rst, "QA outputs"): a grid of spacing h
    puts at least one point in every interval longer than h, so cells of 1.5 h leave no
    cell of a sampled region empty (1 to 4 points each), and a map ~450 px wide shows no
    more than ``cells`` of them. The median is taken over a fixed stride of at most ~2000
    points.
    """
    from scipy.spatial import cKDTree

    if len(x) < 2:
        return 1.0 if len(x) else math.nan
    xy = np.stack([x, y], -1)
    span = float(np.ptp(xy, axis=0).max())
    probe = xy[::max(1, len(xy) // 2000)]  # a fixed stride, not a random draw
    dist = cKDTree(xy).query(probe, k=2)[0][:, 1]
    dist = dist[dist > 0]
    spacing = 1.5 * float(np.median(dist)) if len(dist) else 0.0
    return max(spacing, span / cells) or 1.0


@dataclass(frozen=True)
class QAResult:
    """Everything the QA computed; the report layer only renders it.

    ``cloud`` is the cloud the QA ran on; ``curve`` the model's uncertainty curve on the
    camera axis over the blocks' depths (:func:`scanqa.design.tools.axis_curve`), from the model
    that gave the cloud's sigmas, or None when that model is unknown.
    """

    blocks: list[BlockResult]
    steps: list[StepResult]
    block_id: np.ndarray       # (n,) per point, -1 outside every block
    residual_um: np.ndarray    # (n,) per point, NaN outside blocks
    local_std_um: np.ndarray   # (n,) per point
    has_prediction: bool
    notes: list[str]
    settings: dict
    cloud: AnnotatedCloud | None = field(default=None, repr=False)
    curve: dict | None = field(default=None, repr=False)

    def steps_evaluated(self) -> list[StepResult]:
        """Steps between two blocks whose status is "ok" (the others get no decision)."""
        return [s for s in self.steps if s.evaluated]

    def residual_limit_um(self, percentile: float = 99.0) -> float:
        """Colour-scale limit of the residual maps: the ``percentile`` of |residual| over
        the points in a block [um] (NaN when no point is in a block).

        Parameters
        ----------
        percentile : float
            Percentile of |residual| [%] (the few worst points saturate the scale).
        """
        sel = self.block_id >= 0
        if not sel.any():
            return math.nan
        return float(np.nanpercentile(np.abs(self.residual_um[sel]), percentile))

    def residual_map_cell_mm(self) -> float:
        """Cell of the residual map (:func:`map_cell_mm` of the XY of the points in a
        block with a residual) [mm]; NaN without such points or without the cloud."""
        if self.cloud is None:
            return math.nan
        xy = self.cloud.xyz[:, :2]
        sel = (self.block_id >= 0) & np.isfinite(self.residual_um) & np.isfinite(xy).all(1)
        return map_cell_mm(xy[sel, 0], xy[sel, 1])

    def summary(self) -> dict:
        """JSON-ready summary: settings, every block and step with its budget, the counts.

        Every count is over the tables it sits beside: ``steps_evaluated`` +
        ``steps_not_evaluated`` = the number of steps, ``decisions`` counts the steps'
        ``pass`` column, ``steps_error_within_U`` the evaluated steps with |error| <= U.
        """
        evaluated = self.steps_evaluated()
        within = [s for s in evaluated if s.within_u]
        ratios = [b.ratio for b in self.blocks if b.status == "ok" and math.isfinite(b.ratio)]
        decisions = {d: sum(s.decision == d for s in self.steps) for d in DECISIONS}
        return {
            "format": "scanqa-qa-summary/3",
            "verdict": verdict(s.decision for s in self.steps)["verdict"],
            "tolerance_um": self.settings.get("tolerance_um"),
            "tolerance_source": self.settings.get("tolerance_source", "given"),
            "settings": self.settings,
            "model": self.cloud.model if self.cloud is not None else {},
            "sigma_source": (self.cloud.metadata.get("sigma_source")
                             if self.cloud is not None else None),
            "has_prediction": self.has_prediction,
            "blocks": [json_ready(b.row()) for b in self.blocks],
            "blocks_ok": sum(b.status == "ok" for b in self.blocks),
            "blocks_flagged": sum(b.status != "ok" for b in self.blocks),
            "steps": [json_ready(s.row()) for s in self.steps],
            "budgets": [{"block_a": s.block_a, "block_b": s.block_b,
                         **json_ready(s.budget.summary())}
                        for s in self.steps if s.budget is not None],
            "type_b_included": self.type_b_included,
            "steps_evaluated": len(evaluated),
            "steps_not_evaluated": len(self.steps) - len(evaluated),
            "steps_error_within_U": len(within),
            "fraction_within_U": len(within) / len(evaluated) if evaluated else None,
            "decisions": decisions,
            "max_abs_ratio_deviation": max((abs(r - 1) for r in ratios), default=None),
            "notes": list(self.notes),
        }

    @property
    def type_b_included(self) -> bool:
        return bool(self.steps) and all(s.budget is not None and s.budget.type_b_included
                                        for s in self.steps)

    def annotated_cloud(self) -> AnnotatedCloud | None:
        """The cloud with the per-point QA fields ``qa_block_id``, ``qa_residual_um`` and
        ``qa_local_std_um`` added (None when the result holds no cloud)."""
        if self.cloud is None:
            return None
        return self.cloud.with_attributes(qa_block_id=self.block_id,
                                          qa_residual_um=self.residual_um,
                                          qa_local_std_um=self.local_std_um)


# ------------------------------------------------------------------ VDI/VDE 2634-2 artefacts

@dataclass(frozen=True)
class ArtefactSpec:
    """One artefact of a layout (lengths [mm]; vectors None when not given)."""

    kind: str
    id: str
    diameter_mm: float = math.nan
    distance_mm: float = math.nan
    centre_mm: tuple | None = None
    centre_b_mm: tuple | None = None
    normal: tuple | None = None
    size_mm: tuple | None = None
    bar_diameter_mm: float = math.nan
    scan: str = ""

    def applies_to(self, scan: str) -> bool:
        """Whether this artefact is in the scan named ``scan`` (module notes)."""
        return not self.scan or not scan or scan.startswith(self.scan)


@dataclass(frozen=True)
class ArtefactLayout:
    """Artefacts of one or more scans."""

    name: str
    artefacts: tuple[ArtefactSpec, ...]
    source: str = ""


@dataclass(frozen=True)
class Options:
    """Point selection and evaluation settings (module notes; lengths [mm], angles [deg])."""

    k: float = 2.0
    drop_fraction: float = DROP_FRACTION
    sd_drop_fraction: float = 0.0
    max_incidence_deg: float = 70.0
    shell_mm: float | None = None
    margin_mm: float = 1.0
    mount_margin_deg: float = 10.0
    min_coverage: float = MIN_COVERAGE
    oblique: str = "decoder"
    tile_mm: float = TILE_MM
    decide_with: str = "test"

    def __post_init__(self) -> None:
        if not 0 < self.max_incidence_deg <= 90:
            raise InputError(f"max_incidence_deg must be in (0, 90] deg, got "
                             f"{self.max_incidence_deg!r}")
        if self.oblique not in OBLIQUE:
            raise InputError(f"oblique must be one of {', '.join(OBLIQUE)}, got "
                             f"{self.oblique!r}")
        if not (self.tile_mm > 0 and self.margin_mm >= 0 and self.k > 0):
            raise InputError("tile_mm and k must be > 0 and margin_mm >= 0")

    def row(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Selection:
    """Which points an artefact's quantities rest on and what each step removed."""

    index: np.ndarray
    counts: dict


@dataclass(frozen=True)
class ArtefactResult:
    """The quantities of one artefact in one scan."""

    spec: ArtefactSpec
    scan: str
    quantities: tuple[Quantity, ...]
    selections: tuple[Selection, ...]
    test: SphereTest | BallBarTest | FlatTest = field(repr=False)
    u_table: float = 0.0
    kappa: float = 1.0
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)

    def rows(self) -> list[dict]:
        """One report row per quantity (lengths in um)."""
        zone = getattr(self.test, "zone", None)
        return [{"scan": self.scan, "artefact": self.spec.id, "kind": self.spec.kind,
                 **q.row(), "noise_corr_factor": self.kappa,
                 "minimum_zone_um": 1e3 * zone.width if zone is not None
                 and q.name in ("PF", "F") else math.nan} for q in self.quantities]

    def budget(self) -> list[dict]:
        """Each quantity's uncertainty budget: standard uncertainties [um] by component
        (module notes of this module and of :mod:`scanqa.qa.vdi2634`)."""
        out = []
        for q in self.quantities:
            if not math.isfinite(q.u):
                continue
            for component, u, how in self._components(q):
                out.append({"scan": self.scan, "artefact": self.spec.id,
                            "quantity": q.name, "component": component,
                            "u_um": 1e3 * u, "enters": how})
            out.append({"scan": self.scan, "artefact": self.spec.id, "quantity": q.name,
                        "component": f"U = {q.k:g} u + |bias|", "u_um": 1e3 * q.expanded,
                        "enters": "expanded"})
        return out

    def _components(self, q: Quantity) -> list[tuple[str, float, str]]:
        kappa = f"noise-correlation factor {self.kappa:.2f} included"
        if q.name in ("PF", "F"):
            return [("noise of the points: spread of the range over scans", q.u_points, kappa),
                     ("artefact form (certified, rectangular)", q.u_artefact, "test")]
        if q.name == "PS":
            fit = self.test.fit
            return [("noise of the points: 2 u(R) of the fit", 2 * fit.u_radius, kappa),
                    ("calibration table's own error: 2 u(R)", 2 * self.u_table, "quadrature"),
                    ("certificate of the diameter", q.u_artefact, "test"),
                    ("bias of the fit from line-of-sight noise", abs(q.bias), "linear")]
        return [("noise of the points: both centres along the bar",
                 self.test.bar.u_distance, kappa),
                ("calibration table's own error: both balls", math.sqrt(2) * self.u_table,
                 "quadrature"),
                ("certificate of the distance", q.u_artefact, "test"),
                ("bias of the fits from line-of-sight noise", abs(q.bias), "linear")]

    def residual_limit_um(self, percentile: float = 99.5) -> float:
        """Colour-scale limit of the residual map: the ``percentile`` of |residual| [um],
        1.0 when every residual is 0.

        Parameters
        ----------
        percentile : float
            Percentile of |residual| [%].
        """
        return float(np.percentile(np.abs(self.residuals()[1]), percentile)) * 1e3 or 1.0

    def residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """The selected points [mm] and their distances from the fitted sphere(s) or
        plane [mm] (the points the 0.3 % rule dropped included)."""
        t, pts = self.test, self.points
        if isinstance(t, FlatTest):
            return pts, (pts - t.plane.centroid) @ t.plane.normal
        fits = [t.fit] if isinstance(t, SphereTest) else [t.bar.sphere_a, t.bar.sphere_b]
        d = np.stack([np.linalg.norm(pts - f.centre, axis=1) - f.radius for f in fits])
        return pts, d[np.argmin(np.abs(d), axis=0), np.arange(len(pts))]


@dataclass(frozen=True)
class ArtefactQAResult:
    """Every artefact's result over one or more scans, with settings and notes."""

    results: tuple[ArtefactResult, ...]
    options: Options
    spec: Spec | None
    layout: ArtefactLayout
    notes: tuple[str, ...] = ()
    #: where the scans' per-point sigmas come from (the first scan with a warning, else
    #: the first scan; :func:`scanqa.annotation.points.sigma_source`), None when unknown
    sigma_source: dict | None = None

    def quantities(self) -> list[Quantity]:
        return [q for r in self.results for q in r.quantities]

    def rows(self) -> list[dict]:
        return [row for r in self.results for row in r.rows()]

    def verdict(self) -> dict:
        """The overall verdict and the count of each decision (:mod:`scanqa.qa.verdict`)."""
        return verdict([q.decision for q in self.quantities()])

    def summary(self) -> dict:
        """A JSON-ready summary: verdict, rows, selections, settings, notes."""
        return {"verdict": self.verdict(), "layout": self.layout.source,
                "spec": None if self.spec is None else {"name": self.spec.name,
                                                        "source": self.spec.source},
                "quantities": [json_ready(row) for row in self.rows()],
                "selections": [{"scan": r.scan, "artefact": r.spec.id,
                                "ball": "ab"[i] if len(r.selections) == 2 else "",
                                **s.counts} for r in self.results
                               for i, s in enumerate(r.selections)],
                "options": self.options.row(), "sigma_source": self.sigma_source,
                "notes": list(self.notes)}
