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
