"""Closed loops through synthetic captures (tests/synth_fringes.py): every pixel the code
can decode is decoded, and each misdescription is caught from the captures themselves.

The captures are 8-bit frames of a blurred projector (an OpenCV-style Gray code, each
bit followed by its inverse, a white and a black frame, two non-nested 3-step periods)
on a smooth surface whose x_p is known. ``TUNED`` seeds and rigs are the ones the
thresholds of :mod:`scanqa.decoding.checks` were chosen on; ``HELD_OUT`` ones were run
only after, and are reported apart in docs/codings.rst ("What the captures say").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.patternset import write_pattern_set
from scanqa.errors import InputError
from tests.synth_fringes import THREE, Rig, capture, description, order_errors, stacks

#: The rig and seed the thresholds were tuned on, and the ones held out.
TUNED = (Rig(cell=4.0, bits=8, periods=(100.0, 66.667), blur=1.5), 0)
HELD_OUT = (Rig(cell=2.0, bits=9, width=1000, periods=(80.0, 57.0), blur=2.0,
                noise_dn=2.5), 7)
CASES = pytest.mark.parametrize("case", [TUNED, HELD_OUT], ids=["tuned", "held_out"])
REVERSED = tuple(-s for s in THREE)


def _decode(rig: Rig, seed: int, frames=None, **stated):
    if frames is None:
        frames, _ = capture(rig, seed)
    desc, keys = description(rig, **stated)
    return decode_images(desc, stacks(frames, keys))


def _warnings(pm) -> list[str]:
    return pm.provenance["decode"]["warnings"]


@CASES
@pytest.mark.parametrize("stated", [{}, {"phase": False}, {"gray": False, "reference": False,
                                                          "coarse": True}],
                         ids=["gray_and_phase", "gray_alone", "phase_alone"])
def test_a_correct_description_decodes_every_pixel_without_a_warning(case, stated):
    rig, seed = case
    stated = dict(stated)
    if stated.pop("coarse", False):  # phase sets alone need a period covering the panel
        rig = Rig(**{**rig.__dict__, "periods": (float(rig.width), rig.periods[-1])})
    frames, x = capture(rig, seed)
    pm = _decode(rig, seed, frames, **stated)
    valid, wrong = order_errors(pm, x, rig.periods[-1] if stated.get("phase", True)
                                else 4 * rig.cell)
    assert valid >= 0.98, pm.summary()  # before issue 26: 0.47-0.95 with the Gray code
    assert wrong == 0.0
    assert _warnings(pm) == [] and "warning" not in pm.summary()


@pytest.mark.parametrize("rig,before", [
    (Rig(jump=137.0, albedo=0.15), 0.29),  # tuned on: 1-px cells, 100 / 66.667 px
    (Rig(cell=2.0, bits=9, periods=(80.0, 57.0), blur=2.0, noise_dn=2.5, jump=300.0,
         albedo=0.2), 0.53)], ids=["tuned", "held_out"])
def test_gray_cell_edges_of_a_dark_surface_with_a_depth_edge_are_kept(rig, before):
    # rows darkening to 15-20 % reflectance and a depth edge through the middle column:
    # valid 0.29 and 0.53 before issue 26 (edge bands masked), 0.98 and 0.94 after,
    # with no pixel off by a fringe order (seeds 0, 5, 9 alike)
    frames, x = capture(rig, 5)
    pm = _decode(rig, 5, frames)
    valid, wrong = order_errors(pm, x, rig.periods[-1])
    assert valid >= before + 0.35 and wrong == 0.0, pm.summary()
    assert _warnings(pm) == []  # dark rows do not look like a misdescription


@CASES
@pytest.mark.parametrize("error", [0.005, 0.015])
@pytest.mark.parametrize("which", [0, 1])
def test_a_misstated_period_is_named(case, error, which):
    rig, seed = case
    periods = list(rig.periods)
    periods[which] = round(periods[which] * (1 + error), 3)
    pm = _decode(rig, seed, periods=tuple(periods))
    text = " ".join(_warnings(pm)) + " ".join(r["step"] for r in
                                             pm.provenance["decode"]["misstated"])
    assert "period_px is misstated" in text or pm.provenance["decode"]["misstated"], \
        pm.summary()


@CASES
def test_a_reversed_shift_sign_against_the_gray_code_is_named(case):
    rig, seed = case
    pm = _decode(rig, seed, shifts=REVERSED)
    assert "misstated coding? step" in pm.summary()
    assert any("phase-shift sign is reversed" in w for w in _warnings(pm)), pm.summary()


@CASES
def test_a_reversed_shift_sign_of_phase_sets_alone_is_named(case):
    # the sets mirror together and agree: only x_p running against the camera shows it
    rig, seed = case
    rig = Rig(**{**rig.__dict__, "periods": (float(rig.width), rig.periods[-1])})
    pm = _decode(rig, seed, shifts=REVERSED, gray=False, reference=False)
    # where the coarse period is not a multiple of the fine one, the mirrored sets
    # disagree instead, and the guard's search names the sign
    assert any(("the decode looks mirrored" in w and "shifts_rad" in w)
               or "phase-shift sign is reversed" in w for w in _warnings(pm)), pm.summary()


@CASES
def test_white_and_black_swapped_are_named(case):
    rig, seed = case
    pm = _decode(rig, seed, levels=("black", "white"))
    assert any("white and black are swapped" in w for w in _warnings(pm)), pm.summary()


@CASES
def test_inverse_frames_in_another_layout_are_named(case):
    rig, seed = case
    pm = _decode(rig, seed, inverse="grouped")  # captured interleaved
    assert any("not in the stated order" in w for w in _warnings(pm)), pm.summary()
    assert any("set inverse = 'interleaved'" in w for w in _warnings(pm))


@CASES
@pytest.mark.parametrize("phase", [True, False])
def test_inverse_frames_before_their_bits_are_named(case, phase):
    rig, seed = case
    frames, _ = capture(rig, seed)
    g = frames["gray"]
    frames["gray"] = g.reshape(rig.bits, 2, *g.shape[1:])[:, ::-1].reshape(g.shape)
    pm = _decode(rig, seed, frames, phase=phase)
    expected = "each bit and its inverse are swapped" if phase else "decode looks mirrored"
    assert any(expected in w for w in _warnings(pm)), pm.summary()


@pytest.mark.parametrize("blur,box", [(6.0, 0.0), (3.0, 12.0), (10.0, 0.0)])
def test_gray_bits_finer_than_the_optics_are_dropped_with_a_note(blur, box):
    # 2-px cells, 10 bits and inverses ordering a 64 px phase: before issue 26 0.0-0.1 %
    # of the pixels decoded (the fine bits read noise); dropped, every pixel decodes
    rig = Rig(cell=2.0, bits=10, width=2000, periods=(64.0,), blur=blur, box=box)
    frames, x = capture(rig, 3)
    pm = _decode(rig, 3, frames)
    valid, wrong = order_errors(pm, x, 64.0)
    assert valid >= 0.99 and wrong == 0.0, pm.summary()
    notes = [n for n in pm.provenance["decode"]["notes"] if "finer than the optics" in n]
    assert len(notes) == 1 and "10 (0 %" in notes[0], pm.summary()
    assert _warnings(pm) == []


def test_no_order_is_left_when_the_resolved_cells_outgrow_the_period():
    rig = Rig(cell=1.0, bits=11, width=2000, periods=(6.0,), blur=8.0)
    with pytest.raises(InputError, match="no fringe order can be decided"):
        _decode(rig, 4)


def test_the_command_line_prints_warnings_loudly(tmp_path, capsys):
    rig, seed = TUNED
    frames, _ = capture(rig, seed)
    desc, keys = description(rig, levels=("black", "white"))
    write_pattern_set(tmp_path / "scan", desc, stacks(frames, keys))
    assert main(["decode", str(tmp_path / "scan"), "--out", str(tmp_path / "p.npz")]) == 0
    out, err = capsys.readouterr()
    assert "scanqa: warning: set 'wb': the frames named white are darker" in err
    assert "\nwarning: set 'wb'" in out


def _phase_alone(case):
    """The case's rig with a cue of one period across the panel and its finest set."""
    rig, seed = case
    return Rig(**{**rig.__dict__, "periods": (float(rig.width), rig.periods[-1])}), seed


