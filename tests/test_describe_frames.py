"""The frame analysis behind ``scanqa describe`` (:mod:`scanqa.description.frames`) on
small synthetic frames with hand-computed answers, and the command's refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from scanqa.cli import main
from scanqa.description import frames as fr
from scanqa.description.inference import describe_frames
from scanqa.errors import InputError

SHAPE = (32, 128)
U = np.broadcast_to(np.arange(SHAPE[1], dtype=float), SHAPE)


def _phase(period: float, steps: int, sign: float = 1.0) -> np.ndarray:
    """Frames 100 + 80 cos(2 pi u / P + sign 2 pi k / N) [DN]."""
    return np.stack([100 + 80 * np.cos(2 * np.pi * U / period + sign * 2 * np.pi * k / steps)
                     for k in range(steps)])


def test_normalise_divides_out_the_albedo_and_refuses_constant_frames():
    frames = _phase(16.0, 4) * (0.5 + np.arange(SHAPE[0])[:, None] / SHAPE[0])
    norm = fr.normalise(frames)
    assert norm.lit.all()
    # 4 steps sample cos at 0, 90, 180, 270 degrees: min and max are 100 -/+ 80 |cos| or
    # |sin|, whichever is larger; the normalised frames span [0, 1] at every pixel
    np.testing.assert_allclose(norm.n.min(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(norm.n.max(axis=0), 1.0, atol=1e-6)
    with pytest.raises(InputError, match="the frames do not change"):
        fr.normalise(np.full((3, 4, 4), 7.0))


def test_references_at_the_ends_or_side_by_side_but_not_a_lone_uniform_frame():
    white, black = np.full((1, *SHAPE), 200.0), np.full((1, *SHAPE), 5.0)
    gray = (np.stack([U, 127 - U]) > 63.5) * 195.0 + 5.0  # a bit and its inverse
    first = np.concatenate([white, black, gray, _phase(16.0, 3)])
    assert fr.reference_frames(fr.normalise(first)) == (0, 1)
    middle = np.concatenate([gray, white, black, _phase(16.0, 3)])
    assert fr.reference_frames(fr.normalise(middle)) == (2, 3)
    lone = np.concatenate([gray[:1], white, gray[1:], _phase(16.0, 3)])
    assert fr.reference_frames(fr.normalise(lone)) == ()  # needs a black frame too


def test_a_phase_set_sums_to_a_uniform_image_and_correlates_as_cosines():
    frames = np.concatenate([_phase(16.0, 4), _phase(40.0, 3)])
    norm = fr.normalise(frames)
    assert fr.is_phase_run(norm, [0, 1, 2, 3]) and fr.is_phase_run(norm, [4, 5, 6])
    assert not fr.is_phase_run(norm, [0, 1, 2])  # 3 of 4 steps: the mean keeps fringes
    assert not fr.is_phase_run(norm, [3, 4, 5])  # frames of two sets
    corr = fr.correlations(norm, [0, 1, 2, 3])
    # cos(pi/2 (j - k)): 0 for neighbours, -1 for frames half a cycle apart; dividing by
    # each pixel's darkest and brightest sample (of both sets) bends them by < 0.03
    np.testing.assert_allclose(corr[0], [1.0, 0.0, -1.0, 0.0], atol=0.03)


def test_split_runs_finds_the_sets_in_order():
    gray = (np.stack([U, 127 - U, (U % 64) < 32]) > 0.5) * 150.0 + 10.0
    frames = np.concatenate([_phase(128.0, 3), _phase(16.0, 4), gray[:2] * 0 + gray[:2]])
    runs = fr.split_runs(frames, fr.normalise(frames), ())
    assert [(r.kind, r.frames) for r in runs] == [("phase", (0, 1, 2)),
                                                  ("phase", (3, 4, 5, 6)),
                                                  ("gray", (7, 8))]
    assert {r.orientation for r in runs} == {"vertical"}


def test_phase_slope_sign_follows_the_shifts():
    # frames cos(2 pi u / P + 2 pi k / N): the phasor's angle is +2 pi u / P, its slope
    # +2 pi / 16 = 0.3927 rad/px; with negative shifts the angle is the opposite
    up = fr.phase_frequency(fr.phasor(_phase(16.0, 3)), axis=1)
    down = fr.phase_frequency(fr.phasor(_phase(16.0, 3, sign=-1.0)), axis=1)
    assert up == pytest.approx(2 * math.pi / 16, rel=1e-6) and down == pytest.approx(-up)
    assert fr.phase_orientation(fr.phasor(_phase(16.0, 3)))[0] == "vertical"


def test_frequency_ratio_of_two_periods():
    fine, coarse = fr.phasor(_phase(12.0, 4)), fr.phasor(_phase(100.0, 3))
    ratio, spread = fr.frequency_ratio(fine, coarse, 1, np.ones(SHAPE, bool), 3)
    assert ratio == pytest.approx(12.0 / 100.0, rel=1e-6)  # exact frames: exact ratio
    assert spread < 1e-3


def test_describe_refuses_too_few_frames_and_a_missing_width():
    with pytest.raises(InputError, match="at least 2 frames"):
        describe_frames(np.zeros((1, 4, 4)), ["a.png"])
    frames = np.concatenate([_phase(128.0, 3), _phase(16.0, 3)])
    with pytest.raises(InputError, match="give width_px"):
        describe_frames(frames, [f"f{k}.png" for k in range(6)])


def test_cli_refuses_an_empty_folder_and_keeps_an_existing_file(tmp_path, capsys):
    assert main(["describe", str(tmp_path), "--projector-width", "128"]) == 2
    assert "holds 0 image file(s)" in capsys.readouterr().err
    frames = np.concatenate([_phase(128.0, 3), _phase(16.0, 3)])
    for k, frame in enumerate(frames):
        Image.fromarray(np.rint(frame).astype(np.uint8)).save(tmp_path / f"f_{k}.png")
    (tmp_path / "patterns.toml").write_text("# mine\n")
    assert main(["describe", str(tmp_path), "--projector-width", "128"]) == 2
    assert "exists (give --force" in capsys.readouterr().err
    assert main(["describe", str(tmp_path), "--projector-width", "128", "--force"]) == 0
    text = (tmp_path / "patterns.toml").read_text()
    assert 'files = ["f_0.png", "f_1.png", "f_2.png"]' in text  # beside the toml
    assert "period_px = 128.0" in text and "period_px = 16.0" in text


def test_a_blank_frame_is_named_in_one_line_not_a_traceback(tmp_path, capsys):
    """A zeroed frame inside a sequence (a dropped capture; once a math domain error in
    the frame analysis) is refused with its name."""
    frames = np.concatenate([_phase(128.0, 3), _phase(16.0, 3)])
    frames[2] = 0.0
    for k, frame in enumerate(frames):
        Image.fromarray(np.clip(frame, 0, 255).astype(np.uint8)).save(tmp_path / f"f{k}.bmp")
    assert main(["describe", str(tmp_path), "--projector-width", "128"]) == 2
    err = capsys.readouterr().err
    assert "f2.bmp is blank" in err and "Traceback" not in err


def test_a_black_frame_alone_at_the_end_is_left_out_with_a_note():
    """A DLP capture's lone black frame is no reference set (that needs white too)."""
    black = np.full((1, *SHAPE), 3.0)
    frames = np.concatenate([_phase(128.0, 3), _phase(16.0, 3), black])
    (d,) = describe_frames(frames, [f"f{k}.png" for k in range(7)], 128)
    assert d.desc.reference_set is None
    assert any("f6.png (black) left out" in n for n in d.notes)
    assert sorted(s.period_px for s in d.desc.phase_sets) == [16.0, 128.0]


