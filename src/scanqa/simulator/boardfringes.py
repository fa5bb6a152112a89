"""Simulated chessboard poses under phase-shift fringes, as a board calibration captures
them: per pose, fringes across the columns and across the rows, written as image folders
that ``scanqa calibrate --board``, ``scanqa characterize board`` and their Python twins
(:func:`scanqa.calibrate_board`, :func:`scanqa.characterize_board`) read.

The scanner and the board come from :func:`scanqa.simulator.boardposes.simulate` (a
camera and a projector with radial lens distortion, a chessboard bowed by a quadric sag),
optionally binned to fewer camera pixels (:func:`binned`). What each pixel sees is
the Gray-code renderer's (:func:`scanqa.simulator.boardposes.board_view`): each camera
pixel's ray meets the bowed board, the board coordinates of that point give the
reflectance (0.15 on black squares, 0.85 on white, a white margin of one square, averaged
over 3 x 3 points of the pixel's area) and its projector pixel the light. Here the light
is what :func:`scanqa.decoding.patternset.ideal_patterns` says the projector shows for
each frame of the given pattern descriptions (any phase, Gray-code or reference set).
The camera image ``8 + 230 albedo light`` [DN] is blurred by a Gaussian of ``blur_px``
(the camera lens; the projector is taken sharp) and gets Gaussian noise of variance
``read_var_dn2 + shot_dn I`` (read noise and shot noise, the law that
:mod:`scanqa.characterization.board` fits), then 8-bit rounding. Everything here is
"simulated".
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scanqa.calibration.board import Board
from scanqa.calibration.pinhole import (
    project_points,
    rotation_matrix,
    rotation_vector,
)
from scanqa.decoding.coding import PatternDescription, PhaseSet
from scanqa.decoding.patternset import ideal_patterns, write_pattern_set
from scanqa.errors import InputError
from scanqa.io.atomic import make_out_dir, write_text
from scanqa.io.opencv import OpenCVCalibration
from scanqa.io.patterns import dumps_patterns
from scanqa.simulator import boardkernels
from scanqa.simulator.boardposes import (  # noqa: F401 (board_view: this module's API too)
    ALBEDO,
    board_view,
    simulate,
    within_margin,
)

#: The board of the simulated captures: 7 x 9 inner corners of 15 mm squares (a 120 x
#: 150 mm grid), about 34 camera px a square at 400 mm with a 2 x 2 binned camera.
BOARD = Board(rows=7, columns=9, square_mm=15.0)
#: The finer fringe periods of each direction [projector px]; the coarsest set before them
#: has the panel's size along the direction (one period over the coded range).
PERIODS_PX = (96.0, 16.0)
#: Phase steps per set [-].
STEPS = 4
#: Camera image level: dark offset and full white on a reflectance of 1 [DN].
DARK_DN, WHITE_DN = 8.0, 230.0


@dataclass(frozen=True)
class BoardCaptures:
    """What :func:`write_board_captures` wrote, with the truth behind it.

    Attributes
    ----------
    poses : list of Path
        One folder per board pose: the frames of both directions and a ``patterns.toml``
        of the columns (what ``decode`` and ``characterize board`` read).
    patterns : (Path, Path)
        ``columns.toml`` and ``rows.toml`` beside the poses: what was projected, the file
        names relative to each pose's folder (``calibrate --board --patterns``).
    part : Path or None
        A scan of a flat plain plate (no squares, placed as a board pose) in its own
        folder with its ``patterns.toml``.
    part_pose : (rvec, tvec) or None
        The plate's pose: its plane is Z = 0 of that frame [rad, mm].
    truth : OpenCVCalibration
        The true camera, projector and their pose [px, -, mm].
    noise : dict
        ``read_var_dn2`` [DN^2] and ``shot_dn`` [DN] of the frames, before 8-bit rounding.
    """

    poses: list
    patterns: tuple
    part: Path | None
    truth: OpenCVCalibration
    noise: dict
    part_pose: tuple | None = None


def binned(truth: OpenCVCalibration, factor: int) -> OpenCVCalibration:
    """The same scanner with its camera binned ``factor`` x ``factor``: the focal length
    and principal point scaled (pixel centres at ``(u + 0.5) / factor - 0.5``), the
    image size divided, the projector unchanged."""
    if factor == 1:
        return truth
    kc = truth.Kc.copy()
    kc[:2, :2] /= factor
    kc[:2, 2] = (kc[:2, 2] + 0.5) / factor - 0.5
    sizes = dict(truth.sizes, frameWidth=int(truth.sizes["frameWidth"]) // factor,
                 frameHeight=int(truth.sizes["frameHeight"]) // factor)
    return replace(truth, Kc=kc, sizes=sizes)


def fringe_descriptions(panel: tuple[int, int], periods_px: tuple = PERIODS_PX,
                        steps: int = STEPS) -> tuple[PatternDescription, PatternDescription]:
    """Phase-shift sets across the columns and across the rows of a panel.

    Parameters
    ----------
    panel : (int, int)
        Panel (width, height) [projector px].
    periods_px : tuple of float
        The finer periods of each direction [projector px]; the coarsest set's period is
        the panel's size along the direction.
    steps : int
        Frames per set [-].

    Returns
    -------
    (PatternDescription, PatternDescription)
        Columns (``orientation = "vertical"``, sets ``c<period>``) and rows
        (``"horizontal"``, sets ``r<period>``), without files.
    """
    out = []
    for key, orientation, size in (("c", "vertical", panel[0]), ("r", "horizontal",
                                                                 panel[1])):
        sets = tuple(PhaseSet(f"{key}{p:g}", float(p), steps, orientation=orientation)
                     for p in (float(size), *periods_px))
        out.append(PatternDescription(int(size), sets, description="scanqa simulated board"))
    return out[0], out[1]


def frames(view: dict, description: PatternDescription, rng: np.random.Generator,
           read_var_dn2: float = 1.0, shot_dn: float = 0.05, blur_px: float = 0.7
           ) -> list[np.ndarray]:
    """8-bit camera frames of every set of a description (module notes).

    Parameters
    ----------
    view : dict
        :func:`board_view` of the pose.
    description : PatternDescription
        What the projector shows; a horizontal set codes the panel's rows.
    rng : numpy.random.Generator
        The noise stream.
    read_var_dn2, shot_dn : float
        Noise variance ``read_var_dn2 + shot_dn I`` of a frame of level I [DN^2, DN].
    blur_px : float
        Std of the camera's Gaussian blur [camera px].

    Returns
    -------
    list of (N, H, W) uint8
        One stack per set, in ``description.sets`` order [DN].
    """
    out = []
    gain, weights = WHITE_DN * view["albedo"], boardkernels.gaussian_weights(blur_px)
    noise = np.empty(gain.shape)
    for k, pset in enumerate(description.sets):
        coordinate = view["yp"] if pset.orientation == "horizontal" else view["xp"]
        light = ideal_patterns(description, k, coordinate) * view["lit"]
        stack = []
        for shown in light:
            # (DARK + WHITE albedo light) blurred (gaussian_blur's kernel), the noise,
            # 8-bit rounding: one pass (boardkernels.fringe_shot)
            rng.standard_normal(noise.shape, out=noise)
            stack.append(boardkernels.fringe_shot(DARK_DN, gain, np.ascontiguousarray(shown),
                                                  weights, noise, read_var_dn2, shot_dn))
        out.append(np.array(stack))
    return out


def draw_poses(truth: OpenCVCalibration, board: Board, n_poses: int,
               rng: np.random.Generator, depth_mm: tuple = (370.0, 430.0),
               tilt_rad: float = 0.35) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses whose whole board, its white margin included, is seen by the camera
    and lit by the projector.

    Parameters
    ----------
    truth : OpenCVCalibration
        The camera and projector.
    board : Board
        The chessboard.
    n_poses : int
        Poses to draw [-].
    rng : numpy.random.Generator
        The random stream.
    depth_mm : (float, float)
        Range of the board centre's depth [mm].
    tilt_rad : float
        Largest tilt about each of the board's axes [rad] (a third of it about its
        normal).

    Returns
    -------
    list of (rvec, tvec)
        Rodrigues vector [rad] and translation [mm] of each pose, board to camera frame.
    """
    s = board.square_mm
    outline = np.array([[-s, -s, 0], [board.columns * s, -s, 0],
                        [board.columns * s, board.rows * s, 0], [-s, board.rows * s, 0]])
    centre = outline.mean(axis=0)
    camera = (int(truth.sizes["frameWidth"]), int(truth.sizes["frameHeight"]))
    panel = (int(truth.sizes["screenResX"]), int(truth.sizes["screenResY"]))
    poses = []
    for _ in range(1000 * n_poses):
        if len(poses) == n_poses:
            break
        rvec = np.array([rng.uniform(-tilt_rad, tilt_rad), rng.uniform(-tilt_rad, tilt_rad),
                         rng.uniform(-tilt_rad, tilt_rad) / 3])
        rmat = rotation_matrix(rvec)
        tvec = np.array([rng.normal(10, 10), rng.normal(0, 10), rng.uniform(*depth_mm)]
                        ) - rmat @ centre
        cam = project_points(outline, rvec, tvec, truth.Kc, truth.kc)
        proj = project_points(outline, rotation_vector(truth.Rp @ rmat),
                              truth.Rp @ tvec + truth.Tp, truth.Kp, truth.kp)
        if within_margin(cam, camera, 4) and within_margin(proj, panel, 4):
            poses.append((rvec, tvec))
    if len(poses) < n_poses:
        raise InputError(f"only {len(poses)} of {n_poses} board poses of a {board.rows} x "
                         f"{board.columns} board fit the camera and the projector: give a "
                         "smaller board or a larger depth_mm")
    return poses


