"""``scanqa describe``, blind (the projector size only), on the conformance corpus of
:mod:`describe_corpus`: captures of the layouts public tools write, with 8-bit
quantisation, residual gamma, stray light and blur.

The 12 tuning layouts were chosen and the generator written before describe was tuned
on them (5 of 12 right before, 12 of 12 after; with the scene and noise of seeds 1 and 2
also 12 of 12, once a tie between fringe counts that fit equally well - 59 and 177 for
the three-frequency set - went to the fewest); describe must be right on at least 11.
The held-out layouts were not looked at while tuning; at their first run, after tuning,
1 of 3 was right: the DLP rows (1140 px, 4 bits of 114-px cells) took 76-px cells
(76, 95 and 114 all divide 1140 and fit the bits; describe asks which), and a 7-step
heterodyne of 45, 40 and 5 fringes was read as 9, 8 and 1 (the same ratios: the frames
cannot tell, describe asks). The test keeps that first-run count as its floor.

Issue 44's second round (plain binary codes decoded as such, phase starts of phase sets
without a Gray code) added four held-out layouts, written before describe was changed
for them (:func:`describe_corpus.held_out_binary_and_starts`). At their first run 1 of 4
was right, and that only by its periods, steps and signs (the heterodyne whose phases
start off the cue's decoded 0 %): plain binary with grouped inverses, LSB first, was
read inverse-first (the choice was made on the reflected reading, which a binary code
does not make smooth), a binary row code without inverses or references lost its three
coarse bit planes to a "3-step set" (and describe crashed on the one bit left), the
cue with two finer sets starting off zero decoded 0 %. Fixed after that run (so no
longer held out): the four readings of a Gray run are compared at once, a period that
cannot be measured is a question; with phase starts measured against the cue the
heterodyne decodes 94 %. Still wrong: the binary rows (the run split) and the cue with
a 16-px set, which the 160-px camera of the corpus samples at 2.3 px per period (its
period is measured 16.41; the 80-px set's start 1.192 rad against 1.2). The floor is
the count after the fixes, 2.

Issue 44's third round (session 43) wrote nine more layouts and committed them before
describe was changed (:func:`describe_corpus.held_out_round3`: DLP projectors of other
sizes than the 912 x 1140 kept back, period-wide Gray cells least significant bit first
and a black frame only, 50 % square-wave and clipped fringes, rows or columns alone, 3-
to 5-step sets, a heterodyne triple, kamino410's coding on a 1280 x 720 projector,
both phase sets before both Gray codes with the camera rolled 25 degrees; gamma, blur,
stray light, a clipping camera, checker, speckle and striped albedos). They are judged
as the held-out acceptance judges the kept-back scanner (:func:`describe_corpus.
judge_hand`: >= 90 % of the pixels the true description decodes, median |x_p
difference| <= 2 px, non-sine fringes named). Blind, at their first run: 2 of 9 (6 of 9
by :func:`describe_corpus.judge`, against the true x_p): the rolled camera's Gray frames
were merged across directions and a coarse bit that looked black was taken for the
black frame (describe refused), no fringe profile was ever named, cells of a 1024 x 600
DLP's rows and of the kamino410-like coding were the wrong ones of several that fit.
Fixed after that run: Gray frames oriented by their stripes' direction against the
phase sets', a frame beside a cleaner reference of its level read as a bit, the
profile measured and named, whole-pixel shifts of binary fringes, the coarsest set's
cycles in view as a lower bound of its fringe count: 5 of 9 (7 of 9 against the true
x_p); the phase start of binary fringes measured over whole Gray cells (their staircase
read at the edges alone put it up to 0.25 rad off on a DLP's simulated rows; found on
probes of 912 x 1140 captures, not on these layouts) left the count at 5. Still wrong:
the cells of the 1024 x 600 rows (40 taken, 50 projected) and of the
1280 x 720 kamino410-like coding (50 taken, 64 projected) - both fit the bits and the
cells seen and decode alike, and the files ask; the clipped 4-step sines and the
2.5-px-blurred square waves are not named, and the decoder's own check does not flag
them either (their x_p error is below 3 % of the period). Three fresh layouts written
after the fixes (:func:`describe_corpus.fresh_after_round3`) were right on 2 of 3 at
their first run: the rows of 90-px square-wave cells over 800 px were taken as 100-px
cells (the roundest; 90 does not divide 800).
"""

from __future__ import annotations

import pytest

from scanqa.description.inference import describe_frames
from scanqa.errors import ScanQAError
from tests import describe_corpus as corpus


def run_layout(layout: corpus.Layout, seed: int = 0) -> corpus.Verdict:
    """Capture, describe blind, judge."""
    images, sc = corpus.capture(layout, seed)
    try:
        described = describe_frames(images, corpus.frame_names(layout), layout.width,
                                    layout.height)
    except ScanQAError as exc:
        return corpus.Verdict(layout.name, False, f"describe refused: {exc}", {})
    return corpus.judge(layout, images, sc, described)


def _report(verdicts) -> str:
    return "; ".join(f"{v.layout}: {'right' if v.right else 'WRONG ' + v.why} {v.shares}"
                     for v in verdicts)


def test_the_corpus_has_twelve_tuning_layouts_of_distinct_conventions():
    layouts = corpus.tuning_layouts()
    assert len(layouts) == 12 and len({x.name for x in layouts}) == 12
    held = {x.name for x in corpus.held_out_layouts() + corpus.held_out_binary_and_starts()
            + corpus.held_out_round3() + corpus.fresh_after_round3()}
    assert len(held) == 19 and not held & {x.name for x in layouts}


@pytest.mark.slow
def test_describe_is_right_on_at_least_11_of_12_tuning_layouts():
    verdicts = [run_layout(x) for x in corpus.tuning_layouts()]
    right = sum(v.right for v in verdicts)
    assert right >= 11, _report(verdicts)


@pytest.mark.slow
def test_describe_on_held_out_layouts():
    verdicts = [run_layout(x) for x in corpus.held_out_layouts()]
    assert sum(v.right for v in verdicts) >= 1, _report(verdicts)


@pytest.mark.slow
def test_describe_on_binary_and_phase_start_layouts():
    verdicts = [run_layout(x) for x in corpus.held_out_binary_and_starts()]
    assert sum(v.right for v in verdicts) >= 2, _report(verdicts)


def run_layout_hand(layout: corpus.Layout, seed: int = 0) -> corpus.Verdict:
    """Capture, describe blind, judge against the hand description."""
    images, _ = corpus.capture(layout, seed)
    try:
        described = describe_frames(images, corpus.frame_names(layout), layout.width,
                                    layout.height)
    except ScanQAError as exc:
        return corpus.Verdict(layout.name, False, f"describe refused: {exc}", {})
    return corpus.judge_hand(layout, images, described)


@pytest.mark.slow
def test_describe_on_round3_held_out_layouts():
    verdicts = [run_layout_hand(x) for x in corpus.held_out_round3()]
    assert sum(v.right for v in verdicts) >= 5, _report(verdicts)


@pytest.mark.slow
def test_describe_on_fresh_layouts_after_round3():
    verdicts = [run_layout_hand(x) for x in corpus.fresh_after_round3()]
    assert sum(v.right for v in verdicts) >= 2, _report(verdicts)
