"""Real captures (SLStudio's skull, README in the real-data folder) decoded with default
settings: no [sensor] table, so the noise comes from the images.

``skull_2x3``: two 3-step sets along projector columns, 114 px and 1824 px, shifts 0,
-2 pi/3, -4 pi/3. ``skull_gray``: a white and a black frame, then 10 bit planes (most
significant first) of the reflected Gray code of the column index, each code covering 2
columns. The patterns.toml of each is written here into tmp_path and names the real
BMPs by absolute path (nothing is copied).

Reference numbers: a reference decoder finds 14.0 % of skull_2x3 valid; SLStudio's own
reconstruction of skull_gray (its pointCloud.mat) has 4.1 % of the pixels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.io.patterns import dumps_patterns
from tests.realdata import SLSTUDIO, needs_slstudio

pytestmark = needs_slstudio

SHIFTS = [0.0, -2 * math.pi / 3, -4 * math.pi / 3]


def _frames(folder: str, indices) -> list[str]:
    return [str(SLSTUDIO / folder / f"frameSeq_{i:02d}.bmp") for i in indices]


def _write(tmp_path, name: str, sets: list[dict]) -> str:
    folder = tmp_path / name
    folder.mkdir()
    text = dumps_patterns({"format": "scanqa-patterns/2", "projector_width_px": 1824,
                           "set": sets})
    (folder / "patterns.toml").write_text(text)
    return str(folder)


@pytest.fixture(scope="module")
def decoded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("skull")
    two_by_three = _write(tmp, "skull_2x3", [
        {"kind": "phase", "name": "p114", "period_px": 114.0, "steps": 3,
         "shifts_rad": SHIFTS, "files": _frames("skull_2x3", range(3))},
        {"kind": "phase", "name": "p1824", "period_px": 1824.0, "steps": 3,
         "shifts_rad": SHIFTS, "files": _frames("skull_2x3", range(3, 6))}])
    gray = _write(tmp, "skull_gray", [
        {"kind": "reference", "name": "white_black", "levels": ["white", "black"],
         "files": _frames("skull_gray", range(2))},
        {"kind": "gray", "name": "gray", "bits": 10, "cell_px": 2.0,
         "files": _frames("skull_gray", range(2, 12))}])
    return decode_pattern_dir(two_by_three), decode_pattern_dir(gray)


def test_phase_sets_decode_a_real_8_bit_camera_by_default(decoded):
    pm, _ = decoded
    share = pm.valid.mean()
    assert share >= 0.13, pm.summary()  # a reference decoder: 14.0 %
    summary = pm.summary()
    assert "noise: estimated from the images: offsets of the phase sets" in summary
    assert "period disagreement: 'p1824' - x_p median" in summary
    # the most masked pixels are dark (the skull fills a fifth of the frame): the
    # summary names the reason and the key that would change it
    assert "most pixels are masked: low_modulation" in summary
    assert "thresholds.unwrap_sigma_margin" in summary
    assert np.nanmax(pm.xp) < 1823.5 and np.nanmin(pm.xp) > -0.5


def test_gray_code_alone_decodes_at_least_what_slstudio_reconstructed(decoded):
    _, pm = decoded
    assert pm.valid.mean() >= 0.041, pm.summary()  # SLStudio's pointCloud.mat: 4.1 %
    assert "repeats of the white and black levels" in pm.summary()
    np.testing.assert_allclose(pm.sigma_xp[pm.valid], 2 / math.sqrt(12), rtol=1e-6)


def test_slstudio_reconstructed_pixels_are_decoded():
    pytest.importorskip("scipy.io")
    from scipy.io import loadmat

    xyz = loadmat(SLSTUDIO / "skull_gray" / "pointCloud.mat")["xyz"]
    theirs = np.isfinite(xyz).all(axis=2) & (np.abs(xyz).sum(axis=2) > 0)
    assert theirs.mean() == pytest.approx(0.041, abs=0.001)


def test_both_codings_agree_within_the_gray_quantisation(decoded):
    phase, gray = decoded
    both = phase.valid & gray.valid
    assert both.sum() > 50000
    diff = np.abs(phase.xp - gray.xp)[both]
    # no fringe-order error anywhere: one order is 114 px
    assert diff.max() < 57.0
    # the Gray code knows x_p to its 2-column cell (|error| <= 1 px), the phase to its
    # predicted sigma: 99.5 % agree within 1 px + 3 sigma
    sigma = phase.sigma_xp[both]
    assert np.mean(diff <= 1.0 + 3.0 * sigma) >= 0.995
    # and 98.5 % within 2 columns flat (measured 98.7 %: the 3-step phase noise, a
    # median offset of -0.2 px between the captures and Gray edges make the rest)
    assert np.mean(diff <= 2.0) >= 0.985