def write_board_captures(folder: str | os.PathLike, seed: int, n_poses: int = 3,
                         bin_factor: int = 2, board: Board = BOARD,
                         part: str | os.PathLike | None = "part", read_var_dn2: float = 1.0,
                         shot_dn: float = 0.05) -> BoardCaptures:
    """Write simulated board captures as a lab would keep them.

    ``folder/pose1`` .. ``pose<n>`` (each with both directions' frames and the columns'
    ``patterns.toml``), ``folder/columns.toml`` and ``folder/rows.toml``,
    and a scan of a plain plate in the same volume (in ``part``).

    Parameters
    ----------
    folder : path
        Created if missing.
    seed : int
        The scanner, the board's bow, the poses and the noise.
    n_poses : int
        Board poses [-].
    bin_factor : int
        Camera binning (2: 640 x 512 px) [-].
    board : Board
        The chessboard.
    part : path or None
        The plate's folder (relative to ``folder``, or absolute); None writes no plate.
    read_var_dn2, shot_dn : float
        Noise law of the frames [DN^2, DN] (:func:`frames`).

    Returns
    -------
    BoardCaptures
    """
    root = make_out_dir(folder)
    sim = simulate(seed, n_poses=1, board=board)
    truth = binned(sim.truth, bin_factor)
    rng = np.random.default_rng([seed, 1])
    panel = (int(truth.sizes["screenResX"]), int(truth.sizes["screenResY"]))
    columns, rows = fringe_descriptions(panel)
    placed = draw_poses(truth, board, n_poses + (part is not None), rng)
    noise = {"read_var_dn2": read_var_dn2, "shot_dn": shot_dn}
    poses, written = [], {}
    for k, (rvec, tvec) in enumerate(placed):
        plate = k == n_poses
        view = board_view(truth, board, rvec, tvec, None if plate else sim.bow,
                          squares=not plate)
        where = root / part if plate else root / f"pose{k + 1}"
        # rows first: the columns' patterns.toml is the one left in the folder
        for desc in (rows, columns) if not plate else (columns,):
            written[desc.sets[0].orientation] = write_pattern_set(
                where, desc, frames(view, desc, rng, read_var_dn2, shot_dn))
        if not plate:
            poses.append(where)
    patterns = (root / "columns.toml", root / "rows.toml")
    for path, key in zip(patterns, ("vertical", "horizontal"), strict=True):
        write_text(path, dumps_patterns(replace(written[key], source="").to_dict()))
    return BoardCaptures(poses, patterns, None if part is None else root / part, truth,
                         noise, None if part is None else placed[-1])

