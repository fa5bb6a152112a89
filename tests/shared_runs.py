"""Runs several test files need, computed once per ``make test`` (tests/diskcache.py):
the key includes every source file of scanqa, so each is what the current code writes.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from tests.diskcache import cached

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_DATA = ROOT / "sample_data"
#: The sample scanner's config and profile (the committed sweep's camera).
SAMPLE_CONFIG = f"{SAMPLE_DATA / 'sample_scanner.toml'}#sample"


def sample_table(folder: Path) -> Path:
    """``scanqa calibrate`` of the committed calibration sweep with the sample profile
    (~12 s of CPU; tests/test_closed_loop.py, test_batch.py, test_simulate_artefacts.py):
    ``folder/table.npz`` and its report files, returns the table's path."""

    def build() -> dict[str, bytes]:
        from scanqa.cli import main

        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "table.npz"
            assert main(["calibrate", str(SAMPLE_DATA / "calibration_sweep" / "sweep.toml"),
                         "--config", SAMPLE_CONFIG, "--out", str(out), "-q"]) == 0
            return {p.name: p.read_bytes() for p in Path(tmp).iterdir() if p.is_file()}

    files = cached("sample_table", build, SAMPLE_DATA, ROOT / "calib")
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return folder / "table.npz"


def _board_key(folders, columns, rows, board, model="k1", held_out=False, reference=None,
               progress=None, corner_method="model") -> tuple:
    """What calibrate_poses's result depends on: the poses' frames, the descriptions
    (without the path they were read from), the options; not the progress messages."""
    from dataclasses import replace

    if reference is not None:
        raise ValueError("the board calibration is cached without a reference only")
    if isinstance(board, (int, float)):  # a square size: decode_pose takes float(board)
        board = float(board)
    poses = [(str(Path(f).resolve()), Path(f)) for f in folders]  # path and frames
    return (poses, repr(replace(columns, source="")), repr(replace(rows, source="")), board,
            model, held_out, corner_method)


def share_board_calibration(monkeypatch) -> None:
    """Make :func:`scanqa.calibration.board_fit.calibrate_poses` (the decode and the
    calibration behind ``scanqa calibrate --board`` and ``scanqa.calibrate_board``) run
    once per make test for the same poses and options, wherever it is called from: the
    command's test (test_board_real.py) and the API's (test_api.py) each check what
    their own code writes from it."""
    import sys

    import scanqa.api  # the modules that hold the name, loaded first
    import scanqa.cli  # noqa: F401
    from scanqa.calibration import board_fit
    from tests.diskcache import memoized

    original = board_fit.calibrate_poses
    shared = memoized("board_calibration", original, _board_key)
    for name, module in list(sys.modules.items()):
        if name.startswith("scanqa") and getattr(module, "calibrate_poses", None) is original:
            monkeypatch.setattr(module, "calibrate_poses", shared)


def _characterisation_key(sweep_dirs, config=None, min_attenuation=0.49, roi_px=256) -> tuple:
    """What characterize_sweeps's result depends on: the sweeps (path and bytes), the
    config (a frozen dataclass: its repr is its value), the options."""
    sweeps = [(str(Path(d).resolve()), Path(d)) for d in sweep_dirs]
    return sweeps, repr(config), float(min_attenuation), int(roi_px)


def share_sweep_characterisation(monkeypatch) -> None:
    """Make :func:`scanqa.characterization.sweep.characterize_sweeps` (the fit behind
    ``scanqa characterize sweep``, ~2.5 s of CPU for the sample camera sweep) run once per
    make test for the same sweeps, config and options: test_failures.py runs the command
    on the sample camera sweep twice (its plots failing, then whole); each run writes and
    checks its own outputs from the result."""
    from scanqa.characterization import sweep
    from tests.diskcache import memoized

    monkeypatch.setattr(sweep, "characterize_sweeps", memoized(
        "sweep_characterisation", sweep.characterize_sweeps, _characterisation_key))


def share_demo_characterisation(monkeypatch) -> None:
    """Make the fit of the demo's first stage
    (:func:`scanqa.characterization.sweep.characterize_sweeps` of the sample sweeps, ~4 s
    of CPU; its plots are drawn by each run) run once per make test: test_demo.py's demo run and
    test_failures.py's demo that fails in its third stage characterise the same sweeps;
    each writes and checks its own outputs from the result."""
    from scanqa.runs import demo
    from tests.diskcache import memoized

    monkeypatch.setattr(demo, "characterize_sweeps", memoized(
        "demo_characterisation", demo.characterize_sweeps, _characterisation_key))



def board_column_residual(k: int, phase_map, calibration, description: dict,
                          calibration_file: Path, split=None):
    """:func:`scanqa.characterization.board.pose_residual` of SLStudio's pose calseq<k>
    (9 x 13 inner corners), computed once per make test: test_realdata_noise.py (all six
    poses, through characterize_board) and test_flattening_real.py (poses 1, 2 and 5
    before flattening) split the same decode of the same frames about its plane.

    ``phase_map`` is the caller's decode of the patterns.toml ``description`` (a
    scanqa-patterns document naming its frames by absolute path), ``calibration`` what
    ``calibration_file`` holds. The key is the description, its frames' bytes, the
    calibration file's bytes and the sources, so the result is what ``pose_residual``
    gives that decode; a caller whose description differs gets its own. ``split`` is
    ``pose_residual`` itself (default), given by a caller that has replaced the module's
    name with a function that comes back here."""
    if split is None:
        from scanqa.characterization.board import pose_residual as split

    frames = [Path(f) for s in description["set"] for f in s["files"]]
    return cached("board_column_residual",
                  lambda: split(f"calseq{k}", phase_map, calibration, (13, 9)),
                  k, description, frames, calibration_file)
