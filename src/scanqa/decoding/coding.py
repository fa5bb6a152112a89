"""Pattern codings: what was projected, as described by a ``patterns.toml``.

A pattern folder holds the camera images of one scan and a ``patterns.toml`` that says
what was projected (docs/codings.rst shows every supported layout). This module holds
the decoder's own types - the coding (:class:`PatternDescription` with its
:class:`PhaseSet`, :class:`GrayCodeSet` and :class:`ReferenceSet` entries), the camera
noise model (:class:`SensorModel`), the decision thresholds (:class:`Thresholds`) and
the decoding options (:class:`DecodeOptions`) - and checks that a coding can be
decoded; :mod:`scanqa.decoding.parsing` validates a parsed file into them,
:mod:`scanqa.io.patterns` reads and writes the file itself.

Gray code convention: a Gray-code set of ``bits`` bits and cells of ``cell_px``
projector columns codes the cell index ``c = floor((x + 1/2) / cell_px)`` of the
projector coordinate x (pixel centres at whole x, so projector column j belongs to
cell ``floor(j / cell_px)``) as the reflected binary code ``g = c ^ (c >> 1)``; frame b
(b = 0 is the most significant bit) is white where bit ``bits - 1 - b`` of g is set.
Inverse frames follow all bits ("grouped") or each bit ("interleaved"). Without
``cell_px`` the cells are half the period of the set the code orders (stripes of half a
period make the fringe order robust to a Gray-code error of one stripe at its edges).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from scanqa.decoding import chain
from scanqa.errors import ConfigError
from scanqa.io.patterns import FORMAT

#: Fringe orientations: "vertical" fringes code x_p (columns), "horizontal" y_p (rows).
ORIENTATIONS = ("vertical", "horizontal")
#: Layouts of a Gray code's inverse frames.
INVERSE_LAYOUTS = ("none", "grouped", "interleaved")
#: How a Gray code's bits are thresholded.
GRAY_THRESHOLDS = ("auto", "inverse", "reference", "offset")
#: How a Gray-code set writes its cell index: reflected binary Gray, or plain binary.
GRAY_CODES = ("reflected", "binary")
#: Levels of a reference set's frames.
REFERENCE_LEVELS = ("white", "black")
#: Where the decoder takes the camera noise from.
NOISE_SOURCES = ("auto", "sensor", "data")


@dataclass(frozen=True)
class SensorModel:
    """Intensity noise model of the camera (the ``[sensor]`` table).

    Attributes
    ----------
    bit_depth : int or None
        Bits per sample [bit]; None takes it from the images (8 for 8-bit files, 16 for
        16-bit files and float stacks).
    gain_e_per_dn : float or None
        Conversion gain [e-/DN]; shot-noise variance is (I - black) / gain [DN^2].
        None (with ``read_noise_e`` None): the decoder estimates the noise from the
        images (:mod:`scanqa.decoding.noise`).
    read_noise_e : float or None
        Read (dark) noise [e-]; None as for ``gain_e_per_dn``.
    saturation_dn : float or None
        Level at or above which a sample is saturated [DN]; None means
        ``2**bit_depth - 1``.
    black_level_dn : float
        Dark offset subtracted before the shot-noise term [DN].
    """

    bit_depth: int | None = None
    gain_e_per_dn: float | None = None
    read_noise_e: float | None = None
    saturation_dn: float | None = None
    black_level_dn: float = 0.0

    def __post_init__(self) -> None:
        require_setting(self.bit_depth is None or 1 <= self.bit_depth <= 32,
                 "sensor.bit_depth", self.bit_depth, "a whole number in 1..32 [bit]")
        require_setting(self.gain_e_per_dn is None or self.gain_e_per_dn > 0,
                 "sensor.gain_e_per_dn", self.gain_e_per_dn, "> 0 [e-/DN]")
        require_setting(self.read_noise_e is None or self.read_noise_e >= 0, "sensor.read_noise_e",
                 self.read_noise_e, ">= 0 [e-]")
        require_setting((self.gain_e_per_dn is None) == (self.read_noise_e is None),
                 "sensor.gain_e_per_dn and sensor.read_noise_e",
                 (self.gain_e_per_dn, self.read_noise_e),
                 "both given (the camera's noise) or both left out (noise from the data)")
        require_setting(self.saturation_dn is None or self.saturation_dn > 0,
                 "sensor.saturation_dn", self.saturation_dn, "> 0 [DN]")
        require_setting(self.black_level_dn >= 0, "sensor.black_level_dn", self.black_level_dn,
                 ">= 0 [DN]")

    @property
    def knows_noise(self) -> bool:
        """True when gain and read noise are given."""
        return self.gain_e_per_dn is not None

    def resolved(self, dtype: np.dtype) -> SensorModel:
        """Copy with ``bit_depth`` and ``saturation_dn`` filled in from an image dtype."""
        bits = self.bit_depth or (8 if np.dtype(dtype) == np.uint8 else 16)
        sat = self.saturation_dn if self.saturation_dn is not None else 2.0 ** bits - 1
        return replace(self, bit_depth=bits, saturation_dn=float(sat))

    @property
    def read_noise_dn(self) -> float:
        """Read noise in image units [DN]."""
        if not self.knows_noise:
            raise ConfigError("the sensor noise is not known yet (estimate it from the data "
                              "or give sensor.gain_e_per_dn and sensor.read_noise_e)")
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
        Largest accepted disagreement between a set and the estimate that unwraps it
        [cycles of the set's period]; beyond it the pixel is inconsistent.
    unwrap_sigma_margin : float
        Noise margin of every fringe-order decision [-]. A set's own phase is too
        noisy when its predicted standard deviation times this margin exceeds the
        accepted residual. An unwrapping step keeps a pixel while the odds of the
        neighbouring order against the one taken, ``exp(-(1 - 2 |r|) / (2 sigma^2))``
        for its observed residual r and predicted standard deviation sigma [cycles],
        stay below those of a ``3 margin`` standard deviation excursion (6 for the
        default: sigma up to 0.167 cycles where r = 0, 0.118 where r reaches
        ``unwrap_max_residual``); a Gray code's order needs ``3 margin`` standard
        deviations of the phase between it and the decision boundary.
    gray_edge_cells : float
        How far the phase may fall outside the Gray-code cell it was decoded in [cells]
        (blur and noise at the cell edges); limited to ``(P - cell) / 2`` so that one
        fringe order is accepted at most.
    gray_min_contrast_sigma : float
        A Gray-code bit whose contrast is below this many noise standard deviations
        is undecidable, and the pixel has too low a modulation - unless, in a Gray
        code decoded alone, it is the one such bit between two neighbouring cells
        (the pixel then takes their edge, :mod:`scanqa.decoding.gray`) [-].
    max_period_ratio : float
        Largest ratio between the period of an estimate (times its noise
        amplification) and the period it unwraps [-].
    coincidence_fraction : float
        A set (or Gray code) whose share of inconsistent pixels reaches this fraction
        of what unrelated patterns would give is taken as misstated, and every pixel
        is masked [-].
    """

    min_modulation_dn: float = 0.0
    unwrap_max_residual: float = 0.25
    unwrap_sigma_margin: float = 2.0
    gray_edge_cells: float = 0.25
    gray_min_contrast_sigma: float = 3.0
    max_period_ratio: float = 64.0
    coincidence_fraction: float = 0.7

    def __post_init__(self) -> None:
        require_setting(self.min_modulation_dn >= 0, "thresholds.min_modulation_dn",
                 self.min_modulation_dn, ">= 0 [DN]")
        require_setting(0 < self.unwrap_max_residual < 0.5, "thresholds.unwrap_max_residual",
                 self.unwrap_max_residual, "in (0, 0.5) [cycles]")
        require_setting(self.unwrap_sigma_margin >= 1, "thresholds.unwrap_sigma_margin",
                 self.unwrap_sigma_margin, ">= 1 [-]")
        require_setting(0 <= self.gray_edge_cells < 8, "thresholds.gray_edge_cells",
                 self.gray_edge_cells, "in [0, 8) [cells]")
        require_setting(self.gray_min_contrast_sigma >= 0, "thresholds.gray_min_contrast_sigma",
                 self.gray_min_contrast_sigma, ">= 0 [-]")
        require_setting(self.max_period_ratio > 1, "thresholds.max_period_ratio",
                 self.max_period_ratio, "> 1 [-]")
        require_setting(0 < self.coincidence_fraction <= 1, "thresholds.coincidence_fraction",
                 self.coincidence_fraction, "in (0, 1] [-]")


