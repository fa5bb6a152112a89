"""``scanqa describe``: the pattern description of existing captures, inferred from them.

The frames are split into sets by :mod:`scanqa.description.frames`; this module measures
what each set codes and checks the guess with scanqa's decoder:

* the direction of a set is that of its fringe slope (along the camera rows: vertical
  fringes, projector columns; along the columns: rows);
* the sign of a phase set's shifts is the sign of its phase slope for shifts
  ``+2 pi k / N``, assuming that the projector coordinate grows with the camera
  coordinate (the camera beside the projector, neither mirrored); with a Gray code, the
  Gray code's own direction decides;
* period ratios come from the phase slopes of two sets on the same image segments
  (:func:`scanqa.description.frames.frequency_ratio`), a phase set's period in Gray cells
  from its phase at the Gray code's cell edges (:func:`~scanqa.description.gray.
  refine_ratio`, snapped to a simple fraction), and its phase start from the same
  edges (:func:`~scanqa.description.gray.edge_offsets`, added to its shifts);
* the absolute scale needs the projector size along the coded direction: phase sets
  are taken to repeat a whole number of times over it (``P = W / n``, the fewest that
  fit, e.g. a coarse set of one period over the panel or a heterodyne triple whose
  beat covers it); a Gray code is taken to need all its bits with whole-pixel cells
  that put the last cell seen on the panel - pinned when the panel's far edge is in
  view, else the same cell for columns and rows, then cells dividing the width, the
  roundest, the finest (:func:`~scanqa.description.gray.rank_cells`);
* the candidates the measurement leaves open are decoded (on about 200 x 400 pixels,
  :mod:`scanqa.description.evidence`, which also reads the fringe profile, the cycles in
  view and the phase start of binary fringes over whole cells); the likeliest is kept
  unless another decodes clearly more, the others are reported, and the description
  says how sure it is.

Everything the frames cannot tell is said in the written file as a question.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, PhaseSet, ReferenceSet
from scanqa.description import evidence as ev
from scanqa.description import frames as fr
from scanqa.description.gray import (
    GrayRun,
    cell_range,
    cells_seen,
    code_note,
    confidence_line,
    cue_offsets,
    edge_offsets,
    gray_layout,
    panel_edge_seen,
    rank_cells,
    read_gray,
    refine_ratio,
    simple_ratio,
    slope_sign,
    with_code,
)
from scanqa.errors import ConfigError, InputError

#: Largest count of fringes over the panel searched for phase-only codings [-].
MAX_FRINGES = 256


@dataclass(frozen=True)
class SetNote:
    """What is known about one set: how sure, what was assumed, what is asked."""

    name: str
    sure: str
    notes: tuple = ()
    questions: tuple = ()


@dataclass(frozen=True)
class Description:
    """The inferred description of one coded direction.

    Attributes
    ----------
    desc : PatternDescription
        The sets with their frame files, ready to write.
    set_notes : tuple of SetNote
        One per set of ``desc.sets``.
    valid_share : float
        Share of the lit pixels the decoding check decoded [-].
    notes, questions : tuple of str
        About the whole description.
    checked : tuple of int
        Rows and columns of the sample the decoding check read [camera px].
    confidence : str
        "sure", "likely" or "unsure", with the shares decoded by the chosen and the
        next candidate and the count of open questions.
    """

    desc: PatternDescription
    set_notes: tuple
    valid_share: float
    notes: tuple = ()
    questions: tuple = ()
    checked: tuple = ()
    confidence: str = ""


@dataclass
class _Group:
    """Working state of one direction while it is described."""

    orientation: str
    width_px: int | None
    runs: list
    levels: tuple = ()
    notes: list = field(default_factory=list)
    questions: list = field(default_factory=list)
    gray: GrayRun | None = None
    cells: np.ndarray | None = None
    range: tuple = ()
    cell_choices: list = field(default_factory=list)
    set_notes: dict = field(default_factory=dict)
    profiles: list = field(default_factory=list)  # FringeProfile or None per phase run


def describe_frames(images: np.ndarray, names: list[str], width_px: int | None = None,
                    height_px: int | None = None) -> list[Description]:
    """Infer the pattern description(s) of a sequence of camera frames.

    Parameters
    ----------
    images : (K, H, W) array
        The frames in projection order [DN].
    names : list of str
        File name of each frame, as the description should list it.
    width_px, height_px : int, optional
        Projector size [px]: the coded range of vertical (columns) and horizontal
        (rows) fringes.

    Returns
    -------
    list of Description
        One per coded direction (columns first).

    Raises
    ------
    InputError
        When fewer than 2 frames are given or no set is found.
    """
    if images.ndim != 3 or images.shape[0] < 2 or len(names) != images.shape[0]:
        raise InputError(f"describe needs at least 2 frames of one size with a name "
                         f"each, got {images.shape[0] if images.ndim == 3 else 0}")
    data = images.astype(np.float32)
    norm = fr.normalise(data)
    refs = fr.reference_frames(norm)
    blank = [k for k in range(len(names)) if k not in refs and float(np.ptp(data[k])) <= 2]
    if blank:
        raise InputError(f"frame {names[blank[0]]} is blank (every pixel within 2 DN of "
                         f"{float(data[blank[0]].mean()):.0f} DN) and is no white or black "
                         "frame at the ends of the sequence: a dropped or overwritten "
                         "capture; replace it, or list the frames without it")
    levels = tuple(fr.frame_level(norm, k) for k in refs)
    if refs:
        lo = [data[k] for k, v in zip(refs, levels, strict=True) if v == "black"]
        hi = [data[k] for k, v in zip(refs, levels, strict=True) if v == "white"]
        norm = fr.normalise(data, np.mean(lo, 0) if lo else None,
                            np.mean(hi, 0) if hi else None, out=norm.n)
    runs = fr.split_runs(data, norm, refs)
    lone = ()
    if refs and len(set(levels)) < 2:  # a black (or white) frame alone: no reference set
        lone = tuple(f"{names[k]} ({v})" for k, v in zip(refs, levels, strict=True))
        runs = [r for r in runs if r.kind != "reference"]
        refs, levels = (), ()
    stray = [r for r in runs if r.kind == "gray" and len(r.frames) <= 2 and all(
        fr.frame_level(norm, k) for k in r.frames)]  # uniform frames between sets
    if stray:
        lone += tuple(f"{names[k]} ({fr.frame_level(norm, k)})" for r in stray
                      for k in r.frames)
        runs = [r for r in runs if r not in stray]
    coded = [r for r in runs if r.kind != "reference"]
    if not coded:
        raise InputError("no phase set or Gray code found among the frames (only uniform "
                         "frames?)")
    groups = []
    for orientation, size in (("vertical", width_px), ("horizontal", height_px)):
        group = [r for r in coded if r.orientation == orientation]
        if group:
            ref = [r for r in runs if r.kind == "reference"]
            g = _Group(orientation, size, ref + group, levels)
            if lone:
                g.notes.append(f"uniform frame {', '.join(lone)} left out: the decoder's "
                               "reference set needs a white and a black frame")
            _read_group_gray(data, norm, g)
            groups.append(g)
    _joint_cells(groups)
    return [_describe_group(images, data, norm, names, g) for g in groups]


def _read_group_gray(data: np.ndarray, norm: fr.Normalised, group: _Group) -> None:
    """The group's Gray code read (bits, layout, cells) and the cell widths it allows."""
    axis = 1 if group.orientation == "vertical" else 0
    grays = [r for r in group.runs if r.kind == "gray"]
    if not grays:
        return
    gray = gray_layout(norm, grays, axis, group, group.set_notes)
    if len(grays) > 1:
        group.questions.append(f"{len(grays)} separate runs of binary frames were found; "
                               "only the first is used as the Gray code - are the others "
                               "part of it?")
    gray, cells = read_gray(data, norm, gray, axis, group)
    group.gray, group.cells = gray, cells
    if group.width_px is not None:
        top = cells_seen(group.cells, 2 ** gray.bits)
        edge = panel_edge_seen(group.cells, top, axis)
        group.range = cell_range(group.width_px, gray.bits, top, edge)
        if edge:
            group.notes.append(f"the panel's far edge is seen in Gray cell {top}: the "
                               f"cells are {group.width_px / (top + 1):.4g} to "
                               f"{group.width_px / top:.4g} px wide")


