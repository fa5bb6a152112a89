"""The per-point sigma against the real scatter of a real scanner (SLStudio's captures,
README in the real-data folder), triangulated with its own calibration.xml.

Board poses calseq1..6 (columns: 114 px fringes unwrapped by the 1824 px cue): each pose's
residual about its fitted plane, bright and dark squares apart. The measured quantities
are computed by the module under test's plane/surface split, but the comparison is
against the law fitted to the *other five* poses (each pose held out in turn), and
against the decoder's own image estimate with no characterisation at all.

Skull (skull_2x3): the cue decoded alone (one 1824 px period over the panel) against the
fine decode: their x_p difference is pure noise of both plus the cue's phase-locked
error, so its robust std must match sqrt(s1^2 + s2^2) of the two decodes' sigma_xp.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.calibration.parametric import load_opencv_calibration
from scanqa.characterization import board as boardnoise
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.io.patterns import dumps_patterns
from scanqa.model.config import load_config
from scanqa.numeric import robust_std
from tests.conftest import ROOT
from tests.local_scatter import window_medians
from tests.realdata import SLSTUDIO, needs_slstudio
from tests.shared_runs import board_column_residual

pytestmark = [needs_slstudio, pytest.mark.slow]

SHIFTS = [0.0, -2 * math.pi / 3, -4 * math.pi / 3]


def _phase_set(name, period, files):
    return {"kind": "phase", "name": name, "period_px": period, "steps": 3,
            "shifts_rad": SHIFTS, "files": [str(f) for f in files]}


def _doc(sets, sensor=None) -> dict:
    doc = {"format": "scanqa-patterns/2", "projector_width_px": 1824, "set": sets}
    if sensor:
        doc["sensor"] = sensor
    return doc


def _decode(tmp, name, sets, sensor=None):
    folder = tmp / name
    folder.mkdir()
    (folder / "patterns.toml").write_text(dumps_patterns(_doc(sets, sensor)))
    return decode_pattern_dir(str(folder))


CALIBRATION_XML = SLSTUDIO / "calibration" / "calibration.xml"


@pytest.fixture(scope="module")
def calibration():
    return load_opencv_calibration(CALIBRATION_XML)


@pytest.fixture(scope="module")
def board(tmp_path_factory, calibration):
    tmp = tmp_path_factory.mktemp("board")
    poses, docs = {}, {}
    for k in range(1, 7):
        folder = SLSTUDIO / "calibration" / f"calseq{k}"
        frames = [folder / f"frameSeq_{i:02d}.png" for i in range(6)]
        sets = [_phase_set("p114", 114.0, frames[:3]), _phase_set("p1824", 1824.0, frames[3:])]
        poses[f"calseq{k}"], docs[f"calseq{k}"] = _decode(tmp, f"calseq{k}", sets), _doc(sets)
    original = boardnoise.pose_residual

    def shared(name, phase_map, cal, inner):
        """Each pose's residual about its plane, computed once per make test with
        test_flattening_real's (tests/shared_runs.py): these decodes, this calibration."""
        if phase_map is poses.get(name) and cal is calibration and tuple(inner) == (13, 9):
            return board_column_residual(int(name[-1]), phase_map, cal, docs[name],
                                         CALIBRATION_XML, split=original)
        return original(name, phase_map, cal, inner)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(boardnoise, "pose_residual", shared)
        return boardnoise.characterize_board(poses, calibration, (13, 9))


def test_held_out_poses_match_the_board_law(board):
    """Each pose predicted by the law fitted to the other five: measured/predicted in
    [0.8, 1.25] in >= 10 of the 12 (pose, colour) cells (measured here: 0.99-1.12 for the
    random part, 0.97-1.08 about the plane with the systematic term), and the dark/bright
    ratio within 10 % on every pose."""
    rows = board["held_out"]
    assert len(rows) == 12
    random = [r["ratio_random"] for r in rows]
    plane = [r["ratio_about_plane"] for r in rows]
    assert sum(0.8 <= r <= 1.25 for r in random) >= 10, random
    assert sum(0.8 <= r <= 1.25 for r in plane) >= 10, plane
    for pose in {r["pose"] for r in rows}:
        bright, dark = (next(r for r in rows if r["pose"] == pose and r["colour"] == c)
                        for c in ("bright", "dark"))
        measured = dark["measured_random_um"] / bright["measured_random_um"]
        predicted = dark["predicted_um"] / bright["predicted_um"]
        assert abs(predicted / measured - 1) <= 0.10, (pose, measured, predicted)
        # dark squares are noisier: several-fold lower fringe contrast
        assert measured > 1.3