def test_a_black_frame_between_two_phase_sets_is_left_out_not_read_as_a_gray_bit():
    black = np.full((1, *SHAPE), 3.0) + (U[None] % 7)  # a little ambient texture
    frames = np.concatenate([_phase(128.0, 3), black, _phase(16.0, 3)])
    (d,) = describe_frames(frames, [f"f{k}.png" for k in range(7)], 128)
    assert d.desc.gray_set is None and d.desc.reference_set is None
    assert any("f3.png (black) left out" in n for n in d.notes)
    assert sorted(s.period_px for s in d.desc.phase_sets) == [16.0, 128.0]


def test_cell_widths_periods_in_cells_and_phase_starts_hand_computed():
    from scanqa.description import gray as dg

    # object1: 5 column bits over 1920 px (cells 60..120), 4 row bits over 1080 px with
    # cell 10 seen (67.5..108): one setting for both - no whole cell divides both
    # widths, so the roundest, 100 px
    assert dg.rank_cells([(1920, dg.cell_range(1920, 5, 16)),
                          (1080, dg.cell_range(1080, 4, 10))])[0] == 100
    assert dg.rank_cells([(912, dg.cell_range(912, 3, 7))])[0] == 114  # 912 / 8
    assert dg.cell_range(640, 7, 79, edge=True) == pytest.approx((8.0, 8.101), abs=1e-2)
    assert dg.simple_ratio(0.6669) == pytest.approx(2 / 3)
    assert dg.simple_ratio(1.0312) == 1.0312  # 3 % off: kept as measured
    # a 3-step set of period 2 cells (cell 8 px) starting 0.9 rad late, read at the
    # cell edges of a noiseless column ramp
    u = np.arange(256, dtype=float)[None].repeat(16, 0)
    cells = np.floor((u + 0.5) / 8)
    z = sum(np.cos(2 * np.pi * u / 16 + 0.9 + 2 * np.pi * k / 3)
            * np.exp(-2j * np.pi * k / 3) for k in range(3))
    assert dg.refine_ratio(z, cells, 1, 1.9) == pytest.approx(2.0, rel=2e-3)
    (start,) = dg.edge_offsets([z], [1.0], cells, 8.0, (16.0,), 1)
    assert start == pytest.approx(0.9, abs=0.01)


