"""``scanqa describe`` on kamino410's object1 (another scanner than SLStudio's: rows and
columns in one folder, two non-nested 3-step periods each, an OpenCV Gray code with
inverses after each bit whose cells equal the coarser period, white and black last),
described blind - the projector size only - must equal the description its README gives
(written by hand here from that README). object1 was tuning data for describe.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.decoding.coding import GrayCodeSet, PhaseSet, ReferenceSet
from scanqa.decoding.parsing import load_patterns

KAMINO = Path(os.environ.get(
    "SCANQA_REALDATA", Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
)) / "kamino410" / "object1"

#: README: shifts -2 pi / 3, 0, +2 pi / 3 in frame order [rad], stated in [0, 2 pi).
SHIFTS = [4 * math.pi / 3, 0.0, 2 * math.pi / 3]


def _names(first: int, count: int) -> list[str]:
    return [f"pat{k:02d}.png" for k in range(first, first + count)]


@pytest.mark.slow
@pytest.mark.skipif(not KAMINO.is_dir(), reason=f"kamino410's object1 not found at {KAMINO} "
                    "(set SCANQA_REALDATA to the folder of real captures)")
def test_object1_described_blind_as_its_readme_states(tmp_path, capsys):
    out = tmp_path / "object1.toml"
    assert main(["describe", str(KAMINO), "--projector-width", "1920",
                 "--projector-height", "1080", "--out", str(out)]) == 0
    for path, orientation, bits, first_phase, first_gray in (
            (out, "vertical", 5, 0, 12), (out.with_name("object1_rows.toml"), "horizontal",
                                          4, 6, 22)):
        desc = load_patterns(path)
        ref, gray, fine, coarse = desc.sets
        assert isinstance(ref, ReferenceSet) and ref.levels == ("white", "black")
        assert [Path(f).name for f in ref.files] == ["pat30.png", "pat31.png"]
        assert isinstance(gray, GrayCodeSet) and gray.orientation == orientation
        assert (gray.bits, gray.inverse, gray.cell_px) == (bits, "interleaved", 100.0)
        assert [Path(f).name for f in gray.files] == _names(first_gray, 2 * bits)
        for pset, period, first in ((fine, 200 / 3, first_phase),
                                    (coarse, 100.0, first_phase + 3)):
            assert isinstance(pset, PhaseSet) and pset.orientation == orientation
            assert pset.period_px == pytest.approx(period, rel=1e-6)
            np.testing.assert_allclose(pset.shifts_rad, SHIFTS, atol=1e-6)
            assert [Path(f).name for f in pset.files] == _names(first, 3)
    said = capsys.readouterr().out
    assert "vertical: white_black (2), gray (10), p66.667 (3), p100 (3)" in said
