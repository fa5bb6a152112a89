"""The GUM budget of the gauge-block steps and the block statuses, on synthetic clouds
whose expected numbers are computed here by hand (JCGM 100:2008)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.io.cloud import write_cloud
from scanqa.qa.blocks import MAX_FLAGGED_FRACTION, run_qa
from scanqa.qa.budget import coverage_factor, load_budget, welch_satterthwaite

from .test_gauge import LAYOUT, synthetic_cloud

BUDGET = """format = "scanqa-budget/1"
[gauge_blocks]
certificate_U_um = 0.10
certificate_U_per_mm_um = 0.001
certificate_k = 2.0
[temperature]
deviation_K = 0.5
uncertainty_K = 0.2
expansion_per_K = 11.5e-6
expansion_uncertainty_per_K = 1.0e-6
[stage]
scale_uncertainty_ppm = 20.0
[calibration_flat]
flatness_um = 0.5
"""


@pytest.fixture(scope="module")
def cloud():
    xyz, attrs, layout = synthetic_cloud(step=0.5)
    return AnnotatedCloud(xyz, attrs), layout


def test_budget_file_adds_type_b_by_the_hand_computed_amount(cloud, tmp_path):
    (tmp_path / "b.toml").write_text(BUDGET)
    plain = run_qa(*cloud)
    full = run_qa(*cloud, budget=load_budget(tmp_path / "b.toml"))
    assert not plain.summary()["type_b_included"] and full.summary()["type_b_included"]
    for s0, s1 in zip(plain.steps, full.steps, strict=True):
        la = {b.block_id: b.nominal_height_mm for b in plain.blocks}[s0.block_a]
        lb = {b.block_id: b.nominal_height_mm for b in plain.blocks}[s0.block_b]
        d = la - lb  # [mm]
        by_hand = [  # contributions [um], each written out from the budget file
            (0.10 + 0.001 * la) / 2.0, (0.10 + 0.001 * lb) / 2.0,   # certificates
            11.5e-6 * d * 1e3 * 0.2,                               # temperature
            d * 1e3 * 0.5 * 1.0e-6,                                # expansion coefficient
            20e-6 * d * 1e3,                                       # stage scale
            0.5 / math.sqrt(6.0)]                                  # flat: F / sqrt(6)
        u = math.sqrt(s0.u_um**2 + sum(c * c for c in by_hand))
        assert s1.u_um == pytest.approx(u, rel=1e-12)
        assert s1.expanded_um == pytest.approx(2.0 * u, rel=1e-12)
        # the reference is the nominal difference at 20.5 degC: d (1 + alpha dT)
        assert s1.error_um == pytest.approx(s0.error_um - 1e3 * d * 11.5e-6 * 0.5, abs=1e-9)


def test_welch_satterthwaite_and_its_k():
    # GUM G.4: u = sqrt(1 + 1), nu_eff = u^4 / (1 / 10) = 40; t_0.975(40) = 2.021 (tables)
    assert welch_satterthwaite([(1.0, 10.0), (1.0, math.inf)]) == pytest.approx(40.0)
    assert coverage_factor(40.0) == pytest.approx(2.021, abs=5e-4)
    assert coverage_factor(math.inf) == pytest.approx(1.960, abs=5e-4)
    assert welch_satterthwaite([(0.0, 5.0), (1.0, math.inf)]) == math.inf


def test_k_from_the_effective_degrees_of_freedom(cloud):
    res = run_qa(*cloud, k="welch-satterthwaite")
    for s in res.steps:
        nu = s.budget.nu_eff
        assert nu > 4 and s.k == pytest.approx(coverage_factor(nu))
        assert s.expanded_um == pytest.approx(s.k * s.u_um)
    with pytest.raises(InputError, match="k must be a number > 0"):
        run_qa(*cloud, k="three")


def _flag(attrs: dict, xyz: np.ndarray, region: tuple, fraction: float, field: str) -> None:
    """Mark ``fraction`` of the points inside ``region`` (less the 1 mm margin) invalid in
    ``field``."""
    x0, x1, y0, y1 = region
    on = (xyz[:, 0] > x0 + 1) & (xyz[:, 0] < x1 - 1) & (xyz[:, 1] > y0 + 1) \
        & (xyz[:, 1] < y1 - 1)
    idx = np.flatnonzero(on)
    attrs[field][idx[:round(fraction * idx.size)]] = 0.0


def test_half_invalid_block_is_flagged_and_its_steps_not_evaluated(tmp_path):
    xyz, attrs, layout = synthetic_cloud(step=0.5)
    regions = {b.block_id: b.region_mm for b in layout.blocks}
    _flag(attrs, xyz, regions[3], 0.5, "in_volume")     # half of block 3 outside the volume
    _flag(attrs, xyz, regions[6], 0.03, "model_valid")  # 3 % of block 6 past the model: ok
    res = run_qa(AnnotatedCloud(xyz, attrs), layout)
    status = {b.block_id: b.status for b in res.blocks}
    assert status[3] == "outside_volume" and status[6] == "ok"
    assert 0.03 < MAX_FLAGGED_FRACTION < 0.5
    decision = {(s.block_a, s.block_b): s.decision for s in res.steps}
    assert decision[(2, 3)] == decision[(3, 4)] == "not evaluated"
    assert all(v in ("pass", "undecided") for k, v in decision.items() if 3 not in k)
    assert all(s.within_u for s in res.steps if s.evaluated)
    # every count in the summary agrees with the tables written beside it
    cloud = write_cloud(tmp_path / "c.ply", xyz, attrs)
    assert main(["qa", str(cloud), "--layout", str(LAYOUT), "--out", str(tmp_path / "qa")]) == 0
    info = json.loads((tmp_path / "qa" / "summary.json").read_text())
    rows = [line.split(",") for line in
            (tmp_path / "qa" / "steps.csv").read_text().splitlines()[1:]]
    blocks = [line.split(",")[-1] for line in
              (tmp_path / "qa" / "blocks.csv").read_text().splitlines()[1:]]
    assert info["steps_not_evaluated"] == sum(r[-2] == "not evaluated" for r in rows) == 2
    assert info["steps_evaluated"] == len(rows) - 2 == 5
    for d in ("pass", "fail", "undecided"):
        assert info["decisions"][d] == sum(r[-2] == d for r in rows)
    assert info["blocks_flagged"] == sum(b != "ok" for b in blocks) == 1
    assert info["steps_error_within_U"] == 5
    html = (tmp_path / "qa" / "report.html").read_text()
    assert "2 not evaluated" in html and "Type B is not included" in html


@pytest.mark.parametrize(("body", "message"), [
    ('format = "x"\n', "format must be 'scanqa-budget/1'"),
    (BUDGET + "[extra]\na = 1\n", r"unknown key 'extra' \(known: format, gauge_blocks"),
    (BUDGET.replace("flatness_um = 0.5", "flatness_mm = 0.5"), "unknown key 'flatness_mm'"),
    (BUDGET.replace("uncertainty_K = 0.2", "uncertainty_K = -0.2"),
     r"uncertainty_K must be a finite number >= 0 \[K\]"),
    (BUDGET.replace("expansion_per_K = 11.5e-6\n", ""), "needs expansion_per_K"),
    (BUDGET + "[coverage]\nk = \"big\"\n", "k must be a number > 0 or 'welch-satterthwaite'"),
])
def test_budget_file_errors_name_the_file_and_key(tmp_path, body, message):
    path = tmp_path / "budget.toml"
    path.write_text(body)
    with pytest.raises(InputError, match=message) as err:
        load_budget(path)
    assert str(path) in str(err.value)


def test_budget_file_coverage_and_cli(cloud, tmp_path, capsys):
    (tmp_path / "b.toml").write_text(BUDGET + "[coverage]\nk = \"welch-satterthwaite\"\n")
    res = run_qa(*cloud, budget=load_budget(tmp_path / "b.toml"))
    assert all(s.k == pytest.approx(coverage_factor(s.budget.nu_eff)) for s in res.steps)
    xyz, attrs, _ = synthetic_cloud(step=0.5)
    path = write_cloud(tmp_path / "c.ply", xyz, attrs)
    assert main(["qa", str(path), "--layout", str(LAYOUT), "--out", str(tmp_path / "qa"),
                 "--budget", str(tmp_path / "b.toml"), "--k", "2"]) == 0
    info = json.loads((tmp_path / "qa" / "summary.json").read_text())
    assert info["type_b_included"] and all(s["k"] == 2.0 for s in info["steps"])
    names = {c["component"] for c in info["budgets"][0]["components"]}
    assert {"gauge-block certificates (both blocks)", "temperature of the blocks",
            "calibration stage scale", "flatness of the calibration flat"} <= names
    assert "Type B is not included" not in (tmp_path / "qa" / "report.html").read_text()
