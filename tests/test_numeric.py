"""scanqa.numeric: the one robust std, range parser and JSON cleaning (issue 47)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from scanqa.numeric import inclusive_range, json_ready, parse_range, robust_std


def test_robust_std_is_the_std_of_a_normal_sample_and_ignores_outliers():
    rng = np.random.default_rng(7)
    x = rng.normal(5.0, 2.0, 200_000)
    x[:1000] = 1e6  # 0.5 % gross outliers
    assert robust_std(x) == pytest.approx(2.0, rel=0.02)
    # about zero: |[-3, 1, 2]| has median 2
    assert robust_std([-3.0, 1.0, 2.0, np.nan], centre=0.0) == pytest.approx(1.4826 * 2)
    assert math.isnan(robust_std([np.nan, np.inf]))


def test_parse_range_is_inclusive_and_refuses_what_is_not_a_range():
    assert parse_range("-30:30:2") == [float(v) for v in range(-30, 31, 2)]
    assert parse_range("0:1:0.1")[-1] == 1.0 and len(parse_range("0:1:0.1")) == 11
    assert list(inclusive_range(424.0, 476.0, 4.0)) == list(range(424, 477, 4))
    for bad in ("1:2", "a:b:c", "0:1:0", "2:1:1", "0:1e9:1"):
        with pytest.raises(ValueError, match=r"START:STOP:STEP|STEP > 0"):
            parse_range(bad)


def test_json_ready_gives_strict_json():
    value = {"a": [1.0, float("nan"), np.float32(0.5)], "b": (np.int64(3), -np.inf),
             "c": {"d": np.bool_(True), "e": "text"}}
    text = json.dumps(json_ready(value), allow_nan=False)
    assert json.loads(text) == {"a": [1.0, None, 0.5], "b": [3, None],
                                "c": {"d": True, "e": "text"}}