def test_refine_ratio_picks_what_the_edge_by_edge_search_picks():
    # refine_ratio sums per cell edge first and edge by edge only near the best; the
    # search over every r edge by edge (its definition: r on 601 points within 15 % of
    # the guess, then 41 within 0.05 % of the best, + before -, the first best kept)
    # must pick the same r, on noisy ramps whose fringes and cells line up only roughly
    from scanqa.description import gray as dg

    rng = np.random.default_rng(7)
    for cell, period, guess in ((8.0, 16.3, 1.9), (6.0, 4.1, 0.7), (10.0, 31.0, 3.2)):
        u = np.arange(300)[None] * 1.03 + rng.normal(0, 0.3, (40, 1))
        cells = np.floor(u / cell)
        cells[rng.random(cells.shape) < 0.02] = np.nan
        z = np.exp(1j * (2 * np.pi * u / period + 0.4 + rng.normal(0, 0.3, u.shape)))
        a, b = cells[:, :-1], cells[:, 1:]
        ok = np.isfinite(a) & np.isfinite(b) & (np.abs(b - a) == 1)
        m = np.maximum(a, b)[ok].astype(np.int64)
        za, zb = z[:, :-1][ok], z[:, 1:][ok]
        phi = np.angle(za / np.maximum(np.abs(za), 1e-9) + zb / np.maximum(np.abs(zb), 1e-9))
        counts = np.bincount(m)
        weight = np.where(counts[m] >= 10, 1.0 / counts[m], 0.0)
        best, score = guess, -1.0
        for grid in (guess * np.linspace(0.85, 1.15, 601), None):
            if grid is None:
                grid = np.linspace(best * 0.9995, best * 1.0005, 41)
            for r in grid:
                for sign in (1.0, -1.0):
                    v = abs(np.sum(weight * np.exp(1j * (sign * phi - 2 * np.pi * m / r))))
                    if v > score:
                        best, score = float(r), v
        assert dg.refine_ratio(z, cells, 1, guess) == best
