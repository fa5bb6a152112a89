"""The paper's Table 3 (Drouin et al. 2017, Sect. 4.3) beside scanqa's per-block numbers.

The expected values below are typed from the paper's text, Table 3 "The predicted and
measured standard deviation in um, for a plane fitted on each gauge block":

    Height in (mm)            50.80  25.40  12.7  7.62  6.35  5.08  3.18  2.54
    Measured Std. Dev. (um)   22     12     14    16    16    (gap) 18    20
    Predicted Std. Dev. (um)  Large  13     13    15    16    17    21    22

The measured row has seven numbers for eight blocks, the gap under block 6.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.qa.paper import (
    PAPER_TABLE3,
    PAPER_TABLE3_HEIGHTS_MM,
    TABLE3_COLUMNS,
    paper_ratio,
    paper_series,
    table3_rows,
)
from scanqa.qa.results import BlockResult
from scanqa.report.qa import BLOCK_MAIN, LABELS
from scanqa.simulator.scene import GAUGE_HEIGHTS_MM

TABLE3_HEIGHTS = (50.80, 25.40, 12.70, 7.62, 6.35, 5.08, 3.18, 2.54)  # [mm]
TABLE3_MEASURED = (22, 12, 14, 16, 16, None, 18, 20)  # [um]; block 6 not legible
TABLE3_PREDICTED = (None, 13, 13, 15, 16, 17, 21, 22)  # [um]; block 1 "Large value"


def test_table3_values_are_the_papers():
    for i in range(8):
        assert PAPER_TABLE3[i + 1] == (TABLE3_PREDICTED[i], TABLE3_MEASURED[i]), i + 1
        assert PAPER_TABLE3_HEIGHTS_MM[i + 1] == TABLE3_HEIGHTS[i]
    assert sorted(PAPER_TABLE3) == list(range(1, 9))


def test_table3_heights_are_the_simulated_blocks():
    """The simulated gauge set (sample data, demo) stacks Table 3's blocks."""
    assert GAUGE_HEIGHTS_MM == TABLE3_HEIGHTS


def test_table3_ratios_by_hand():
    """Measured / predicted of Table 3, by hand: 12/13, 14/13, 16/15, 16/16, 18/21, 20/22;
    the paper's "predicted values similar to the measured" is within 15 % for each."""
    hand = {2: 0.9230769230769231, 3: 1.0769230769230769, 4: 1.0666666666666667,
            5: 1.0, 7: 0.8571428571428571, 8: 0.9090909090909091}
    for block, ratio in hand.items():
        assert paper_ratio(block) == pytest.approx(ratio, rel=1e-15)  # float rounding
        assert abs(paper_ratio(block) - 1.0) <= 0.15, block
    for block in (1, 6, 9, 0):  # no pair printed, or no such block
        assert math.isnan(paper_ratio(block)), block


def test_table3_series_has_nan_where_the_paper_has_no_number():
    predicted, measured = paper_series([1, 6, 7, 42])
    np.testing.assert_array_equal(predicted, [np.nan, 17.0, 21.0, np.nan])
    np.testing.assert_array_equal(measured, [22.0, np.nan, 18.0, np.nan])


def _blocks() -> list[BlockResult]:
    return [BlockResult(block_id=i, nominal_height_mm=h, n_points=1000,
                        measured_std_um=6.0 + 0.1 * i, predicted_std_um=6.5, status="ok")
            for i, h in zip(range(1, 9), TABLE3_HEIGHTS, strict=True)]


def test_table3_rows_join_the_paper_to_scanqa_by_block():
    rows = table3_rows(_blocks(), paper=True)
    assert [r["block_id"] for r in rows] == list(range(1, 9))
    assert rows[0]["paper_predicted_um"] == "large/-" and rows[0]["paper_measured_um"] == 22
    assert rows[5]["paper_predicted_um"] == 17 and rows[5]["paper_measured_um"] == "-"
    assert rows[6]["paper_predicted_um"] == 21 and rows[6]["paper_measured_um"] == 18
    assert rows[6]["paper_ratio"] == pytest.approx(18 / 21, rel=1e-15)
    # scanqa's own numbers are untouched: 6.7 / 6.5 for block 7
    assert rows[6]["ratio"] == pytest.approx(6.7 / 6.5, rel=1e-12)
    assert all(c in LABELS for c in TABLE3_COLUMNS)
    plain = table3_rows(_blocks(), paper=False)
    assert not any(c in r for r in plain for c in TABLE3_COLUMNS)
    assert set(BLOCK_MAIN) <= set(plain[0])


def test_table3_report_renders_the_papers_values():
    from scanqa.qa.results import QAResult
    from scanqa.report.html import Page
    from scanqa.report.qa import _table3_section

    blocks = _blocks()
    n = 0
    result = QAResult(blocks=blocks, steps=[], block_id=np.full(n, -1),
                      residual_um=np.zeros(n), local_std_um=np.zeros(n), has_prediction=True,
                      notes=[], settings={"paper_comparison": True})
    page = Page("Table 3")
    _table3_section(page, result)
    html = page.render()
    assert "paper Table 3" in html and "large/-" in html
    assert "paper ratio" in html
