"""Search scanner configurations for the largest usable volume (Sect. 5.1 of the paper).

A design spec names the volume the scanner must cover (a box in the scanner frame), the
largest sigma allowed in it, the settings that may vary and their limits (the names of
:data:`scanqa.design.rig.SETTINGS`) and obstacles, boxes that no view pyramid may cross. The
optimiser maximises the usable volume (:func:`scanqa.design.tools.usable_volume`), or with
``objective = "worst_sigma"`` minimises the largest sigma over the box, over the
settings among the configurations that cover the box at that sigma and clear the
obstacles: a coarse grid of the box of limits, then a compass search (pattern search
with halving steps) from the best feasible point. Every evaluation runs the one model
chain; :class:`Evaluator` counts them.

The spec is a TOML file declared, with an example, in :mod:`scanqa.io.designspec`.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linprog

from scanqa.design import rig, tools
from scanqa.errors import InputError, ScanQAError
from scanqa.io import designspec
from scanqa.io.designspec import read_design_spec
from scanqa.model import optics
from scanqa.model.config import ScannerConfig

#: What the search maximises: the usable volume, or minus the largest sigma over the
#: cover box (its points of :meth:`Box.samples`).
OBJECTIVES = ("usable_volume", "worst_sigma")


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the scanner frame, corners (3,) [mm]."""

    min_mm: tuple
    max_mm: tuple

    def __post_init__(self) -> None:
        if len(self.min_mm) != 3 or len(self.max_mm) != 3 or \
                not all(a < b for a, b in zip(self.min_mm, self.max_mm, strict=True)):
            raise InputError(f"a box needs min_mm < max_mm, three values each [mm], got "
                             f"{list(self.min_mm)} and {list(self.max_mm)}")

    def samples(self, n: int = 5) -> np.ndarray:
        """(n^3, 3) points on a regular grid over the box, corners included [mm]."""
        axes = [np.linspace(a, b, n) for a, b in zip(self.min_mm, self.max_mm, strict=True)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@dataclass(frozen=True)
class DesignSpec:
    """What the scanner must do and what may change (module notes)."""

    cover: Box
    sigma_max_um: float
    limits: dict
    obstacles: tuple = ()
    level: float = 0.49
    step_mm: float = 2.0
    source: str = "<spec>"
    objective: str = "usable_volume"

    def __post_init__(self) -> None:
        if not self.limits:
            raise InputError(f"[limits] must name at least one setting ({self.source})")
        for key, (lo, hi) in self.limits.items():
            if key not in rig.SETTINGS or key in ("level", "coc_max_mm"):
                raise InputError(f"limits.{key} is not a scanner setting (known: "
                                 f"{', '.join(list(rig.SETTINGS)[:-2])}) ({self.source})")
            if not lo < hi:
                raise InputError(f"limits.{key} needs low < high, got [{lo}, {hi}] "
                                 f"({self.source})")
            spec = rig.SETTINGS[key]
            low, high = spec.check.ge, spec.check.le  # type: ignore[union-attr]
            if lo < low or hi > high:  # else every point outside is infeasible
                raise InputError(f"limits.{key} = [{lo:g}, {hi:g}] must lie within "
                                 f"[{low:g}, {high:g}] {spec.unit} (the range "
                                 f"of the setting) ({self.source})")
        if self.objective not in OBJECTIVES:
            raise InputError(f"objective must be one of {', '.join(OBJECTIVES)}, got "
                             f"{self.objective!r} ({self.source})")
        if not self.sigma_max_um > 0 or not 0 < self.level < 1 or not self.step_mm > 0:
            raise InputError(f"sigma_max_um and step_mm must be > 0 and level in (0, 1) "
                             f"({self.source})")


def load_spec(path: str | os.PathLike) -> DesignSpec:
    """Read a design spec TOML (:mod:`scanqa.io.designspec`); errors name the file and
    the key."""
    data = read_design_spec(path)
    value = designspec.SCHEMA.value
    limits = {k: (float(v[0]), float(v[1])) for k, v in data["limits"].items()}
    return DesignSpec(
        _box(data["cover"]), float(data["sigma_max_um"]), limits,
        tuple(_box(o) for o in data.get("obstacles", [])),
        float(value(data, "level")), float(value(data, "step_mm")), str(path),
        str(value(data, "objective")))


def _box(table: dict) -> Box:
    return Box(tuple(table["min_mm"]), tuple(table["max_mm"]))


@dataclass
class Evaluator:
    """The spec's objective at settings, -inf when infeasible: the usable volume [mm^3]
    or minus the worst sigma in the cover box [um].

    ``calls`` counts model evaluations (each a usable volume and the checks); repeated
    settings are served from a cache and not counted.
    """

    config: ScannerConfig
    spec: DesignSpec
    calls: int = 0
    cache: dict = field(default_factory=dict)

    def settings(self, values: dict) -> dict:
        base = rig.settings_from_config(self.config, self.spec.level)
        return {**base, **values}

    def __call__(self, values: dict) -> float:
        key = tuple(round(values[k], 9) for k in sorted(values))
        if key not in self.cache:
            self.calls += 1
            self.cache[key] = self._evaluate(values)
        return self.cache[key]

    def _evaluate(self, values: dict) -> float:
        try:
            config = rig.apply_settings(self.config, self.settings(values))
        except ScanQAError:
            return -np.inf
        if not feasible(config, self.spec):
            return -np.inf
        if self.spec.objective == "worst_sigma":
            return -worst_sigma_um(config, self.spec)
        return tools.usable_volume(config, self.spec.level, step=self.spec.step_mm).usable_mm3


def worst_sigma_um(config: ScannerConfig, spec: DesignSpec) -> float:
    """The largest sigma along the line of sight over the cover box's samples [um]."""
    return float(np.max(optics.predict(spec.cover.samples(), config).sigma)) * 1e3


def feasible(config: ScannerConfig, spec: DesignSpec) -> bool:
    """The cover box usable at sigma <= sigma_max_um, and no obstacle in a view pyramid."""
    pts = spec.cover.samples()
    inside, good = tools.volume_masks(pts[:, 0], pts[:, 1], pts[:, 2], config, spec.level,
                                       None, None)
    if not (inside & good).all():
        return False
    pred = optics.predict(pts, config)
    if not (pred.valid.all() and np.all(pred.sigma * 1e3 <= spec.sigma_max_um)):
        return False
    far = 1.25 * config.camera.focus_mm
    return not any(crosses(config, box, far) for box in spec.obstacles)


def crosses(config: ScannerConfig, box: Box, z_far: float) -> bool:
    """Whether a box meets the camera's or the projector's view pyramid up to the far
    plane of the usable volume (a linear feasibility problem per pyramid)."""
    view = rig.pyramid_halfspaces(config, z_far)
    bounds = list(zip(box.min_mm, box.max_mm, strict=True))
    for planes in view:
        res = linprog(np.zeros(3), A_ub=planes[:, :3], b_ub=-planes[:, 3], bounds=bounds,
                      method="highs")
        if res.status == 0:
            return True
    return False


@dataclass(frozen=True)
class OptimisationResult:
    """The best settings found, the evaluations used, the config, and its usable volume
    [mm^3] and worst sigma in the cover box [um] (whichever the objective was)."""

    values: dict
    evaluations: int
    config: ScannerConfig
    usable_mm3: float
    worst_sigma_um: float


def _result(config: ScannerConfig, spec: DesignSpec, ev: Evaluator, values: dict
            ) -> OptimisationResult:
    best = rig.apply_settings(config, ev.settings(values))
    vol = tools.usable_volume(best, spec.level, step=spec.step_mm)
    return OptimisationResult(values, ev.calls, best, vol.usable_mm3,
                              worst_sigma_um(best, spec))


def optimise(config: ScannerConfig, spec: DesignSpec, coarse: int = 3,
             min_step: float = 1 / 64, budget: int = 200) -> OptimisationResult:
    """Maximise the spec's objective over its settings (module notes).

    Parameters
    ----------
    config : ScannerConfig
        The scanner the settings are laid over (:func:`scanqa.design.rig.apply_settings`).
    spec : DesignSpec
        Cover box, sigma threshold, limits and obstacles.
    coarse : int
        Grid points per setting of the first stage [-]; one more per setting until a
        point of the grid meets the spec (within half the budget).
    min_step : float
        Smallest compass step, as a fraction of each setting's range [-].
    budget : int
        Largest number of model evaluations [-].

    Returns
    -------
    OptimisationResult
        With the config of the best settings.

    Raises
    ------
    InputError
        When no configuration the search visited meets the spec.
    """
    names = list(spec.limits)
    lo = np.array([spec.limits[k][0] for k in names])
    hi = np.array([spec.limits[k][1] for k in names])
    ev = Evaluator(config, spec)

    def score(u: np.ndarray) -> float:
        return ev(dict(zip(names, (lo + np.clip(u, 0, 1) * (hi - lo)).tolist(), strict=True)))

    best = -np.inf
    while not np.isfinite(best) and ev.calls < budget // 2:  # finer until one is feasible
        grid = np.linspace(0.0, 1.0, coarse)
        start = [np.array(u) for u in itertools.product(grid, repeat=len(names))]
        best_u = max(start, key=score)
        best, step = score(best_u), 1.0 / (2 * (coarse - 1))
        coarse += 1
    while step >= min_step and ev.calls < budget:
        moves = [best_u + s * step * e for e in np.eye(len(names)) for s in (1, -1)]
        moves = [np.clip(m, 0, 1) for m in moves]
        trial = max(moves, key=score)
        if score(trial) > best:
            best_u, best = trial, score(trial)
        else:
            step /= 2
    if not np.isfinite(best):
        raise InputError("no configuration within the limits covers the box at the sigma "
                         "threshold while clearing the obstacles; widen [limits], enlarge "
                         "sigma_max_um or shrink [cover]")
    values = dict(zip(names, (lo + best_u * (hi - lo)).tolist(), strict=True))
    return _result(config, spec, ev, values)


def grid_search(config: ScannerConfig, spec: DesignSpec, points: int
                ) -> OptimisationResult:
    """Brute force: every point of a regular grid over the limits (the reference)."""
    names = list(spec.limits)
    ev = Evaluator(config, spec)
    axes = [np.linspace(*spec.limits[k], points) for k in names]
    best_values, best = None, -np.inf
    for combo in itertools.product(*axes):
        values = dict(zip(names, map(float, combo), strict=True))
        score = ev(values)
        if score > best:
            best_values, best = values, score
    if best_values is None:
        raise InputError("no grid point meets the spec")
    return _result(config, spec, ev, best_values)
