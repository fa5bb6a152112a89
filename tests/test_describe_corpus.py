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
    held = {x.name for x in corpus.held_out_layouts()}
    assert not held & {x.name for x in layouts}


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