def test_image_estimate_alone_is_within_15_percent(board):
    """No characterisation: the decoder's own per-pixel noise estimate (offsets of the
    two phase sets, differenced along the fringes), measured/predicted in [0.85, 1.15]
    on every cell (0.93-1.06 measured here; calseq1 was looked at while the estimator's
    lag was chosen, calseq2-6 not)."""
    ratios = [r["ratio_random"] for r in board["images_only"]]
    assert len(ratios) == 12 and all(0.85 <= r <= 1.15 for r in ratios), ratios


def test_board_summary_reports_the_systematic_parts_and_the_law(board, tmp_path):
    """Smooth part and phase-locked ripple per pose; the law's two terms fitted with
    intervals; --model reads the summary back into the config."""
    import json

    from scanqa.characterization.sweep import apply_fitted_model

    law = board["noise_law"]
    assert law["read_var_dn2"] > 0 and law["shot_dn"] > 0
    for key in ("read_var_dn2", "shot_dn"):
        lo, hi = law["interval_95"][key]
        assert lo <= law[key] <= hi
    for pose in board["poses"]:
        # tens of um on this board: neither is zero, neither swamps the random part
        assert 10 < pose["smooth_rms_um"] < 200 and 0 < pose["ripple_amplitude_um"] < 150
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(board))
    config = apply_fitted_model(load_config(ROOT / "calib" / "slstudio_example.toml"), path)
    assert config.model.noise_shot_dn == pytest.approx(law["shot_dn"])
    assert "(scanqa characterize board" in config.model.characterised_by


def test_skull_cue_against_fine_decode_and_local_scatter(tmp_path, calibration):
    """skull_2x3: the robust std of (cue alone - fine) x_p, the cue's phase-locked error
    fitted out, against sqrt(s1^2 + s2^2) in [0.8, 1.25] (1.27 with that error left in),
    the per-pixel random part against sigma_xp in [0.85, 1.15] (1.00), and the cloud's
    local scatter (z minus its 5 x 5 median) against the median sigma_z in [0.67, 1.5]
    with the image estimate (0.82 before this estimator)."""
    frames = [SLSTUDIO / "skull_2x3" / f"frameSeq_{i:02d}.bmp" for i in range(6)]
    fine = _decode(tmp_path, "fine", [_phase_set("p114", 114.0, frames[:3]),
                                      _phase_set("p1824", 1824.0, frames[3:])])
    s = fine.provenance["sensor_resolved"]
    cue = _decode(tmp_path, "cue", [_phase_set("p1824", 1824.0, frames[3:])],
                  {"bit_depth": 8, "gain_e_per_dn": s["gain_e_per_dn"],
                   "read_noise_e": s["read_noise_e"]})
    # the per-pixel random part: lag-3 second difference down the columns (along the
    # fringes) against the median sigma_xp, in [0.85, 1.15] (1.00 measured; held out)
    d = (fine.xp[:-6] - 2 * fine.xp[3:-3] + fine.xp[6:]) / math.sqrt(6)
    ok = np.isfinite(d) & np.isfinite(fine.sigma_xp[3:-3])
    ratio = float(np.median(fine.sigma_xp[3:-3][ok])) / robust_std(d[ok])
    assert 0.85 <= ratio <= 1.15, ratio
    both = np.isfinite(fine.xp) & np.isfinite(cue.xp)
    diff = (cue.xp - fine.xp)[both]
    # the cue's phase-locked error (a projector response that is not a sine, harmonics
    # 1-3 of its one period) is systematic, not noise: fitted out first
    theta = 2 * math.pi * fine.xp[both] / 1824.0
    basis = np.column_stack([np.ones_like(theta)] + [f(k * theta) for k in (1, 2, 3)
                                                      for f in (np.cos, np.sin)])
    diff = diff - basis @ np.linalg.lstsq(basis, diff, rcond=None)[0]
    measured = robust_std(diff)
    predicted = float(np.median(np.hypot(cue.sigma_xp[both], fine.sigma_xp[both])))
    assert 0.8 <= measured / predicted <= 1.25, (measured, predicted)

    config = load_config(ROOT / "calib" / "slstudio_example.toml")
    cloud = annotate(fine, calibration, config)
    assert cloud.metadata["sigma_source"]["kind"] == "images"
    a = cloud.attributes
    height, width = fine.xp.shape
    z = np.full((height, width), np.nan)
    sz = np.full((height, width), np.nan)
    rows, cols = a["pixel_v"].astype(int), a["pixel_u"].astype(int)
    z[rows, cols], sz[rows, cols] = cloud.xyz[:, 2], a["sz_um"]
    full, medians = window_medians(z, 5)
    local = 1e3 * (z[full] - medians)
    ratio = robust_std(local) / float(np.median(sz[full]))
    assert 0.67 <= ratio <= 1.5, ratio