@CASES
@pytest.mark.parametrize("misstated,cause", [
    ("fine_sign", "set 'p1' alone has its phase-shift sign reversed"),
    ("fine_period_half", "period(p0) / period(p1) ="),
    ("files_swapped", "are swapped"),
    ("frame_twice", "one image is listed twice"),
], ids=["fine_sign", "fine_period_half", "files_swapped", "frame_twice"])
def test_phase_sets_that_contradict_each_other_mask_every_pixel(case, misstated, cause):
    # the residual test of decoding/consistency was tuned on real captures only
    # (skull_2x3); these synthetic rigs are held out for it
    rig, seed = _phase_alone(case)
    frames, _ = capture(rig, seed)
    desc, keys = description(rig, gray=False, reference=False)
    images = stacks(frames, keys)
    cue, fine = desc.sets
    if misstated == "fine_sign":
        desc = replace(desc, sets=(cue, replace(fine, shifts_rad=REVERSED)))
    elif misstated == "fine_period_half":
        desc = replace(desc, sets=(cue, replace(fine, period_px=fine.period_px / 2)))
    elif misstated == "files_swapped":
        images = images[::-1]
    else:
        images = [images[0], images[1].copy()]
        images[1][2] = images[0][0]
    pm = decode_images(desc, images)
    assert pm.valid.sum() == 0, pm.summary()
    if misstated == "fine_period_half" and case is HELD_OUT:
        # 1000 / 28.5 px: the cue's noise times the ratio exceeds P_f / 6 at every
        # pixel, so no pixel qualifies and the test is silent; the unwrap step's own
        # noise margin masks every pixel (low_modulation) - no wrong x_p, but the hint
        # still points at thresholds (a limitation, docs/codings.rst)
        assert pm.provenance["decode"]["consistency"][0]["pixels"] == 0
        return
    assert any(cause in w for w in _warnings(pm)), _warnings(pm)
    assert "fix patterns.toml" in pm.summary()


