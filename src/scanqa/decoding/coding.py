"""Pattern codings: what was projected, as described by a ``patterns.toml``.

A pattern folder holds the camera images of one scan and a ``patterns.toml`` that says
what was projected (docs/formats.rst documents every key). This module holds the
decoder's own types - the coding (:class:`PatternDescription` with its
:class:`PhaseSet` and :class:`GrayCodeSet` entries), the camera noise model
(:class:`SensorModel`) and the decision thresholds (:class:`Thresholds`) - and
validates a parsed file into them; :mod:`scanqa.io.patterns` reads and writes the file
itself, :mod:`scanqa.decoding.patternset` the images.

Gray code convention: a Gray-code set with ``bits`` bits orders the phase set named by
``orders`` (by default the coarsest) of period P. It codes the half-period index
``h = floor(2 x / P)`` (clipped to ``0 .. 2**bits - 1``) as the reflected binary code
``g = h ^ (h >> 1)``; frame b (b = 0 is the most significant bit) is white (1) where
bit ``bits - 1 - b`` of g is set. With ``inverse = true`` the files list the ``bits``
patterns first and then their inverses in the same order. Stripes of half a period make
the fringe order robust to a Gray-code error of one stripe at stripe edges.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from scanqa.errors import ConfigError
from scanqa.io.patterns import FORMAT, read_patterns_file

#: Fringe orientations: "vertical" fringes code x_p (columns), "horizontal" y_p (rows).
ORIENTATIONS = ("vertical", "horizontal")


@dataclass(frozen=True)
class SensorModel:
    """Intensity noise model of the camera (the ``[sensor]`` table).

    Attributes
    ----------
    bit_depth : int or None
        Bits per sample [bit]; None takes it from the images (8 for 8-bit files, 16 for
        16-bit files and float stacks).
    gain_e_per_dn : float
        Conversion gain [e-/DN]; shot-noise variance is (I - black) / gain [DN^2].
    read_noise_e : float
        Read (dark) noise [e-].
    saturation_dn : float or None
        Level at or above which a sample is saturated [DN]; None means
        ``2**bit_depth - 1``.
    black_level_dn : float
        Dark offset subtracted before the shot-noise term [DN].
    """

    bit_depth: int | None = None
    gain_e_per_dn: float = 4.0
    read_noise_e: float = 8.0
    saturation_dn: float | None = None
    black_level_dn: float = 0.0

    def __post_init__(self) -> None:
        _require(self.bit_depth is None or 1 <= self.bit_depth <= 32,
                 "sensor.bit_depth", self.bit_depth, "a whole number in 1..32 [bit]")
        _require(self.gain_e_per_dn > 0, "sensor.gain_e_per_dn", self.gain_e_per_dn,
                 "> 0 [e-/DN]")
        _require(self.read_noise_e >= 0, "sensor.read_noise_e", self.read_noise_e, ">= 0 [e-]")
        _require(self.saturation_dn is None or self.saturation_dn > 0,
                 "sensor.saturation_dn", self.saturation_dn, "> 0 [DN]")
        _require(self.black_level_dn >= 0, "sensor.black_level_dn", self.black_level_dn,
                 ">= 0 [DN]")

    def resolved(self, dtype: np.dtype) -> SensorModel:
        """Copy with ``bit_depth`` and ``saturation_dn`` filled in from an image dtype."""
        bits = self.bit_depth or (8 if np.dtype(dtype) == np.uint8 else 16)
        sat = self.saturation_dn if self.saturation_dn is not None else 2.0 ** bits - 1
        return replace(self, bit_depth=bits, saturation_dn=float(sat))

    @property
    def read_noise_dn(self) -> float:
        """Read noise in image units [DN]."""
        return self.read_noise_e / self.gain_e_per_dn


@dataclass(frozen=True)
class Thresholds:
    """Decision thresholds of the decoder (the ``[thresholds]`` table).

    Attributes
    ----------
    min_modulation_dn : float
        Absolute modulation floor for every phase set [DN]; 0 leaves only the
        noise-based floor.
    unwrap_max_residual : float
        Largest accepted disagreement between a set and the coarser estimate that
        unwraps it [cycles of the finer period]; beyond it the pixel is inconsistent.
    unwrap_sigma_margin : float
        A pixel has too low a modulation when its predicted unwrapping residual times
        this margin exceeds the accepted residual [-].
    gray_max_residual : float
        Largest accepted disagreement between the Gray code and the phase it orders
        [cycles]; the code's own quantisation is 0.25.
    gray_min_contrast_sigma : float
        A Gray-code bit whose contrast is below this many noise standard deviations
        is undecidable, and the pixel has too low a modulation [-].
    max_period_ratio : float
        Largest ratio between successive periods that the hierarchy accepts [-].
    """

    min_modulation_dn: float = 0.0
    unwrap_max_residual: float = 0.25
    unwrap_sigma_margin: float = 4.0
    gray_max_residual: float = 0.375
    gray_min_contrast_sigma: float = 3.0
    max_period_ratio: float = 64.0

    def __post_init__(self) -> None:
        _require(self.min_modulation_dn >= 0, "thresholds.min_modulation_dn",
                 self.min_modulation_dn, ">= 0 [DN]")
        _require(0 < self.unwrap_max_residual < 0.5, "thresholds.unwrap_max_residual",
                 self.unwrap_max_residual, "in (0, 0.5) [cycles]")
        _require(self.unwrap_sigma_margin >= 1, "thresholds.unwrap_sigma_margin",
                 self.unwrap_sigma_margin, ">= 1 [-]")
        _require(0.25 < self.gray_max_residual < 0.5, "thresholds.gray_max_residual",
                 self.gray_max_residual, "in (0.25, 0.5) [cycles]")
        _require(self.gray_min_contrast_sigma >= 0, "thresholds.gray_min_contrast_sigma",
                 self.gray_min_contrast_sigma, ">= 0 [-]")
        _require(self.max_period_ratio > 1, "thresholds.max_period_ratio",
                 self.max_period_ratio, "> 1 [-]")


@dataclass(frozen=True)
class PhaseSet:
    """An N-step phase-shift set (``kind = "phase"``).

    Attributes
    ----------
    name : str
        Label used in messages and by a Gray-code set's ``orders``.
    period_px : float
        Fringe period [projector px].
    steps : int
        Number of frames N >= 3 [-].
    shifts_rad : tuple of float
        Phase shift delta_k of each frame [rad]; empty means 2 pi k / N.
    orientation : str
        "vertical" (codes x_p) or "horizontal" (codes y_p).
    files : tuple of str
        Image files in frame order, relative to the patterns.toml folder.
    stack : str
        Alternatively one .npy/.npz stack (N, H, W).
    stack_key : str
        Array name inside a .npz stack.
    """

    name: str
    period_px: float
    steps: int
    shifts_rad: tuple = ()
    orientation: str = "vertical"
    files: tuple = ()
    stack: str = ""
    stack_key: str = ""

    def __post_init__(self) -> None:
        where = f"set {self.name!r}"
        _require(math.isfinite(self.period_px) and self.period_px > 0,
                 f"{where}: period_px", self.period_px, "> 0 [projector px]")
        _require(isinstance(self.steps, int) and self.steps >= 3, f"{where}: steps",
                 self.steps, "a whole number >= 3")
        _check_orientation(where, self.orientation)
        shifts = tuple(float(s) for s in self.shifts_rad) or tuple(
            2 * math.pi * k / self.steps for k in range(self.steps))
        _require(len(shifts) == self.steps, f"{where}: shifts_rad", list(self.shifts_rad),
                 f"{self.steps} values (one per step) [rad]")
        _check_shifts(where, shifts)
        object.__setattr__(self, "shifts_rad", shifts)
        object.__setattr__(self, "files", tuple(self.files))

    @property
    def frames(self) -> int:
        """Number of images in the set [-]."""
        return self.steps


@dataclass(frozen=True)
class GrayCodeSet:
    """A Gray-code set (``kind = "gray"``) that gives the fringe order of a phase set.

    Attributes
    ----------
    name : str
        Label used in messages.
    bits : int
        Number of Gray-code bits [-].
    orders : str
        Name of the phase set it orders; empty means the coarsest phase set.
    inverse : bool
        True when every bit pattern is followed (after all bits) by its inverse.
    orientation : str
        Must equal the phase sets' orientation.
    files, stack, stack_key
        As for :class:`PhaseSet`.
    """

    name: str
    bits: int
    orders: str = ""
    inverse: bool = False
    orientation: str = "vertical"
    files: tuple = ()
    stack: str = ""
    stack_key: str = ""

    def __post_init__(self) -> None:
        _require(isinstance(self.bits, int) and 1 <= self.bits <= 24,
                 f"set {self.name!r}: bits", self.bits, "a whole number in 1..24")
        _check_orientation(f"set {self.name!r}", self.orientation)
        object.__setattr__(self, "files", tuple(self.files))

    @property
    def frames(self) -> int:
        """Number of images in the set [-]."""
        return self.bits * (2 if self.inverse else 1)


@dataclass(frozen=True)
class PatternDescription:
    """A whole ``patterns.toml``: coded range, sensor, thresholds and sets.

    Attributes
    ----------
    projector_width_px : int
        Coded range along the fringe direction [projector px]: x_p in [0, width).
    sets : tuple of PhaseSet and GrayCodeSet
        In file order.
    sensor : SensorModel
        Camera noise model.
    thresholds : Thresholds
        Decision thresholds.
    description : str
        Free text.
    source : str
        The patterns.toml path (file names are relative to its folder).
    """

    projector_width_px: int
    sets: tuple
    sensor: SensorModel = field(default_factory=SensorModel)
    thresholds: Thresholds = field(default_factory=Thresholds)
    description: str = ""
    source: str = ""

    def __post_init__(self) -> None:
        _require(isinstance(self.projector_width_px, int) and self.projector_width_px >= 1,
                 "projector_width_px", self.projector_width_px, "a whole number >= 1 [px]")
        object.__setattr__(self, "sets", tuple(self.sets))
        _check_sets(self)

    @property
    def phase_sets(self) -> tuple[PhaseSet, ...]:
        """Phase sets, coarsest (largest period) first."""
        sets = [s for s in self.sets if isinstance(s, PhaseSet)]
        return tuple(sorted(sets, key=lambda s: -s.period_px))

    @property
    def gray_set(self) -> GrayCodeSet | None:
        """The Gray-code set, if any."""
        return next((s for s in self.sets if isinstance(s, GrayCodeSet)), None)

    @property
    def working_period_px(self) -> float:
        """The finest period [projector px]."""
        return self.phase_sets[-1].period_px

    @property
    def orientation(self) -> str:
        """The common fringe orientation."""
        return self.sets[0].orientation

    def to_dict(self) -> dict:
        """Plain dict in the patterns.toml layout (for provenance and writing)."""
        out: dict[str, Any] = {"format": FORMAT, "projector_width_px": self.projector_width_px}
        if self.description:
            out["description"] = self.description
        out["sensor"] = {k: v for k, v in asdict(self.sensor).items() if v is not None}
        out["thresholds"] = asdict(self.thresholds)
        out["set"] = [_set_dict(s) for s in self.sets]
        return out


def _set_dict(pset: PhaseSet | GrayCodeSet) -> dict:
    """One ``[[set]]`` table as a dict, leaving out empty storage keys."""
    kind = "phase" if isinstance(pset, PhaseSet) else "gray"
    out: dict[str, Any] = {"kind": kind}
    for key, value in asdict(pset).items():
        if value in ("", ()) and key in ("files", "stack", "stack_key", "orders"):
            continue
        out[key] = list(value) if isinstance(value, tuple) else value
    return out


def _require(ok: bool, key: str, value: Any, expected: str) -> None:
    """Raise ConfigError ``key must be <expected>, got <value>`` unless ok."""
    if not ok:
        raise ConfigError(f"{key} must be {expected}, got {value!r}")


def _check_orientation(where: str, orientation: str) -> None:
    _require(orientation in ORIENTATIONS, f"{where}: orientation", orientation,
             "'vertical' or 'horizontal'")


def _check_shifts(where: str, shifts: Sequence[float]) -> None:
    """Shifts must determine (A, B cos phi, B sin phi) by least squares."""
    design = np.column_stack([np.ones(len(shifts)), np.cos(shifts), np.sin(shifts)])
    if np.linalg.cond(design) > 1e6:
        raise ConfigError(f"{where}: shifts_rad {list(shifts)} do not determine the phase "
                          "(need at least 3 shifts that differ modulo 2 pi)")


def _check_sets(desc: PatternDescription) -> None:
    """Cross-set rules: names, orientation, one Gray set, a period chain that unwraps."""
    _require(len(desc.sets) > 0, "set", [], "at least one [[set]] table")
    names = [s.name for s in desc.sets]
    dup = sorted({n for n in names if names.count(n) > 1})
    _require(not dup, "set names", dup, "unique (set a distinct name = ...)")
    orient = {s.orientation for s in desc.sets}
    _require(len(orient) == 1, "orientation", sorted(orient),
             "the same for every set (decode x_p and y_p from separate pattern folders)")
    phase = desc.phase_sets
    _require(len(phase) > 0, "set", names, "at least one set with kind = 'phase'")
    gray = [s for s in desc.sets if isinstance(s, GrayCodeSet)]
    _require(len(gray) <= 1, "set", names, "at most one set with kind = 'gray'")
    if gray:
        _check_gray(desc, gray[0], phase)
    elif phase[0].period_px < desc.projector_width_px:
        raise ConfigError(
            f"periods cannot be unwrapped: the coarsest period_px = {phase[0].period_px:g} "
            f"(set {phase[0].name!r}) is shorter than projector_width_px = "
            f"{desc.projector_width_px}, so x_p is ambiguous; add a phase set with "
            f"period_px >= {desc.projector_width_px} or a Gray-code set")
    _check_ratios(desc, phase)


def _check_gray(desc: PatternDescription, gray: GrayCodeSet, phase: tuple) -> None:
    """The Gray code must order the coarsest phase set and cover the coded range."""
    target = gray.orders or phase[0].name
    match = [s for s in phase if s.name == target]
    _require(bool(match), f"set {gray.name!r}: orders", gray.orders,
             f"the name of a phase set (one of {', '.join(s.name for s in phase)})")
    _require(match[0] is phase[0], f"set {gray.name!r}: orders", target,
             f"the coarsest phase set {phase[0].name!r} (finer sets unwrap from it)")
    covered = 2 ** gray.bits * phase[0].period_px / 2
    if covered < desc.projector_width_px:
        need = math.ceil(math.log2(2 * desc.projector_width_px / phase[0].period_px))
        raise ConfigError(
            f"periods cannot be unwrapped: set {gray.name!r} with bits = {gray.bits} codes "
            f"{covered:g} px (2**bits half-periods of {phase[0].period_px:g} px) < "
            f"projector_width_px = {desc.projector_width_px}; use bits = {need}")


def _check_ratios(desc: PatternDescription, phase: tuple) -> None:
    """Successive periods must be distinct and within max_period_ratio."""
    limit = desc.thresholds.max_period_ratio
    for coarse, fine in itertools.pairwise(phase):
        ratio = coarse.period_px / fine.period_px
        if ratio <= 1 + 1e-9 or ratio > limit:
            raise ConfigError(
                f"periods cannot be unwrapped: set {coarse.name!r} (period_px = "
                f"{coarse.period_px:g}) cannot unwrap set {fine.name!r} (period_px = "
                f"{fine.period_px:g}): the ratio {ratio:.4g} must be > 1 and <= "
                f"thresholds.max_period_ratio = {limit:g}; add an intermediate period")


# ---------------------------------------------------------------------------- parsing

_TOP_KEYS = ("format", "projector_width_px", "description", "sensor", "thresholds", "set")
_STORAGE_KEYS = ("name", "orientation", "files", "stack", "stack_key")
_SET_KEYS = {
    "phase": ("kind", "period_px", "steps", "shifts_rad", *_STORAGE_KEYS),
    "gray": ("kind", "bits", "orders", "inverse", *_STORAGE_KEYS),
}


def load_patterns(path: str | os.PathLike) -> PatternDescription:
    """Load and validate a ``patterns.toml`` (or the one inside a folder).

    Parameters
    ----------
    path : str or PathLike
        The patterns.toml file, or the pattern folder that contains it.

    Returns
    -------
    PatternDescription
        The validated description, with ``source`` set to the file path.

    Raises
    ------
    ConfigError
        On a missing/unreadable file, bad TOML, an unknown or missing key, a bad value,
        a wrong count of files, or periods that cannot unwrap each other.
    """
    data, p = read_patterns_file(path)
    return patterns_from_dict(data, source=str(p))


def patterns_from_dict(data: dict, source: str = "<dict>") -> PatternDescription:
    """Validate a parsed patterns.toml given as nested dicts.

    Parameters
    ----------
    data : dict
        The parsed TOML.
    source : str
        File name used in error messages and to resolve relative image paths.
    """
    try:
        return _from_dict(data, source)
    except ConfigError as err:
        raise ConfigError(f"{err} (in {source})") from None
    except TypeError as err:
        raise ConfigError(f"bad value in pattern description: {err} (in {source})") from None


def _from_dict(data: dict, source: str) -> PatternDescription:
    _reject_unknown("", data, _TOP_KEYS)
    fmt = data.get("format")
    _require(fmt == FORMAT, "format", fmt, f"{FORMAT!r} (the only version this scanqa reads)")
    _require("projector_width_px" in data, "projector_width_px", None,
             "given (the coded range along the fringe direction [projector px])")
    sensor = SensorModel(**_table("sensor", data.get("sensor", {}), SensorModel))
    thresholds = Thresholds(**_table("thresholds", data.get("thresholds", {}), Thresholds))
    raw_sets = data.get("set", [])
    _require(isinstance(raw_sets, list) and len(raw_sets) > 0, "set", raw_sets,
             "one or more [[set]] tables")
    sets = tuple(_parse_set(i, t) for i, t in enumerate(raw_sets))
    return PatternDescription(projector_width_px=_integer("projector_width_px",
                                                          data["projector_width_px"]),
                              sets=sets, sensor=sensor, thresholds=thresholds,
                              description=str(data.get("description", "")), source=source)


def _reject_unknown(prefix: str, table: dict, known: Sequence[str]) -> None:
    for key in table:
        if key not in known:
            raise ConfigError(f"unknown key {prefix}{key} (known keys: {', '.join(known)})")


def _table(name: str, table: Any, cls: type) -> dict:
    """Keys of an optional table, checked against the dataclass fields and types."""
    _require(isinstance(table, dict), f"[{name}]", table, "a table")
    known = list(cls.__dataclass_fields__)
    _reject_unknown(f"{name}.", table, known)
    out = {}
    for key, value in table.items():
        whole = key == "bit_depth"
        out[key] = _integer(f"{name}.{key}", value) if whole else _number(f"{name}.{key}",
                                                                          value)
    return out


def _number(key: str, value: Any) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    _require(ok and math.isfinite(value), key, value, "a finite number")
    return float(value)


def _integer(key: str, value: Any) -> int:
    ok = isinstance(value, int) and not isinstance(value, bool)
    _require(ok, key, value, "a whole number")
    return int(value)


def _parse_set(index: int, table: Any) -> PhaseSet | GrayCodeSet:
    """One ``[[set]]`` table, with its storage (files or stack) checked."""
    where = f"set[{index}]"
    _require(isinstance(table, dict), where, table, "a table")
    kind = table.get("kind")
    _require(kind in _SET_KEYS, f"{where}.kind", kind, "'phase' or 'gray'")
    _reject_unknown(f"{where}.", table, _SET_KEYS[kind])
    args = {k: v for k, v in table.items() if k != "kind"}
    args.setdefault("name", f"{kind}{index}")
    for key in ("name", "orientation", "stack", "stack_key", "orders"):
        if key in args:
            _require(isinstance(args[key], str), f"{where}.{key}", args[key], "a string")
    if kind == "phase":
        _require("period_px" in args and "steps" in args, where, sorted(args),
                 "a table with period_px and steps")
        args["period_px"] = _number(f"{where}.period_px", args["period_px"])
        args["steps"] = _integer(f"{where}.steps", args["steps"])
        args["shifts_rad"] = tuple(_number(f"{where}.shifts_rad", v)
                                   for v in _list(f"{where}.shifts_rad",
                                                  args.get("shifts_rad", [])))
        pset: PhaseSet | GrayCodeSet = PhaseSet(**args)
    else:
        _require("bits" in args, where, sorted(args), "a table with bits")
        args["bits"] = _integer(f"{where}.bits", args["bits"])
        _require(isinstance(args.get("inverse", False), bool), f"{where}.inverse",
                 args.get("inverse"), "true or false")
        pset = GrayCodeSet(**args)
    _check_storage(where, pset, table)
    return pset


def _list(key: str, value: Any) -> list:
    _require(isinstance(value, list), key, value, "a list")
    return value


def _check_storage(where: str, pset: PhaseSet | GrayCodeSet, table: dict) -> None:
    """Exactly one of files (with the right count) and stack."""
    has_files, has_stack = "files" in table, "stack" in table
    _require(has_files != has_stack, where, sorted(table),
             "a table with either files = [...] or stack = '...' (not both)")
    if has_files:
        files = _list(f"{where}.files", table["files"])
        _require(all(isinstance(f, str) for f in files), f"{where}.files", files,
                 "a list of file names")
        if len(files) != pset.frames:
            what = (f"steps = {pset.frames}" if isinstance(pset, PhaseSet) else
                    f"bits = {pset.bits}{' x 2 (inverse = true)' if pset.inverse else ''}")
            raise ConfigError(f"wrong count of files in {where} ({pset.name!r}): got "
                              f"{len(files)}, need {pset.frames} ({what})")
    elif "stack_key" in table and not pset.stack.lower().endswith(".npz"):
        raise ConfigError(f"{where}.stack_key is only meaningful with a .npz stack")