def _joint_cells(groups: list) -> None:
    """Cell widths for each Gray code, likeliest first: the same cell in both
    directions when their ranges allow one (one tool setting), else each its own."""
    coded = [g for g in groups if g.range]
    joint = [(g.width_px, g.range) for g in coded]
    together = rank_cells(joint) if len(joint) > 1 else []
    for g in coded:
        g.cell_choices = together or rank_cells([(g.width_px, g.range)])
        if together:
            g.notes.append("the same Gray cell width is assumed for columns and rows")


def _describe_group(images: np.ndarray, data: np.ndarray, norm: fr.Normalised,
                    names: list[str], group: _Group) -> Description:
    """Sets, scale and the decoding check of one direction."""
    axis = 1 if group.orientation == "vertical" else 0
    phase = [r for r in group.runs if r.kind == "phase"]
    ref = next((r for r in group.runs if r.kind == "reference"), None)
    notes = group.set_notes
    gray, cells = group.gray, group.cells
    direction = 1.0
    if gray is not None:
        direction = slope_sign(cells, norm.lit, axis)
        if direction < 0:
            group.questions.append("the Gray code's cells grow against the camera axis: "
                                   "is the projector image mirrored? (x_p then runs the "
                                   "other way)")
    zs = [fr.phasor(data[list(r.frames)], r.order) for r in phase]
    signs = [direction * _sign(fr.phase_frequency(z, axis)) for z in zs]
    _ask_about_runs(group, phase, zs, axis, names)
    group.profiles = [ev.fringe_profile(images[list(r.frames)], _shifts(sign, r), norm.lit)
                      for r, sign in zip(phase, signs, strict=True)]
    candidates = _candidates(data, norm, phase, zs, gray, cells, axis, group, signs)
    if gray is not None:  # the other code too: decoding tells a plain binary code apart
        candidates += [(with_code(d), offsets) for d, offsets in candidates]
    stacks = ev.sample_stacks(images, _frame_lists(group, phase, gray, ref))
    best, share, tried = None, -1.0, []
    for desc, offsets in candidates:
        desc = _with_signs(desc, signs, [r.order for r in phase], offsets)
        got = ev.check(desc, stacks, norm.lit)
        tried.append((desc, got))
        margin = ev.SCALE_MARGIN if ev.scale_only(desc, best) else ev.MARGIN
        if got > share + (margin if tried[1:] else 0.0):  # the likelier kept unless worse
            best, share = desc, got
    if tried and 0 <= share < 0.3 and tried[0][1] >= 0 and best is not tried[0][0]:
        best, share = tried[0]  # none decodes: the best measured fit is kept
        group.questions.append("no candidate decodes 30 % of the lit pixels: the periods "
                               "that fit the measured ratios best were kept - is the "
                               "decoder able to unwrap them (noise, a beat of beats)?")
    if best is None:
        raise InputError(f"no consistent description of the {group.orientation} sets was "
                         f"found ({'; '.join(group.questions) or 'nothing decoded'})")
    best = _with_files(best, names, group, phase, gray, ref)
    if gray is not None:
        code_note(best, tried, gray, group.notes)
    for pset, profile in zip(best.phase_sets, group.profiles, strict=True):
        if profile is not None:
            group.notes.append(profile.note(pset.name, pset.steps, pset.period_px))
    if ev.noise_note(best):
        group.notes.append(ev.noise_note(best))
    ev.alternatives(best, tried, share, group.questions)
    set_notes = _set_notes(best, phase, gray, ref, signs, direction, notes, group)
    sample = (len(range(0, images.shape[1], ev.row_step(images.shape[1]))),
              len(range(0, images.shape[2], ev.column_step(images.shape[2]))))
    return Description(best, set_notes, share, tuple(group.notes), tuple(group.questions),
                       sample, confidence_line(best, share, tried, len(group.questions)))