@CASES
def test_phase_sets_that_agree_pass_the_residual_test(case):
    rig, seed = _phase_alone(case)
    frames, _ = capture(rig, seed)
    pm = decode_images(*_desc_and_stacks(rig, frames))
    (pair,) = pm.provenance["decode"]["consistency"]
    assert not pair["contradicted"] and pair["resultant"] > 0.8 * pair["predicted"]


def _desc_and_stacks(rig, frames):
    desc, keys = description(rig, gray=False, reference=False)
    return desc, stacks(frames, keys)


def test_a_drift_that_steps_is_not_called_a_misstated_period():
    # a misstated period parts the coordinates along a line; a coarse set's own
    # distortion steps or bends (the real board's cue: a 20 px step between two rows)
    from scanqa.decoding.checks import period_drift
    from scanqa.decoding.coding import PatternDescription, PhaseSet

    desc = PatternDescription(1000, (PhaseSet("fine", 50.0, 3), PhaseSet("cue", 1000.0, 3)))
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 1000.0, 20000)
    line = period_drift(desc, {"cue": 0.012 * x + rng.normal(0, 2.0, x.size)}, {"cue": x})
    step = period_drift(desc, {"cue": np.where(x > 600, 12.0, 0.0) + rng.normal(0, 2.0, x.size)},
                        {"cue": x})
    assert len(line) == 1 and "a period_px is misstated" in line[0]
    suggested = float(line[0].split("has period_px ")[1].split()[0])
    assert suggested == pytest.approx(50.0 * 1.012, abs=0.01)
    assert len(step) == 1 and "not along a line" in step[0] and "misstated" in step[0]
    assert "a period_px is misstated" not in step[0]
