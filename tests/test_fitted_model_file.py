"""A characterisation summary.json given to --model: one clear error for each kind of bad
file (found by an ad-hoc fuzz of the file through ``scanqa annotate --model``)."""

from __future__ import annotations

import json

import pytest

from scanqa.errors import InputError
from scanqa.io.fitted_model import read_fitted_model

GOOD = {"best_variant": {"filter_floor": "smooth", "noise_reading": "two_source",
                         "filter_form": "sum", "sigma_p_px": 0.03, "gamma": 2.2,
                         "sensor_sigma_p_px": 0.005}}


def test_a_good_summary_gives_its_numbers(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(GOOD))
    got = read_fitted_model(path)
    assert (got["sigma_p_px"], got["gamma"], got["sensor_sigma_p_px"]) == (0.03, 2.2, 0.005)
    assert got["filter_floor"] == "smooth" and "summary.json" in got["characterised_by"]


@pytest.mark.parametrize(("text", "message"), [
    ("[" * 100000 + "]" * 100000, r"maximum recursion depth"),   # was a RecursionError
    (json.dumps({"best_variant": {**GOOD["best_variant"], "gamma": True}}),
     r"best_variant gamma \(a number, got true\)"),               # float(True) was 1.0
    (json.dumps({"best_variant": {**GOOD["best_variant"], "sigma_p_px": None}}),
     r"float\(\) argument"),
    ("[1, 2]", r"list indices"),
])
def test_bad_summaries_give_one_clear_error(tmp_path, text, message):
    path = tmp_path / "summary.json"
    path.write_text(text)
    with pytest.raises(InputError, match=r"summary\.json is not a characterisation summary "
                                         r"\(scanqa characterize writes one; missing or bad .*"
                                         + message):
        read_fitted_model(path)


def test_json_nested_past_the_parser_inside_npz_files_is_one_clear_error(tmp_path):
    """The JSON a phase map (provenance) and a table (meta) carry, nested deeper than
    Python's parser goes: an InputError naming the file, not a RecursionError."""
    import numpy as np

    from scanqa.calibration.table import load_table
    from scanqa.decoding.phasemap import load_phase_map, save_phase_map
    from tests.smallcases import phase_map, small_config

    deep = "[" * 100000 + "]" * 100000
    good = save_phase_map(tmp_path / "good.npz", phase_map(small_config()))
    with np.load(good) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(tmp_path / "deep.npz", **{**arrays, "provenance": np.array(deep)})
    with pytest.raises(InputError, match=r"deep\.npz: provenance is not valid JSON"):
        load_phase_map(tmp_path / "deep.npz")
    np.savez(tmp_path / "table.npz", meta=np.array(deep))
    with pytest.raises(InputError, match=r"table\.npz: table metadata is not JSON"):
        load_table(tmp_path / "table.npz")