def _ask_about_runs(group: _Group, phase: list, zs: list, axis: int,
                    names: list[str]) -> None:
    """Questions for runs whose direction or shift sign the frames barely show."""
    for run in group.runs:
        if run.kind != "reference" and run.anisotropy < 1.5:
            group.questions.append(
                f"frames {_frame_range(run.frames, names)} vary almost as much along the rows as "
                f"along the columns (ratio {run.anisotropy:.2f}): are they "
                f"{'columns' if group.orientation == 'vertical' else 'rows'} as assumed?")
    for run, z in zip(phase, zs, strict=True):
        along, across = (abs(fr.phase_frequency(z, a)) for a in (axis, 1 - axis))
        if along < 3 * max(across, 1e-6) and along < 1e-3:
            group.questions.append(
                f"the phase of frames {_frame_range(run.frames, names)} hardly changes across the "
                "image: the sign of their shifts is a guess - which way do they run?")


def _frame_range(frames, names: list[str]) -> str:
    first, last = names[frames[0]], names[frames[-1]]
    return f"{first}..{last}" if len(frames) > 1 else first


def _sign(value: float) -> float:
    return -1.0 if value < 0 else 1.0


def _shifts(sign: float, run: fr.Run) -> tuple:
    """A phase run's shifts from its sign and step order (no start) [rad]."""
    steps = len(run.frames)
    return tuple(sign * 2 * math.pi * k / steps for k in (run.order or range(steps)))