@dataclass(frozen=True)
class DecodeOptions:
    """How to decode (the ``[decode]`` table).

    Attributes
    ----------
    fuse_periods : bool
        False (default): x_p comes from the finest phase set alone, coarser sets and
        the Gray code decide its fringe order only. True: every phase set is fused by
        inverse-variance weighting (systematic differences between periods then bias
        x_p; the decode summary says so).
    noise : str
        "auto": the ``[sensor]`` noise model when it gives gain and read noise, else
        the noise estimated from the images; "sensor" or "data" force one.
    channel : str
        "red", "green" or "blue": the channel of colour images that carries the
        fringes; empty for grey images.
    response : str
        Projector response file (phase-error tables written by ``scanqa decode
        --measure-response``) applied to every phase set; relative paths are relative
        to the patterns.toml folder; empty for none.
    """

    fuse_periods: bool = False
    noise: str = "auto"
    channel: str = ""
    response: str = ""

    def __post_init__(self) -> None:
        require_setting(isinstance(self.fuse_periods, bool), "decode.fuse_periods",
                 self.fuse_periods, "true or false")
        require_setting(self.noise in NOISE_SOURCES, "decode.noise", self.noise,
                 "'auto', 'sensor' or 'data'")
        require_setting(self.channel in ("", "red", "green", "blue"), "decode.channel",
                 self.channel, "'red', 'green' or 'blue' (or left out for grey images)")


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
        Image files in frame order, relative to the patterns.toml folder (or absolute).
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
        require_setting(math.isfinite(self.period_px) and self.period_px > 0,
                 f"{where}: period_px", self.period_px, "> 0 [projector px]")
        require_setting(isinstance(self.steps, int) and self.steps >= 3, f"{where}: steps",
                 self.steps, "a whole number >= 3")
        _check_orientation(where, self.orientation)
        shifts = tuple(float(s) for s in self.shifts_rad) or tuple(
            2 * math.pi * k / self.steps for k in range(self.steps))
        require_setting(len(shifts) == self.steps, f"{where}: shifts_rad", list(self.shifts_rad),
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
    """A Gray-code set (``kind = "gray"``): alone, or ordering a phase set.

    Attributes
    ----------
    name : str
        Label used in messages.
    bits : int
        Number of Gray-code bits (bit planes), most significant first [-].
    cell_px : float or None
        Width of one code cell [projector px]; None: half the period of the ordered
        phase set.
    orders : str
        Name of the phase set it orders; empty means the coarsest phase set (a scan
        without phase sets is decoded from the Gray code alone).
    inverse : str
        "none", "grouped" (all bits, then all inverses) or "interleaved" (each bit
        followed by its inverse); True and False are read as "grouped" and "none".
    threshold : str
        "inverse" (bit against its inverse frame), "reference" (against the mid level
        of the white and black frames of the reference set), "offset" (against the
        offset A of the ordered phase set) or "auto" (the first of these the scan has).
    orientation : str
        "vertical" (columns, x_p) or "horizontal" (rows, y_p).
    files, stack, stack_key
        As for :class:`PhaseSet`.
    code : str
        "reflected" (a reflected binary Gray code, the default) or "binary" (the cell
        index written as a plain binary number).
    """

    name: str
    bits: int
    cell_px: float | None = None
    orders: str = ""
    inverse: Any = "none"
    threshold: str = "auto"
    orientation: str = "vertical"
    files: tuple = ()
    stack: str = ""
    stack_key: str = ""
    code: str = "reflected"

    def __post_init__(self) -> None:
        where = f"set {self.name!r}"
        require_setting(self.code in GRAY_CODES, f"{where}: code", self.code,
                        "'reflected' (Gray) or 'binary' (plain binary)")
        require_setting(isinstance(self.bits, int) and 1 <= self.bits <= 24, f"{where}: bits",
                 self.bits, "a whole number in 1..24")
        require_setting(self.cell_px is None or (math.isfinite(self.cell_px) and self.cell_px > 0),
                 f"{where}: cell_px", self.cell_px, "> 0 [projector px]")
        inverse = {True: "grouped", False: "none"}.get(self.inverse, self.inverse) \
            if isinstance(self.inverse, bool) else self.inverse
        require_setting(inverse in INVERSE_LAYOUTS, f"{where}: inverse", self.inverse,
                 "'none', 'grouped' or 'interleaved'")
        require_setting(self.threshold in GRAY_THRESHOLDS, f"{where}: threshold", self.threshold,
                 "'auto', 'inverse', 'reference' or 'offset'")
        _check_orientation(where, self.orientation)
        object.__setattr__(self, "inverse", inverse)
        object.__setattr__(self, "files", tuple(self.files))

    @property
    def frames(self) -> int:
        """Number of images in the set [-]."""
        return self.bits * (1 if self.inverse == "none" else 2)

    def frame_order(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Frame indices of the bit patterns and of their inverses (or None)."""
        bits = np.arange(self.bits)
        if self.inverse == "none":
            return bits, None
        if self.inverse == "grouped":
            return bits, bits + self.bits
        return 2 * bits, 2 * bits + 1


@dataclass(frozen=True)
class ReferenceSet:
    """Uniform white and black frames (``kind = "reference"``).

    They give the Gray code a per-pixel threshold (the mid level of white and black)
    and the noise estimate repeats of the same level.

    Attributes
    ----------
    name : str
        Label used in messages.
    levels : tuple of str
        "white" or "black" for each frame, in frame order (at least one of each).
    files, stack, stack_key
        As for :class:`PhaseSet`.
    """

    name: str
    levels: tuple = ("white", "black")
    files: tuple = ()
    stack: str = ""
    stack_key: str = ""

    def __post_init__(self) -> None:
        levels = tuple(self.levels)
        require_setting(all(v in REFERENCE_LEVELS for v in levels) and "white" in levels
                 and "black" in levels, f"set {self.name!r}: levels", list(levels),
                 "a list of 'white' and 'black' with at least one of each")
        object.__setattr__(self, "levels", levels)
        object.__setattr__(self, "files", tuple(self.files))

    @property
    def frames(self) -> int:
        """Number of images in the set [-]."""
        return len(self.levels)

    @property
    def orientation(self) -> str:
        """Uniform frames have no orientation; any set's is accepted."""
        return ""


@dataclass(frozen=True)
class PatternDescription:
    """A whole ``patterns.toml``: coded range, sensor, thresholds, options and sets.

    Attributes
    ----------
    projector_width_px : int
        Coded range along the fringe direction [projector px]: x_p in [-0.5, width - 0.5).
    sets : tuple of PhaseSet, GrayCodeSet and ReferenceSet
        In file order.
    sensor : SensorModel
        Camera noise model.
    thresholds : Thresholds
        Decision thresholds.
    description : str
        Free text.
    source : str
        The patterns.toml path (file names are relative to its folder).
    options : DecodeOptions
        How to decode.
    """

    projector_width_px: int
    sets: tuple
    sensor: SensorModel = field(default_factory=SensorModel)
    thresholds: Thresholds = field(default_factory=Thresholds)
    description: str = ""
    source: str = ""
    options: DecodeOptions = field(default_factory=DecodeOptions)

    def __post_init__(self) -> None:
        require_setting(isinstance(self.projector_width_px, int) and self.projector_width_px >= 1,
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
    def reference_set(self) -> ReferenceSet | None:
        """The white/black reference set, if any."""
        return next((s for s in self.sets if isinstance(s, ReferenceSet)), None)

    @property
    def ordered_set(self) -> PhaseSet | None:
        """The phase set the Gray code orders (None without Gray code or phase sets)."""
        gray, phase = self.gray_set, self.phase_sets
        if gray is None or not phase:
            return None
        return next(s for s in phase if s.name == (gray.orders or phase[0].name))

    @property
    def gray_cell_px(self) -> float:
        """Width of a Gray-code cell [projector px] (0 without Gray code)."""
        gray = self.gray_set
        if gray is None:
            return 0.0
        return gray.cell_px if gray.cell_px is not None else self.ordered_set.period_px / 2

    @property
    def gray_threshold(self) -> str:
        """The Gray code's threshold with "auto" resolved ("" without Gray code)."""
        gray = self.gray_set
        if gray is None:
            return ""
        return _resolve_threshold(self, gray)

    @property
    def working_period_px(self) -> float:
        """The finest period (the Gray cell for a Gray code alone) [projector px]."""
        phase = self.phase_sets
        return phase[-1].period_px if phase else self.gray_cell_px

    @property
    def orientation(self) -> str:
        """The common fringe orientation."""
        return next(s.orientation for s in self.sets if not isinstance(s, ReferenceSet))

    def to_dict(self) -> dict:
        """Plain dict in the patterns.toml layout (for provenance and writing)."""
        out: dict[str, Any] = {"format": FORMAT, "projector_width_px": self.projector_width_px}
        if self.description:
            out["description"] = self.description
        sensor = {k: v for k, v in asdict(self.sensor).items() if v is not None}
        if sensor != {"black_level_dn": 0.0}:
            out["sensor"] = sensor
        out["thresholds"] = asdict(self.thresholds)
        out["decode"] = asdict(self.options)
        out["set"] = [_set_dict(s) for s in self.sets]
        return out


def _set_dict(pset: PhaseSet | GrayCodeSet | ReferenceSet) -> dict:
    """One ``[[set]]`` table as a dict, leaving out empty and default-free keys."""
    kind = {PhaseSet: "phase", GrayCodeSet: "gray", ReferenceSet: "reference"}[type(pset)]
    out: dict[str, Any] = {"kind": kind}
    for key, value in asdict(pset).items():
        if value is None or (value in ("", ()) and key in ("files", "stack", "stack_key",
                                                          "orders")) or (
                key == "code" and value == "reflected"):  # the default, as before the key
            continue
        out[key] = list(value) if isinstance(value, tuple) else value
    return out


def require_setting(ok: bool, key: str, value: Any, expected: str) -> None:
    """Raise ConfigError ``key must be <expected>, got <value>`` unless ok."""
    if not ok:
        raise ConfigError(f"{key} must be {expected}, got {value!r}")


def _check_orientation(where: str, orientation: str) -> None:
    require_setting(orientation in ORIENTATIONS, f"{where}: orientation", orientation,
             "'vertical' or 'horizontal'")


def _check_shifts(where: str, shifts: Sequence[float]) -> None:
    """Shifts must determine (A, B cos phi, B sin phi) by least squares."""
    design = np.column_stack([np.ones(len(shifts)), np.cos(shifts), np.sin(shifts)])
    if np.linalg.cond(design) > 1e6:
        raise ConfigError(f"{where}: shifts_rad {list(shifts)} do not determine the phase "
                          "(need at least 3 shifts that differ modulo 2 pi)")


def _check_sets(desc: PatternDescription) -> None:
    """Cross-set rules: names, orientation, set counts, a chain that unwraps."""
    require_setting(len(desc.sets) > 0, "set", [], "at least one [[set]] table")
    names = [s.name for s in desc.sets]
    dup = sorted({n for n in names if names.count(n) > 1})
    require_setting(not dup, "set names", dup, "unique (set a distinct name = ...)")
    coded = [s for s in desc.sets if not isinstance(s, ReferenceSet)]
    require_setting(len(coded) > 0, "set", names, "at least one set with kind = 'phase' or 'gray'")
    orient = {s.orientation for s in coded}
    require_setting(len(orient) == 1, "orientation", sorted(orient),
             "the same for every set (decode x_p and y_p from separate pattern folders)")
    for kind in (GrayCodeSet, ReferenceSet):
        many = [s.name for s in desc.sets if isinstance(s, kind)]
        require_setting(len(many) <= 1, "set", many, f"at most one set of kind "
                 f"{'gray' if kind is GrayCodeSet else 'reference'}")
    gray = desc.gray_set
    if gray is not None:
        _check_gray(desc, gray)
    phase = desc.phase_sets
    if phase:
        ordered = desc.ordered_set
        chain.plan_chain([s.period_px for s in phase], [s.name for s in phase],
                         desc.projector_width_px, desc.thresholds.max_period_ratio,
                         start=None if ordered is None else phase.index(ordered))


def _check_gray(desc: PatternDescription, gray: GrayCodeSet) -> None:
    """The Gray code must cover the coded range and be able to order its phase set."""
    phase = desc.phase_sets
    where = f"set {gray.name!r}"
    if gray.orders:
        require_setting(any(s.name == gray.orders for s in phase), f"{where}: orders", gray.orders,
                 "the name of a phase set (one of "
                 f"{', '.join(s.name for s in phase) or 'none: the scan has no phase set'})")
    require_setting(bool(phase) or gray.cell_px is not None, f"{where}: cell_px", None,
             "given when the scan has no phase set (the Gray code is then decoded alone)")
    cell = desc.gray_cell_px
    covered = 2 ** gray.bits * cell
    if covered < desc.projector_width_px:
        cell_hint = "cell_px" if gray.cell_px is not None else \
            f"cell_px (now half the period of set {desc.ordered_set.name!r})"
        raise ConfigError(
            f"periods cannot be unwrapped: set {gray.name!r} codes {2 ** gray.bits} cells "
            f"of {cell:g} px = {covered:g} px (bits = {gray.bits}, {gray.frames} frames) < "
            f"projector_width_px = {desc.projector_width_px}; check projector_width_px "
            f"(the coded width, at most {covered:g} px with these frames) and {cell_hint} "
            f"(at least {desc.projector_width_px / 2 ** gray.bits:g} px for "
            f"{2 ** gray.bits} cells)")
    ordered = desc.ordered_set
    if ordered is not None and cell > ordered.period_px * (1 + 1e-9):
        raise ConfigError(
            f"set {gray.name!r} cannot order set {ordered.name!r}: its cells of {cell:g} px "
            f"are wider than the period {ordered.period_px:g} px; check cell_px and "
            f"period_px, or order a coarser set with orders = ...")
    _resolve_threshold(desc, gray)


def _resolve_threshold(desc: PatternDescription, gray: GrayCodeSet) -> str:
    """The Gray threshold in use; raise when the scan lacks what it needs."""
    has = {"inverse": gray.inverse != "none", "reference": desc.reference_set is not None,
           "offset": desc.ordered_set is not None}
    if gray.threshold == "auto":
        for name in ("inverse", "reference", "offset"):
            if has[name]:
                return name
        raise ConfigError(
            f"set {gray.name!r}: a Gray code alone needs a threshold per pixel: list its "
            "inverse frames (inverse = 'interleaved' or 'grouped') or add a set with "
            "kind = 'reference' holding white and black frames")
    need = {"inverse": "inverse frames (inverse = 'interleaved' or 'grouped')",
            "reference": "a set with kind = 'reference' (white and black frames)",
            "offset": "a phase set to order"}
    require_setting(has[gray.threshold], f"set {gray.name!r}: threshold", gray.threshold,
             f"a threshold the scan provides ({gray.threshold!r} needs "
             f"{need[gray.threshold]})")
    return gray.threshold


#: The noise model assumed where neither the camera nor the data tell it (4 e-/DN, 8 e-).
DEFAULT_SENSOR = SensorModel(gain_e_per_dn=4.0, read_noise_e=8.0)
