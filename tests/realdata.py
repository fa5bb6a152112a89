"""Real captures from hardware nobody on this project built (``../shared/realdata`` beside
the repository). They are read in place, never copied; tests that need them skip with a
reason when the folder is absent (as on a user's clone)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

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