# ------------------------------------------------------------------- periods and cells

@dataclass(frozen=True)
class _Scale:
    """The measured scale: periods (or cells) and what was assumed to get them."""

    width_px: int
    periods: tuple  # one per phase run [projector px]
    cell_px: float | None
    evidence: str
    question: str = ""
    offsets: tuple = ()  # phase start of each run [rad], added to its shifts


def _candidates(data, norm, phase, zs, gray, cells, axis, group, signs) -> list:
    """Descriptions the measurement leaves open (decoded later to choose)."""
    usable = norm.lit & np.all([np.abs(z) > 0.1 * np.percentile(np.abs(z)[norm.lit], 95)
                                for z in zs], axis=0) if zs else norm.lit
    memo: dict = {}  # the cue's unit phasors and starts, shared by the candidates
    scales = (_gray_scales(phase, zs, gray, cells, axis, usable, group, signs) if gray
              else [replace(s, offsets=cue_offsets(zs, signs, s.periods, s.width_px, usable,
                                                   memo))
                    for s in _phase_scales(phase, zs, axis, usable, group)])
    out = []
    for scale in scales:
        try:
            out.append((_build(scale, phase, gray, group), scale.offsets))
        except ConfigError:
            continue
    return out


def _phase_scales(phase, zs, axis, usable, group) -> list[_Scale]:
    """Phase sets alone: whole numbers of fringes over the panel, fewest first."""
    if group.width_px is None:
        raise InputError(f"the projector size along the {group.orientation} fringes is "
                         f"needed to state periods in projector pixels (the frames give "
                         f"only period ratios): give "
                         f"{'width_px' if group.orientation == 'vertical' else 'height_px'}")
    ratios, spreads = _ratios(phase, zs, axis, usable)  # coarsest period / each period
    seen = ev.fewest_fringes(zs[ratios.index(1.0)], axis, usable)
    loose, score = [], {}
    for t in range(max(1, math.ceil(seen - 0.3)), MAX_FRINGES + 1):
        counts = [t * r for r in ratios]
        gaps = [abs(c - max(1, round(c))) for c in counts]
        if all(g <= 0.03 * c + 0.05 for g, c in zip(gaps, counts, strict=True)):
            loose.append(t)  # within 3 %: what a real scene's bias allows
            score[t] = max(g / (c * max(sd, 2e-4))
                           for g, c, sd in zip(gaps, counts, spreads, strict=True))
    if not loose:
        return []
    if seen >= 1.3:
        group.notes.append(f"the coarsest set's phase runs through {seen:.1f} cycles in view: "
                           f"it has at least {math.ceil(seen - 0.3)} fringes over the panel")
    # in measured spreads; within one spread alike (a multiple of the right counts fits
    # as well), and the fewest counts first among them
    best = sorted(loose, key=lambda t: (max(score[t], 1.0), t))[:3]
    out = []  # the best fit first: it is kept when decoding cannot tell
    for t in best:
        if t != loose[0]:
            out.extend(_variants([max(1, round(t * r)) for r in ratios], group.width_px,
                                 ratios)[:1])
    fewest = _variants([max(1, round(loose[0] * r)) for r in ratios], group.width_px,
                       ratios)
    return (fewest + out) if best[0] == loose[0] else (out[:1] + fewest + out[1:])


def _ratios(phase, zs, axis, usable) -> tuple[list[float], list[float]]:
    """Period of the coarsest set over each set's period [-] (1 for the coarsest), and
    the relative uncertainty of each [-]."""
    slopes = [abs(fr.phase_frequency(z, axis)) for z in zs]
    finest = int(np.argmax(slopes))
    rel, spread = [], []
    for i, z in enumerate(zs):
        r, sd = (1.0, 0.0) if i == finest else fr.frequency_ratio(
            zs[finest], z, axis, usable, len(phase[i].frames))
        if not math.isfinite(r):
            r, sd = slopes[i] / slopes[finest], 0.1
        rel.append(abs(r))
        spread.append(sd)
    coarsest = int(np.argmin(rel))
    return ([r / rel[coarsest] for r in rel],
            [math.hypot(sd, spread[coarsest]) for sd in spread])


