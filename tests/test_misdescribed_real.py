"""Misdescribed real captures (SLStudio's skull and calibration board, README in the
real-data folder): the residual test of :mod:`scanqa.decoding.consistency` against the
captures' own description.

The thresholds were chosen on ``skull_2x3`` variants only; the board's twelve sets
(``calseq1..6``, columns frames 00-05 and rows 06-11) were run only afterwards and are
the held-out set. The truth is the README's description: 3-step sets of 114 px and
1824 px along columns (71.25 px and 1140 px along rows), shifts 0, -2 pi/3, -4 pi/3.
Each test reads the 64 sampled rows the decoder's checks read, except the one end-to-end
decode through the command line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from scanqa.cli import main
from scanqa.decoding import checks, consistency
from scanqa.decoding.coding import GrayCodeSet, PatternDescription, PhaseSet, ReferenceSet
from scanqa.decoding.decoder import decode
from scanqa.decoding.noise import resolve_noise
from scanqa.io.patterns import dumps_patterns
from tests.realdata import SLSTUDIO, SLSTUDIO_SHIFTS, needs_slstudio

pytestmark = needs_slstudio

REVERSED = tuple(-s for s in SLSTUDIO_SHIFTS)


def _sample(folder, indices, ext: str) -> list[np.ndarray]:
    """The 64 sampled rows of each frame, as the decoder's checks read them [DN]."""
    frames = [np.asarray(Image.open(SLSTUDIO / folder / f"frameSeq_{i:02d}.{ext}")
                         .convert("L")) for i in indices]
    return list(checks.sample_rows([np.stack(frames)])[0])


def _desc(width: int, fine: float, orientation: str = "vertical", *, fine_period=None,
          cue_period=None, fine_shifts=SLSTUDIO_SHIFTS) -> PatternDescription:
    return PatternDescription(width, (
        PhaseSet("fine", float(fine_period or fine), 3, shifts_rad=tuple(fine_shifts),
                 orientation=orientation),
        PhaseSet("cue", float(cue_period or width), 3, shifts_rad=tuple(SLSTUDIO_SHIFTS),
                 orientation=orientation)))


def _pair(desc: PatternDescription, fine_frames, cue_frames, sensor=None):
    """The residual test, with the camera noise estimated from the images as a decode
    does (or given, to estimate it once for many variants of one capture)."""
    stacks = [np.stack(fine_frames), np.stack(cue_frames)]
    if sensor is None:
        sensor = resolve_noise(desc, stacks, desc.sensor.resolved(stacks[0].dtype),
                               True).sensor
    (pair,) = consistency.set_consistency(desc, stacks, sensor, True)
    return pair


@pytest.fixture(scope="module")
def skull() -> list[np.ndarray]:
    return _sample("skull_2x3", range(6), "bmp")


def test_skull_2x3_as_captured_agrees_with_its_description(skull):
    # tuned on: R 0.714 against 0.873 predicted from the noise (ratio 0.82)
    pair = _pair(_desc(1824, 114.0), skull[:3], skull[3:])
    assert not pair.contradicted
    assert pair.resultant > 0.75 * pair.predicted


@pytest.mark.parametrize("variant,cause", [
    ({"fine_shifts": REVERSED}, "set 'fine' alone has its phase-shift sign reversed"),
    ({"fine_period": 57.0}, "period(cue) / period(fine) = 16, the description 32"),
    ({"cue_period": 3648.0}, "period(cue) / period(fine) = 16, the description 32"),
], ids=["fine_shifts_neg", "fine_period_57", "cue_period_3648"])
def test_skull_2x3_misdescriptions_that_decoded_silently_are_named(skull, variant, cause):
    # before: exit 0, 8.6 % / 3.3 % / 1.9 % of the pixels valid, x_p off by a median
    # 14.6 / 7.7 / 798 px, and advice to lower thresholds or add light
    pair = _pair(_desc(1824, 114.0, **variant), skull[:3], skull[3:])
    assert pair.contradicted, pair
    assert pair.resultant < 0.2 * pair.predicted  # tuned on: 0.03, 0.16, 0.16 of it
    assert cause in pair.cause


def test_skull_2x3_fine_frames_out_of_order_read_as_a_reversed_sign(skull):
    pair = _pair(_desc(1824, 114.0), [skull[i] for i in (0, 2, 1)], skull[3:])
    assert pair.contradicted and "set 'fine' alone" in pair.cause


def test_skull_2x3_cue_frames_out_of_order_name_the_cue(skull):
    # flipping either set makes the pair agree; the cue's own direction tells which
    pair = _pair(_desc(1824, 114.0), skull[:3], [skull[i] for i in (3, 5, 4)])
    assert pair.contradicted and "set 'cue' alone" in pair.cause


def test_skull_2x3_sets_given_each_others_files_are_named(skull):
    pair = _pair(_desc(1824, 114.0), skull[3:], skull[:3])
    assert pair.contradicted and "are swapped" in pair.cause


def test_skull_2x3_a_frame_listed_in_two_sets_is_named(skull):
    desc = _desc(1824, 114.0)
    found = consistency.repeated_frames(desc, [np.stack([skull[0], skull[1], skull[3]]),
                                               np.stack(skull[3:])])
    assert len(found) == 1 and "listed twice" in found[0]


BOARD = [(k, cols) for k in range(1, 7) for cols in (True, False)]


@pytest.fixture(scope="module")
def board() -> dict:
    return {k: _sample(f"calibration/calseq{k}", range(12), "png") for k in range(1, 7)}


