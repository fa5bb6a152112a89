"""The real-scanner path from Python, with the command line's arguments: describe the
frames, calibrate from board poses, characterise the noise on the board, annotate with
that characterisation, compare with a reference.

Each function does what its command does (``scanqa describe``, ``scanqa calibrate
--board``, ``scanqa characterize board``, ``scanqa compare``), takes the same arguments
under the same names (``--square-mm`` is ``square_mm``), accepts file names or the objects
scanqa already loaded, and returns the result; with ``out`` it also writes the command's
files. Nothing is printed: progress goes to the ``scanqa`` logger (a bar in a terminal,
:mod:`scanqa.progress`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from scanqa.errors import InputError
from scanqa.progress import Progress, step_messages

PathLike = str | os.PathLike


def describe(folder: PathLike, frames: list[str] | None = None,
             projector_width: int | None = None, projector_height: int | None = None,
             channel: str = "", out: PathLike | None = None, force: bool = False
             ) -> list[Path]:
    """Infer the patterns.toml of a folder of frames (``scanqa describe``).

    Parameters
    ----------
    folder : path
        The camera frames of one capture.
    frames : list of str, optional
        The frames, in order (default every image of the folder in name order).
    projector_width, projector_height : int, optional
        The projector's panel [px], where the frames cannot tell.
    channel : str
        Colour channel to read ("" for grey or the mean of colour frames).
    out : path, optional
        The file to write (default ``FOLDER/patterns.toml``); a second coded direction
        goes to ``<stem>_rows.toml`` beside it.
    force : bool
        Overwrite existing files.

    Returns
    -------
    list of Path
        The files written, columns first: each one loads with :func:`scanqa.load_patterns`.
    """
    from scanqa.description.inference import describe_frames
    from scanqa.description.text import description_text, frame_files, read_frames
    from scanqa.io.atomic import write_text

    paths = frame_files(folder, list(frames or ()))
    target = Path(out) if out is not None else Path(folder) / "patterns.toml"
    images = read_frames(paths, channel)
    listed = [os.path.relpath(p.resolve(), target.parent.resolve())
              if p.resolve().is_relative_to(target.parent.resolve()) else str(p.resolve())
              for p in paths]
    found = describe_frames(images, listed, projector_width, projector_height)
    targets = ([target] if len(found) == 1 else
               [target if d.desc.orientation == "vertical"
                else target.with_name(f"{target.stem}_rows{target.suffix}") for d in found])
    for t in targets:
        if t.exists() and not force:
            raise InputError(f"{t} exists (give force=True to overwrite it, or out=)")
    for t, d in zip(targets, found, strict=True):
        text = description_text(d, str(folder), len(paths))
        if channel:
            text = text.replace('channel = ""', f'channel = "{channel}"')
        write_text(t, text)
    return targets


def calibrate_board(poses: list[PathLike], patterns: tuple[PathLike, PathLike],
                    square_mm: float, board: tuple[int, int] | None = None,
                    lens_model: str = "k1", corners: str = "model", hold_out: bool = False,
                    reference: PathLike | None = None, out: PathLike | None = None):
    """A camera-projector calibration from chessboard poses (``scanqa calibrate --board``).

    Parameters
    ----------
    poses : list of path
        One folder of frames per board pose (>= 2).
    patterns : (path, path)
        The columns' and the rows' patterns.toml (:func:`describe`).
    square_mm : float
        Side of a board square [mm].
    board : (int, int), optional
        Inner corners (rows, columns); default: found in the frames.
    lens_model, corners, hold_out : str, str, bool
        As ``--lens-model``, ``--corners``, ``--hold-out``.
    reference : path, optional
        A calibration to compare with (``--reference``).
    out : path, optional
        The OpenCV file to write (.xml, .yml, .yaml, .json), with ``<stem>_report.json``,
        ``<stem>_report.html`` and ``<stem>_covariance.json`` (the calibration's parameter
        covariance as a covariance file, :mod:`scanqa.io.covariance`) beside it.

    Returns
    -------
    scanqa.calibration.board_fit.BoardCalibration
        ``.data`` is the calibration (:func:`scanqa.load_calibration` reads the file).
    """
    from scanqa.calibration.board import Board
    from scanqa.calibration.board_fit import calibrate_poses
    from scanqa.decoding.parsing import load_patterns
    from scanqa.io.atomic import check_out_dir, staged_dir, write_text
    from scanqa.io.covariance import write_covariance
    from scanqa.io.opencv import (
        is_opencv_file,
        read_opencv_calibration,
        require_opencv,
        write_opencv_calibration,
    )
    from scanqa.report import board as report_board

    require_opencv("a board calibration (its corner detector and solvers)")
    target = None
    if out is not None:
        target = check_out_dir(out)
        if not is_opencv_file(target):
            raise InputError(f"out={target}: a board calibration is an OpenCV file (.xml, "
                             ".yml, .yaml or .json)")
    grid = square_mm if board is None else Board(board[0], board[1], square_mm)
    ref = read_opencv_calibration(reference) if reference else None
    columns, rows = (load_patterns(p) for p in patterns)
    with Progress("calibrate", total=len(poses), unit="pose") as bar:
        result = calibrate_poses(list(poses), columns, rows, grid, lens_model, hold_out,
                                 ref, progress=step_messages(bar), corner_method=corners)
    if target is not None:
        stem = target.with_suffix("").name
        with staged_dir(target.parent) as stage:
            write_opencv_calibration(stage / target.name, result.data)
            if result.data.covariance is not None:
                write_covariance(stage / f"{stem}_covariance.json", result.data.covariance)
            write_text(stage / f"{stem}_report.json",
                       json.dumps(report_board.summary(result), indent=1))
            write_text(stage / f"{stem}_report.html", report_board.render(result))
    return result


def characterize_board(poses: list[PathLike], calibration: PathLike, config: PathLike,
                       board: tuple[int, int] = (9, 13), profile: str | None = None,
                       depth_range_mm: tuple[float, float] | None = None,
                       out: PathLike | None = None,
                       calibration_covariance: PathLike | None = None,
                       calibration_sigma_um: float | None = None) -> dict:
    """The scanner's noise law from board poses (``scanqa characterize board``).

    Parameters
    ----------
    poses : list of path
        Pose folders (each with its patterns.toml) or decoded phase maps (.npz).
    calibration : path
        The calibration (an OpenCV file or a table).
    config : path
        The scanner config (``--config``), with ``profile``.
    board : (int, int)
        Inner corners (rows, columns), as ``--board 9x13`` (the order of
        :func:`calibrate_board`).
    depth_range_mm : (float, float), optional
        As ``--depth-range-mm``.
    out : path, optional
        Folder for summary.json and cells.csv; the summary is what
        :func:`apply_characterization` and ``annotate --model`` take.
    calibration_covariance, calibration_sigma_um : path or float, optional
        An OpenCV calibration's term given beside it: a covariance file or a stated std
        [um] (:func:`scanqa.load_calibration`'s ``covariance`` and ``sigma_um``).

    Returns
    -------
    dict
        The summary: ``noise_law``, ``held_out`` rows, ...
    """
    import csv
    import io

    from scanqa.calibration.base import load_calibration
    from scanqa.characterization.board import characterize_board as fit_board
    from scanqa.characterization.checks import check_scale, pose_keys
    from scanqa.decoding.decoder import decode
    from scanqa.io.atomic import staged_dir, write_text
    from scanqa.io.opencv import require_opencv
    from scanqa.model.config import load_config

    require_opencv("a board characterization (its corner detector)")
    cfg = load_config(config, profile=profile)
    decoded = {name: decode(p) for name, p in pose_keys([str(p) for p in poses]).items()}
    first = next(iter(decoded.values()))
    cal = load_calibration(calibration, cfg, first.orientation,
                           tuple(depth_range_mm or (0.0, float("inf"))),
                           calibration_covariance, calibration_sigma_um)
    check_scale(cal, cfg, str(calibration))
    rows, columns = board
    with Progress("characterize board", total=len(decoded), unit="pose") as bar:
        result = fit_board(decoded, cal, (columns, rows), progress=step_messages(bar))
    if out is not None:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(result["held_out"][0]))
        writer.writeheader()
        writer.writerows(result["held_out"])
        with staged_dir(out) as stage:
            write_text(stage / "summary.json", json.dumps(result, indent=1))
            write_text(stage / "cells.csv", text.getvalue())
    return result


def apply_characterization(config, summary: PathLike):
    """The config with the model a characterisation fitted (``--model SUMMARY.json``):
    what :func:`scanqa.annotate` then predicts is the characterised sigma.

    Parameters
    ----------
    config : ScannerConfig or path
        The scanner config.
    summary : path
        summary.json of ``characterize`` or ``characterize board``.
    """
    from scanqa.characterization.sweep import apply_fitted_model
    from scanqa.model.config import ScannerConfig, load_config

    cfg = config if isinstance(config, ScannerConfig) else load_config(config)
    return apply_fitted_model(cfg, summary)


def compare(cloud, reference, out: PathLike | None = None, k: float = 2.0,
            tolerance_um: float | None = None, reference_sigma_um: float = 0.0,
            neighbours: int = 16, max_distance_mm: float = 1.0, align: bool = False,
            align_region: str | None = None, align_max_distance_mm: float = 5.0):
    """Deviations of a scan from a reference against the scan's own uncertainty
    (``scanqa compare``).

    Parameters
    ----------
    cloud : AnnotatedCloud or path
        The annotated scan.
    reference : AnnotatedCloud, trimesh.Trimesh or path
        A cloud, or a mesh (.stl, .obj, .off, .glb, or a .ply with faces).
    out : path, optional
        Folder for report.html, summary.json and cloud_compare.ply.
    k, tolerance_um, reference_sigma_um, neighbours, max_distance_mm
        As the command's options (tolerance and sigma in um).
    align, align_region, align_max_distance_mm
        Best-fit the reference first (:mod:`scanqa.qa.align`); a region
        ``"[NAME=]X0,X1,Y0,Y1"`` [mm] implies ``align``.

    Returns
    -------
    scanqa.qa.compare.Comparison
        ``.summary()`` is summary.json; ``.cloud`` has the per-point deviations.
    """
    from scanqa.io.annotated_cloud import AnnotatedCloud, read_cloud
    from scanqa.io.mesh import is_mesh_file, read_mesh
    from scanqa.qa.compare import compare_to_cloud, compare_to_mesh

    scan = cloud if isinstance(cloud, AnnotatedCloud) else read_cloud(cloud)
    name = "reference"
    if isinstance(reference, (str, os.PathLike)):
        name = str(reference)
        reference = read_mesh(reference) if is_mesh_file(reference) else read_cloud(reference)
    ref_sigma = 1e-3 * reference_sigma_um
    fit = None
    if align or align_region is not None:
        from scanqa.qa.align import align_reference, parse_region

        region = parse_region(align_region) if align_region is not None else None
        reference, fit = align_reference(scan, reference, region, align_max_distance_mm,
                                         neighbours, ref_sigma)
    tol = None if tolerance_um is None else 1e-3 * tolerance_um
    if hasattr(reference, "faces"):
        result = compare_to_mesh(scan, reference, k, ref_sigma, max_distance_mm, tol,
                                 name=name, alignment=fit)
    else:
        result = compare_to_cloud(scan, reference, k, neighbours, ref_sigma,
                                  max_distance_mm, tolerance_mm=tol, name=name,
                                  alignment=fit)
    if out is not None:
        from scanqa.report.compare import write_outputs

        write_outputs(result, out)
    return result