def _variants(whole: list[int], width: int, ratios: list[float]) -> list[_Scale]:
    """The fringe counts found, and the finest one and one fewer or more."""
    fine = int(np.argmax(whole))
    out = []
    for delta in (0, -1, 1):
        n = list(whole)
        n[fine] += delta
        if n[fine] < 1 or (delta and n[fine] in n[:fine] + n[fine + 1:]):
            continue
        evidence = (f"{', '.join(f'{c:.3f}' for c in ratios)} times the coarsest "
                    f"frequency measured; taken as {', '.join(map(str, n))} fringes over "
                    f"the {width} px given")
        out.append(_Scale(width, tuple(width / k for k in n), None, evidence))
    return out


def _gray_scales(phase, zs, gray, cells, axis, usable, group, signs) -> list[_Scale]:
    """A Gray code: whole-pixel cells that cover the panel; periods in cells (simple
    fractions of a cell where the measurement allows); each set's phase start from the
    phase at the Gray code's cell edges."""
    count = 2 ** gray.bits
    width = group.width_px
    choices = group.cell_choices
    if width is None:
        width = int(count)
        choices = [1]
        group.questions.append(f"the projector size was not given: cells of 1 px assumed "
                               f"({count} px coded, as OpenCV's GrayCodePattern); give "
                               f"--projector-{'width' if axis == 1 else 'height'}")
    if not choices:
        group.questions.append(f"no whole-pixel cell lets {gray.bits} Gray bits cover "
                               f"{width} px: is the projector size right?")
        return []
    ratios = []
    for z, run in zip(zs, phase, strict=True):
        zg = np.exp(2j * np.pi * np.nan_to_num(cells) / count)
        r, _ = fr.frequency_ratio(z, zg, axis, usable & np.isfinite(cells),
                                  len(run.frames))
        if not (math.isfinite(r) and r != 0):
            group.questions.append(f"the period of frames {run.frames[0]}.. could not be "
                                   "measured against the Gray code (too few clean image "
                                   "segments): what is it?")
            return []
        ratios.append(refine_ratio(z, cells, axis, abs(r) * count))  # period in cells
    if len(choices) > 1 and any(p is not None and p.staircase for p in group.profiles):
        ordered = ev.whole_shift_first(choices, [simple_ratio(r) for r in ratios],
                                       [len(r.frames) for r in phase], width)
        if ordered[0] != choices[0]:
            group.notes.append(f"binary fringes are shifted by whole projector pixels: of "
                               f"the cells that divide {width} px, {ordered[0]:g} px is the "
                               f"one whose periods are (P / N whole), not {choices[0]:g}")
        choices = ordered
    straight = [z if p is None else ev.straightened(z, sign, len(r.frames), usable)
                for z, sign, r, p in zip(zs, signs, phase, group.profiles, strict=True)]
    lo, hi = cell_range(width, gray.bits, 0)
    out = []
    for cell in choices[:3]:
        evidence = (f"{gray.bits} bits cover {width} px with cells of {lo:.4g} to "
                    f"{hi:.4g} px; periods of {', '.join(f'{r:.4f}' for r in ratios)} "
                    f"cells measured")
        for snap in (True, False):
            periods = tuple(cell * (simple_ratio(r) if snap else r) for r in ratios)
            offsets = edge_offsets(straight, signs, cells, float(cell), periods, axis)
            whole = [ev.cell_offsets(z, sign, cells, float(cell), period, axis)
                     if p is not None and p.staircase else None
                     for z, sign, period, p in zip(straight, signs, periods,
                                                   group.profiles, strict=True)]
            offsets = tuple(o if w is None else w for o, w in zip(offsets, whole,
                                                                  strict=True))
            scale = _Scale(width, periods, float(cell), evidence, offsets=offsets)
            if scale not in out:
                out.append(scale)
    if len(choices) > 1:
        others = ", ".join(f"{c:g}" for c in choices[1:4])
        group.questions.append(
            f"cell_px = {choices[0]:g} was taken (cells that divide the coded width first, "
            f"then the roundest); cells of {others} px fit the bits and the cells seen "
            "too and decode alike (x_p scales with the cell) - which one was projected?")
    return out


def _build(scale: _Scale, phase, gray, group) -> PatternDescription:
    """The description of one candidate (files still empty, sets in reading order)."""
    sets: list = []
    ref = next((r for r in group.runs if r.kind == "reference"), None)
    if ref is not None:
        sets.append(ReferenceSet("white_black", group.levels))
    if gray is not None:
        sets.append(GrayCodeSet("gray", gray.bits, cell_px=scale.cell_px,
                                inverse=gray.inverse, orientation=group.orientation,
                                code=gray.code))
    for run, period in zip(phase, scale.periods, strict=True):
        sets.append(PhaseSet(_phase_name(period, sets), float(period), len(run.frames),
                             orientation=group.orientation))
    desc = PatternDescription(int(scale.width_px), tuple(sets),
                              description=f"scanqa describe: {scale.evidence}")
    return desc


