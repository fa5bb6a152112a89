"""Real captures from hardware nobody on this project built (``../shared/realdata`` beside
the repository). They are read in place, never copied; tests that need them skip with a
reason when the folder is absent (as on a user's clone)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest

from scanqa.io.patterns import dumps_patterns

#: The folder of real captures: ``$SCANQA_REALDATA`` or ``<repo>/../shared/realdata``.
REALDATA = Path(os.environ.get(
    "SCANQA_REALDATA", Path(__file__).resolve().parents[1].parent / "shared" / "realdata"))
#: SLStudio's example captures (README in the folder).
SLSTUDIO = REALDATA / "slstudio"

#: Skips a test when the real captures are not beside the repository.
needs_slstudio = pytest.mark.skipif(
    not (SLSTUDIO / "skull_gray").is_dir(),
    reason=f"real captures not found at {SLSTUDIO} (they live beside the repository in "
           "../shared/realdata; set SCANQA_REALDATA to their folder to run these tests)")

#: The phase shifts of SLStudio's 3-step sets [rad].
SLSTUDIO_SHIFTS = [0.0, -2 * math.pi / 3, -4 * math.pi / 3]


def slstudio_board_patterns(folder: Path) -> tuple[Path, Path]:
    """Write the patterns.toml of the board poses' column and row sets into ``folder``
    (README: two 3-step sets each, 114 and 1824 px in columns, 71.25 and 1140 px in rows;
    file names relative to a pose); returns (columns.toml, rows.toml)."""
    paths = []
    for name, width, fine, orientation, first in (
            ("columns.toml", 1824, 114.0, "vertical", 0),
            ("rows.toml", 1140, 71.25, "horizontal", 6)):
        names = [f"frameSeq_{i:02d}.png" for i in range(first, first + 6)]
        path = Path(folder) / name
        path.write_text(dumps_patterns({
            "format": "scanqa-patterns/2", "projector_width_px": width, "set": [
                {"kind": "phase", "name": "fine", "period_px": fine, "steps": 3,
                 "shifts_rad": SLSTUDIO_SHIFTS, "orientation": orientation,
                 "files": names[:3]},
                {"kind": "phase", "name": "cue", "period_px": float(width), "steps": 3,
                 "shifts_rad": SLSTUDIO_SHIFTS, "orientation": orientation,
                 "files": names[3:]}]}))
        paths.append(path)
    return paths[0], paths[1]


#: kamino410/phase-shifting's sample captures (README in the folder): object1 with the
#: reference decoder's result.
KAMINO = REALDATA / "kamino410"

#: Skips a test when kamino410's captures are not beside the repository.
needs_kamino = pytest.mark.skipif(
    not (KAMINO / "object1_ref.npz").is_file(),
    reason=f"kamino410's captures not found at {KAMINO} (they live beside the repository "
           "in ../shared/realdata; set SCANQA_REALDATA to their folder to run these tests)")

#: kamino410's shifts in frame order [rad].
KAMINO_SHIFTS = [-2 * math.pi / 3, 0.0, 2 * math.pi / 3]


def kamino_object1_patterns(folder: Path) -> tuple[Path, Path]:
    """Write hand descriptions of object1's columns and rows into ``folder`` (README:
    3-step sets of 66.667 and 100 px; OpenCV Gray bits of 100 px cells, each followed by
    its inverse, ordering the 100 px set; white pat30, black pat31); returns the two
    folders (columns, rows)."""
    obj = KAMINO / "object1"
    paths = []
    for name, width, fine, coarse, gray, bits, orientation in (
            ("columns", 1920, 0, 3, 12, 5, "vertical"),
            ("rows", 1080, 6, 9, 22, 4, "horizontal")):
        files = [str(obj / f"pat{i:02d}.png") for i in range(32)]
        sub = Path(folder) / name
        sub.mkdir(parents=True, exist_ok=True)
        (sub / "patterns.toml").write_text(dumps_patterns({
            "format": "scanqa-patterns/2", "projector_width_px": width, "set": [
                {"kind": "reference", "name": "white_black", "levels": ["white", "black"],
                 "files": files[30:32]},
                {"kind": "gray", "name": "gray", "bits": bits, "cell_px": 100.0,
                 "inverse": "interleaved", "orders": "p100", "orientation": orientation,
                 "files": files[gray:gray + 2 * bits]},
                {"kind": "phase", "name": "p100", "period_px": 100.0, "steps": 3,
                 "shifts_rad": KAMINO_SHIFTS, "orientation": orientation,
                 "files": files[coarse:coarse + 3]},
                {"kind": "phase", "name": "p66", "period_px": 1920 / 28.8, "steps": 3,
                 "shifts_rad": KAMINO_SHIFTS, "orientation": orientation,
                 "files": files[fine:fine + 3]}]}))
        paths.append(sub)
    return paths[0], paths[1]
