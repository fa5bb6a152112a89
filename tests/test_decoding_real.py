"""Real captures (SLStudio's skull, README in the real-data folder) decoded with default
settings: no [sensor] table, so the noise comes from the images.

``skull_2x3``: two 3-step sets along projector columns, 114 px and 1824 px, shifts 0,
-2 pi/3, -4 pi/3. ``skull_gray``: a white and a black frame, then 10 bit planes (most
significant first) of the reflected Gray code of the column index, each code covering 2
columns. The patterns.toml of each is written here into tmp_path and names the real
BMPs by absolute path (nothing is copied).

Reference numbers: a reference decoder finds 14.0 % of skull_2x3 valid; SLStudio's own
reconstruction of skull_gray (its pointCloud.mat) has 4.1 % of the pixels. scanqa decodes
14.4 % of skull_gray, 61 % of them edge pixels (one bit undecidable between two
neighbouring cells, x_p on their shared edge), and 80.0 % of SLStudio's pixels (5.6 % and
31.6 % when every undecidable bit masked its pixel).
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


def _edges(pm) -> np.ndarray:
    """Valid pixels on a cell edge: x_p = 2 k + 1.5 (cell centres are 2 k + 0.5)."""
    return pm.valid & np.isclose(np.mod(pm.xp, 2.0), 1.5, rtol=0, atol=1e-9)


def test_gray_code_alone_decodes_at_least_what_slstudio_reconstructed(decoded):
    _, pm = decoded
    summary = pm.summary()
    assert pm.valid.mean() >= 0.041, summary  # SLStudio's pointCloud.mat: 4.1 %
    assert pm.valid.mean() >= 0.14, summary  # measured 14.4 %
    assert "repeats of the white and black levels" in summary
    # every valid x_p is a cell centre or a cell edge, with the sigma of its kind:
    # the cell's quantisation, or a uniform distribution over the two cells
    edges, cells = _edges(pm), pm.valid & ~_edges(pm)
    np.testing.assert_allclose(np.mod(pm.xp[cells], 2.0), 0.5, atol=1e-9)
    np.testing.assert_allclose(pm.sigma_xp[cells], 2 / math.sqrt(12), rtol=1e-6)
    np.testing.assert_allclose(pm.sigma_xp[edges], 4 / math.sqrt(12), rtol=1e-6)
    assert 0.55 < edges.sum() / pm.valid.sum() < 0.7  # measured 61.4 %: the finest bit
    assert f"; {edges.sum()} edge pixels ({100 * edges.sum() / pm.valid.sum():.1f} % of " \
        "the valid" in summary


def test_slstudio_reconstructed_pixels_are_decoded(decoded):
    pytest.importorskip("scipy.io")
    from scipy.io import loadmat

    xyz = loadmat(SLSTUDIO / "skull_gray" / "pointCloud.mat")["xyz"]
    theirs = np.isfinite(xyz).all(axis=2) & (np.abs(xyz).sum(axis=2) > 0)
    assert theirs.mean() == pytest.approx(0.041, abs=0.001)
    _, pm = decoded
    covered = np.count_nonzero(theirs & pm.valid) / np.count_nonzero(theirs)
    # measured 80.0 % (31.6 % before the edge rule); most of the rest have the two
    # finest bits undecidable (the finest Gray pattern, 4 px stripes, is nearly washed
    # out by the projector's blur) and stay masked
    assert covered >= 0.79, pm.summary()
    assert np.count_nonzero(theirs & _edges(pm)) / np.count_nonzero(theirs) > 0.45


def test_both_codings_agree_within_the_gray_quantisation(decoded):
    phase, gray = decoded
    edges = _edges(gray)
    both = phase.valid & gray.valid & ~edges
    assert both.sum() > 50000
    diff = np.abs(phase.xp - gray.xp)[both]
    # where every bit is decided: no fringe-order error (one order is 114 px) but the
    # phase's own: 1 of 137 281 since session 41, when the image noise estimate stopped
    # over-predicting the skull's noise (sigma_xp / per-pixel random part 1.00) and the
    # unwrap's margin, judged on the noise alone, let it through
    assert np.count_nonzero(diff >= 57.0) <= 2
    # the Gray code knows x_p to its 2-column cell (|error| <= 1 px), the phase to its
    # predicted sigma: 99.5 % agree within 1 px + 3 sigma
    sigma = phase.sigma_xp[both]
    assert np.mean(diff <= 1.0 + 3.0 * sigma) >= 0.995
    # and 98 % within 2 columns flat (measured 98.4 %, 98.7 % while the image noise
    # estimate over-predicted and masked more of the noisiest pixels: the 3-step phase
    # noise, a median offset of -0.2 px between the captures and Gray edges make the rest)
    assert np.mean(diff <= 2.0) >= 0.98
    # edge pixels: within one cell (2 px, the edge rule's support) + 3 sigma of the
    # phase (measured 99.7 % of 179618), and no more spread than the stated sigmas
    # (measured rms 0.77 of them: the edge's 2 cell / sqrt(12) is conservative)
    on_edge = phase.valid & edges
    diff = (gray.xp - phase.xp)[on_edge]
    order = np.abs(diff) > 57.0
    # 5 pixels are off by about one order: the phase's own errors (both our phase
    # decoder and an independent one put them ~110 px off their neighbours, which the
    # Gray code matches); they were masked by the Gray code before the edge rule. 9 since
    # session 41 (5e-5 of the edge pixels): the image noise estimate no longer
    # over-predicts the skull's noise (sigma_xp / per-pixel random part 1.00), so the
    # unwrap's sigma margin lets 4 more of the phase's own order errors through
    assert np.count_nonzero(order) <= 10
    sigma = phase.sigma_xp[on_edge]
    assert np.mean(np.abs(diff) <= 2.0 + 3.0 * sigma) >= 0.995
    z = diff[~order] / np.hypot(4 / math.sqrt(12), sigma[~order])
    assert 0.6 < np.sqrt(np.mean(z * z)) < 1.0


def test_the_real_captures_as_described_give_no_warning(decoded):
    for pm in decoded:
        assert pm.provenance["decode"]["warnings"] == [], pm.summary()
        assert "warning" not in pm.summary()
        assert not any("finer than the optics" in n for n in pm.provenance["decode"]["notes"])


def test_a_reversed_shift_sign_on_skull_2x3_is_named(tmp_path):
    # both sets mirror and still agree (x_p -> 1824 - x_p, the same pixels valid), which
    # triangulated puts the skull at up to 22.8 m: only the direction of x_p shows it
    flipped = [-s for s in SHIFTS]
    folder = _write(tmp_path, "skull_2x3_sign", [
        {"kind": "phase", "name": "p114", "period_px": 114.0, "steps": 3,
         "shifts_rad": flipped, "files": _frames("skull_2x3", range(3))},
        {"kind": "phase", "name": "p1824", "period_px": 1824.0, "steps": 3,
         "shifts_rad": flipped, "files": _frames("skull_2x3", range(3, 6))}])
    pm = decode_pattern_dir(folder)
    warnings = pm.provenance["decode"]["warnings"]
    assert len(warnings) == 1 and "the decode looks mirrored" in warnings[0], pm.summary()
    assert "x_p falls along the camera's columns in 100 % of the decoded pixels" in \
        warnings[0]


def test_white_and_black_swapped_on_skull_gray_are_named(tmp_path):
    folder = _write(tmp_path, "skull_gray_swapped", [
        {"kind": "reference", "name": "white_black", "levels": ["black", "white"],
         "files": _frames("skull_gray", range(2))},
        {"kind": "gray", "name": "gray", "bits": 10, "cell_px": 2.0,
         "files": _frames("skull_gray", range(2, 12))}])
    pm = decode_pattern_dir(folder)
    assert any("white and black are swapped" in w
               for w in pm.provenance["decode"]["warnings"]), pm.summary()
    assert "\nwarning: set 'white_black': the frames named white are darker" in pm.summary()