@pytest.fixture(scope="module")
def board_noise(board) -> dict:
    """The camera noise of each board set, estimated once from its frames."""
    out = {}
    for k, cols in BOARD:
        desc, stacks = _board_desc(cols), [np.stack(f) for f in _board_frames(board, k, cols)]
        out[k, cols] = resolve_noise(desc, stacks, desc.sensor.resolved(np.uint8), True).sensor
    return out


def _board_desc(cols: bool, **variant) -> PatternDescription:
    return (_desc(1824, 114.0, **variant) if cols
            else _desc(1140, 71.25, "horizontal", **variant))


def _board_frames(board, k: int, cols: bool):
    frames = board[k][:6] if cols else board[k][6:]
    return frames[:3], frames[3:]


@pytest.mark.parametrize("k,cols", BOARD)
def test_held_out_board_sets_as_captured_agree(board, k, cols):
    # held out: R / R_pred 0.67-0.99 over the 12 sets (the threshold is 0.5)
    pair = _pair(_board_desc(cols), *_board_frames(board, k, cols))
    assert not pair.contradicted, pair
    assert pair.resultant > 0.6 * pair.predicted


@pytest.mark.parametrize("variant,named", [
    ({"fine_shifts": REVERSED}, 10), ({"fine_period": "half"}, 11),
    ({"cue_period": "double"}, 11)],
    ids=["fine_shifts_neg", "fine_period_half", "cue_period_double"])
def test_held_out_board_misdescriptions_are_caught(board, board_noise, variant, named):
    # held out: each is caught on all 12 sets; the cause is named where the correct
    # description reaches EXPLAINED_RATIO of R_pred, which the rows of poses 4 and 5
    # (R / R_pred 0.67) do not: a reversed sign there reads "no single misreading".
    # Since the image noise estimate stopped over-predicting the board's noise (session
    # 41: measured/predicted 0.93-1.06 on its cells, was ~0.85), R_pred is higher and one
    # set of the halved and doubled periods reads "no single misreading" too
    causes = 0
    for k, cols in BOARD:
        fine, width = (114.0, 1824) if cols else (71.25, 1140)
        stated = {"fine_shifts": variant.get("fine_shifts", SLSTUDIO_SHIFTS)}
        if "fine_period" in variant:
            stated["fine_period"] = fine / 2
        if "cue_period" in variant:
            stated["cue_period"] = 2.0 * width
        pair = _pair(_board_desc(cols, **stated), *_board_frames(board, k, cols),
                     board_noise[k, cols])
        assert pair.contradicted, (k, cols, pair)
        causes += bool(pair.cause)
    assert causes >= named


def test_the_command_line_masks_a_contradicted_decode_and_points_at_the_description(
        tmp_path, capsys):
    files = [str(SLSTUDIO / "skull_2x3" / f"frameSeq_{i:02d}.bmp") for i in range(6)]
    (tmp_path / "patterns.toml").write_text(dumps_patterns({
        "format": "scanqa-patterns/2", "projector_width_px": 1824, "set": [
            {"kind": "phase", "name": "fine", "period_px": 114.0, "steps": 3,
             "shifts_rad": list(REVERSED), "files": files[:3]},
            {"kind": "phase", "name": "cue", "period_px": 1824.0, "steps": 3,
             "shifts_rad": SLSTUDIO_SHIFTS, "files": files[3:]}]}))
    out = tmp_path / "phase.npz"
    assert main(["decode", str(tmp_path), "--out", str(out)]) == 0
    printed = capsys.readouterr()
    err = printed.err + printed.out
    assert "scanqa: warning: the images contradict the description" in err
    assert "negate its shifts_rad" in err
    assert "0 of 2282176 pixels valid" in err  # before: 196441 (8.6 %), x_p wrong
    hint = err[err.index("most pixels are masked"):]
    assert "fix patterns.toml" in hint
    assert "thresholds." not in hint and "add light" not in hint
    assert math.isfinite(np.load(out)["period_px"])


def test_held_out_skull_gray_with_a_bit_frame_listed_twice_is_named():
    # before: 14.5 % of the pixels decoded valid, no warning (correct: 14.4 %)
    frames = _sample("skull_gray", range(12), "bmp")
    bits = [frames[i] for i in (2, 3, 4, 5, 6, 6, 8, 9, 10, 11)]
    desc = PatternDescription(1824, (ReferenceSet("wb", ("white", "black")),
                                     GrayCodeSet("gray", 10, cell_px=2.0)))
    found = consistency.repeated_frames(desc, [np.stack(frames[:2]), np.stack(bits)])
    assert len(found) == 1 and "'gray' (frame 5)" in found[0]
    assert consistency.repeated_frames(desc, [np.stack(frames[:2]),
                                              np.stack(frames[2:])]) == []


def test_the_board_cue_that_bends_is_not_called_a_misstated_period(tmp_path):
    # calseq5's column set, as captured (114 / 1824 px, right: the skull's Gray code
    # agrees with it): its cue and x_p drift apart by -15 px across the board, bending by
    # 3.7 px about the line (0.24 of the drift); the decoder had called it "a period_px is
    # misstated", and suggested a period of 113.3 px
    from tests.realdata import slstudio_board_patterns

    cols, _ = slstudio_board_patterns(tmp_path)
    for f in (SLSTUDIO / "calibration" / "calseq5").iterdir():
        (tmp_path / f.name).symlink_to(f)
    (tmp_path / "patterns.toml").write_text(cols.read_text())
    pm = decode(tmp_path)
    drift = [w for w in pm.provenance["decode"]["warnings"] if "drift apart" in w]
    assert len(drift) == 1 and "not along a line" in drift[0], drift
    assert "a period_px is misstated" not in drift[0]