def _phase_name(period: float, sets: list) -> str:
    """``p<period>`` (3 decimals at most), unique among the sets."""
    name = f"p{float(f'{period:.3f}'):g}"
    taken = {s.name for s in sets}
    return name if name not in taken else f"{name}_{len(sets)}"


def _with_signs(desc: PatternDescription, signs: list[float], orders: list[tuple],
                offsets: tuple = ()) -> PatternDescription:
    """The phase sets' shifts with the measured signs, step orders and phase starts
    (in run order)."""
    sets, i = [], 0
    for s in desc.sets:
        if isinstance(s, PhaseSet):
            steps = orders[i] or range(s.steps)
            start = offsets[i] if offsets else 0.0
            shifts = tuple(signs[i] * 2 * math.pi * k / s.steps + start for k in steps)
            if orders[i] or start:  # stated in [0, 2 pi), whatever the sign
                shifts = tuple(round(v % (2 * math.pi), 9) % (2 * math.pi) for v in shifts)
            s = replace(s, shifts_rad=tuple(0.0 if v == 0 else v for v in shifts))
            i += 1
        sets.append(s)
    return replace(desc, sets=tuple(sets))


def _frame_lists(group: _Group, phase: list, gray: GrayRun | None, ref) -> list[list[int]]:
    """Frame indices of every set of a built description, in its set order."""
    lists = [list(ref.frames)] if ref is not None else []
    if gray is not None:
        lists.append(list(gray.order))
    return lists + [list(r.frames) for r in phase]


def _with_files(desc, names, group, phase, gray, ref) -> PatternDescription:
    """The chosen description with the frame file names of every set."""
    lists = _frame_lists(group, phase, gray, ref)
    sets = tuple(replace(s, files=tuple(names[k] for k in idx))
                 for s, idx in zip(desc.sets, lists, strict=True))
    return replace(desc, sets=sets)


def _set_notes(desc, phase, gray, ref, signs, direction, notes, group) -> tuple:
    """How sure each set is and what it assumes."""
    out = []
    phase_sets = [s for s in desc.sets if isinstance(s, PhaseSet)]
    for s in desc.sets:
        if isinstance(s, ReferenceSet):
            out.append(SetNote(s.name, "sure", ("uniform frames: " + ", ".join(s.levels),)))
        elif isinstance(s, GrayCodeSet):
            cell = desc.description.removeprefix("scanqa describe: ")
            code = ("plain binary code (its bits a base-2 number), checked by decoding "
                    "against a reflected Gray code" if s.code == "binary" else
                    "reflected Gray code, checked by decoding against plain binary")
            out.append(SetNote(s.name, "sure" if not group.questions else "likely", (
                f"{s.bits} bits, most significant first; inverse frames: {s.inverse}",
                f"cell_px = {s.cell_px:g}: {cell}", code)))
    for s, sign, run in zip(phase_sets, signs, phase, strict=True):
        way = "negative" if sign < 0 else "positive"
        if run.order:
            ks = [round(v * s.steps / (2 * math.pi)) % s.steps for v in s.shifts_rad]
            way = (f"out of order: k = {', '.join(map(str, ks))} in frame order (from the "
                   "frames' correlations), i.e. positive")
        basis = ("the Gray code's direction" if gray is not None else
                 "the assumption that the projector coordinate grows along the camera's "
                 + ("rows" if s.orientation == "vertical" else "columns"))
        start = ()
        if gray is not None and not run.order:
            start = (f"phase start {s.shifts_rad[0]:.3f} rad (added to every shift), "
                     "measured at the Gray code's cell edges",)
        out.append(SetNote(s.name, "sure" if gray is not None else "likely", (
            f"{s.steps} steps, shifts {way} 2 pi k / {s.steps} (from the phase slope and "
            f"{basis})", *start)))
    if phase_sets and gray is None:
        group.questions.append(
            f"the frames give period ratios only: is the projector "
            f"{desc.projector_width_px} px along this direction, and does every pattern "
            "repeat a whole number of times over it (the periods assume both)?")
    order = {n.name: n for n in out}
    return tuple(order[s.name] for s in desc.sets)
