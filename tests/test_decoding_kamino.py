"""kamino410's object1 (another scanner: 8-bit camera, 1920 x 1080 projector with an
unrecorded pre-gamma), decoded from a hand description against the reference decoder's
result (``object1_ref.npz``).

Its Gray cells are as wide as the 100 px period they order, so at every cell edge the
Gray code and the phase disagree by the blur and the 100 px set's gamma ripple
(+-7.5 px); the 66.667 px set tells the neighbouring orders apart there (their 200 px
beat). object1 is the data the order decision was TUNED on (the held-out object2 of the
same coding is not here): the counts below are tuning numbers. Which decoder is right
where the two disagree by a fringe order is judged by the 100 px phase, computed here
from the images with numpy alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from scanqa.decoding.decoder import decode_pattern_dir
from tests.realdata import KAMINO, KAMINO_SHIFTS, kamino_object1_patterns, needs_kamino

pytestmark = [needs_kamino, pytest.mark.slow]


@pytest.fixture(scope="module")
def object1(tmp_path_factory):
    columns, rows = kamino_object1_patterns(tmp_path_factory.mktemp("object1"))
    ref = np.load(KAMINO / "object1_ref.npz")
    return {"x": (decode_pattern_dir(columns), ref["x"].astype(float), 3),
            "y": (decode_pattern_dir(rows), ref["y"].astype(float), 9)}


def _phase_100(first: int) -> np.ndarray:
    """Wrapped phase of the 100 px set [cycles]: I_k = A + B cos(phi + d_k)."""
    frames = np.stack([np.asarray(Image.open(KAMINO / "object1" / f"pat{first + k:02d}.png"),
                                  float) for k in range(3)])
    c = np.tensordot(np.cos(KAMINO_SHIFTS), frames, 1)
    s = np.tensordot(np.sin(KAMINO_SHIFTS), frames, 1)
    return np.mod(np.arctan2(-s, c) / (2 * np.pi), 1.0)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_object1_decodes_what_the_reference_decodes(object1, axis):
    pm, ref, first = object1[axis]
    ours, theirs = np.isfinite(pm.xp), np.isfinite(ref)
    # tuning numbers (before: 0.833 columns, 0.930 rows)
    assert ours.sum() >= 0.95 * theirs.sum(), (ours.sum(), theirs.sum())
    both = ours & theirs
    assert np.median(np.abs(pm.xp[both] - ref[both])) < 1e-3
    phase = _phase_100(first)

    def off_100(x):  # distance of a coordinate from the 100 px set's phase [px]
        r = x / 100.0 - phase
        return np.abs(r - np.rint(r)) * 100.0

    differ = both & (np.abs(pm.xp - ref) > 10.0)
    wrong = differ & (off_100(np.where(differ, pm.xp, 0)) > off_100(np.where(differ, ref, 0)))
    ref_right = wrong & (off_100(np.where(wrong, ref, 0)) < 15.0)
    assert ref_right.sum() <= 1e-4 * both.sum(), (ref_right.sum(), both.sum())


def test_object1_names_its_gamma_distorted_sets(object1):
    pm = object1["x"][0]
    named = [w for w in pm.provenance["decode"]["warnings"] if "not sine waves" in w]
    assert any("'p100'" in w and "ripples" in w for w in named), named
