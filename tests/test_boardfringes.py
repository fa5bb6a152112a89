"""The phase-shift board renderer (scanqa.simulator.boardfringes) against its own truth,
computed here without it: where the board's corners are and what projector pixel lights
them (OpenCV's pinhole model, calibration.pinhole), and the phase noise its frames carry
(the N-step phase noise of a read + shot noise law, written out here). The board path that
reads its captures end to end is tests/test_readme.py's board example (slow)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from scanqa.calibration.pinhole import project_points, rotation_matrix, rotation_vector
from scanqa.decoding.decoder import decode_images
from scanqa.numeric import robust_std
from scanqa.simulator.boardfringes import (
    BOARD,
    DARK_DN,
    WHITE_DN,
    binned,
    board_view,
    draw_poses,
    frames,
    fringe_descriptions,
)
from scanqa.simulator.boardposes import bowed_points, simulate

#: Named before the first run (seed 7 was looked at while the renderer was written).
SEED = 4802


@pytest.fixture(scope="module")
def pose():
    """One scanner binned 4 x 4 (320 x 256 px), one bowed board pose and its view."""
    sim = simulate(SEED, n_poses=1, board=BOARD)
    truth = binned(sim.truth, 4)
    rvec, tvec = draw_poses(truth, BOARD, 1, np.random.default_rng(SEED))[0]
    return truth, sim.bow, rvec, tvec, board_view(truth, BOARD, rvec, tvec, sim.bow)


def test_binning_keeps_the_rays(pose):
    """A binned pixel's centre sees what the full camera sees at the centre of the 4 x 4
    pixels it sums: (u + 0.5) * 4 - 0.5."""
    truth = pose[0]
    full = simulate(SEED, n_poses=1, board=BOARD).truth
    assert truth.sizes["frameWidth"] == full.sizes["frameWidth"] // 4
    xyz = np.array([[10.0, -20.0, 400.0], [-50.0, 30.0, 380.0]])
    binned_px = project_points(xyz, np.zeros(3), np.zeros(3), truth.Kc, np.zeros(5))
    full_px = project_points(xyz, np.zeros(3), np.zeros(3), full.Kc, np.zeros(5))
    np.testing.assert_allclose((binned_px + 0.5) * 4 - 0.5, full_px, atol=1e-9)


def test_the_corners_are_lit_by_their_true_projector_pixels(pose):
    """At each corner's camera pixel (the bowed corner projected through the camera), the
    view's projector coordinates are those of the corner projected through the
    projector: within 0.01 projector px (the map interpolated between pixel centres)."""
    truth, bow, rvec, tvec, view = pose
    obj = bowed_points(BOARD, bow)
    cam = project_points(obj, rvec, tvec, truth.Kc, truth.kc)
    rmat = rotation_matrix(rvec)
    proj = project_points(obj, rotation_vector(truth.Rp @ rmat), truth.Rp @ tvec + truth.Tp,
                          truth.Kp, truth.kp)
    at = [cam[:, 1], cam[:, 0]]
    got = np.column_stack([map_coordinates(view[k], at, order=1) for k in ("xp", "yp")])
    assert view["lit"].mean() > 0.3
    assert np.abs(got - proj).max() < 0.01, np.abs(got - proj).max()
    # the squares meet at the corners: a third of a square to either side along the
    # row, a third of a square down, one is black and the other white
    along = (cam[1] - cam[0]) / 3
    down = (cam[BOARD.columns] - cam[0]) / 3
    sides = [map_coordinates(view["albedo"], [cam[:, 1] + s * along[1] + down[1],
                                              cam[:, 0] + s * along[0] + down[0]], order=1)
             for s in (-1, 1)]
    assert np.all(np.abs(sides[0] - sides[1]) > 0.69)  # 0.85 - 0.15, within a pixel's mix

def test_decoded_columns_match_the_truth_with_the_phase_noise_of_the_law(pose):
    """The columns' frames decoded by scanqa's decoder: on white squares, away from
    edges, the decoded x_p equals the view's (median bias < 0.02 px) and scatters as the
    N-step phase noise of the simulated law, sigma_xp = P / (2 pi) sqrt(2 / N)
    sqrt(a + b A + 1/12) / B with A = 8 + 115 albedo, B = 115 albedo [DN] (ratio
    measured / predicted in [0.85, 1.15])."""
    truth, _, _, _, view = pose
    panel = (truth.sizes["screenResX"], truth.sizes["screenResY"])
    columns = fringe_descriptions(panel)[0]
    read, shot = 1.0, 0.05
    stacks = frames(view, columns, np.random.default_rng(SEED), read, shot, blur_px=0.0)
    decoded = decode_images(columns, stacks).xp
    white = view["lit"] & (view["albedo"] > 0.84)  # whole pixels on white squares
    ok = white & np.isfinite(decoded)
    assert ok.sum() > 0.9 * white.sum() > 5000
    err = decoded[ok] - view["xp"][ok]
    assert abs(float(np.median(err))) < 0.02
    fine = columns.phase_sets[-1]
    b = 0.5 * WHITE_DN * view["albedo"][ok]
    a = DARK_DN + b
    predicted = (fine.period_px / (2 * math.pi) * math.sqrt(2 / fine.steps)
                 * np.sqrt(read + shot * a + 1 / 12) / b)
    ratio = robust_std(err) / float(np.median(predicted))
    assert 0.85 < ratio < 1.15, ratio


def test_rows_code_the_panel_rows(pose):
    """The rows' description is horizontal over the panel's height, and its frames follow
    y_p: the coarsest set's phase (one period over the panel) runs down the image as
    y_p does."""
    truth, _, _, _, view = pose
    panel = (truth.sizes["screenResX"], truth.sizes["screenResY"])
    rows = fringe_descriptions(panel)[1]
    assert rows.projector_width_px == panel[1]
    assert {s.orientation for s in rows.sets} == {"horizontal"}
    coarse = rows.sets[0]
    assert coarse.period_px == panel[1]
    stack = frames(view, rows, np.random.default_rng(1), 0.0, 0.0, blur_px=0.0)[0]
    phase = np.arctan2(-(stack[1].astype(float) - stack[3]), stack[0].astype(float) - stack[2])
    ok = view["lit"] & (view["albedo"] > 0.84)
    want = np.angle(np.exp(2j * np.pi * view["yp"][ok] / coarse.period_px))
    assert np.median(np.abs(np.angle(np.exp(1j * (phase[ok] - want))))) < 0.02


def test_a_board_that_cannot_fit_is_one_clear_error(pose):
    from scanqa.calibration.board import Board
    from scanqa.errors import InputError

    with pytest.raises(InputError, match=r"0 of 1 board poses of a 20 x 30 board fit the "
                                         r"camera and the projector: give a smaller board"):
        draw_poses(pose[0], Board(20, 30, 15.0), 1, np.random.default_rng(0))
