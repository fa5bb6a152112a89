"""The model's readings of Eqs. 17 and 19: one mapping of name to function each.

Hand values: F = 2, A_p = 0.25, A_c = 0.64, so sqrt(A_p A_c) = 0.4, A_p A_c = 0.16,
sqrt(A_p) A_c = 0.32 (Eq. 19 of Drouin et al. 2017 in its readings, docs/model.rst, and
the two-source model, docs/noise_model.rst).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re

import numpy as np
import pytest

from scanqa.characterization import noisefit
from scanqa.errors import MethodError, ScanQAError
from scanqa.model import config as config_module
from scanqa.model import optics, readings

MAPPINGS = {  # mapping -> (the names a config accepts, the ModelConfig field, entry point)
    "reading": (readings.NOISE_READING_METHODS, config_module.NOISE_READINGS,
                "noise_reading"),
    "form": (readings.FILTER_FORM_METHODS, config_module.FILTER_FORMS, "filter_form"),
    "floor": (readings.FILTER_FLOOR_METHODS, config_module.FILTER_FLOORS, "filter_floor"),
}


@pytest.mark.parametrize("what", sorted(MAPPINGS))
def test_mapping_lists_every_name_a_config_accepts(what):
    methods, accepted, field_name = MAPPINGS[what]
    assert tuple(methods) == accepted
    field = next(f for f in dataclasses.fields(config_module.ModelConfig)
                 if f.name == field_name)
    assert tuple(methods) == field.metadata["field"].check.choices


def test_every_variant_the_fit_tries_has_a_method():
    for floor, form, reading in (noisefit.SINGLE_SWEEP_VARIANTS
                                 + noisefit.JOINT_VARIANTS):
        assert floor in readings.FILTER_FLOOR_METHODS
        assert form in readings.FILTER_FORM_METHODS
        assert reading in readings.NOISE_READING_METHODS


def test_optics_re_exports_the_noise_chain():
    for name in ("NOISE_READING_METHODS", "FILTER_FORM_METHODS", "FILTER_FLOOR_METHODS",
                 "noise_scales", "optical_scale", "filter_factor", "camera_noise_area"):
        assert getattr(optics, name) is getattr(readings, name), name


@pytest.mark.parametrize("call, what", [
    (lambda: readings.noise_scales(1.0, 0.5, 0.5, "cube"), "reading"),
    (lambda: optics.optical_scale(1.0, 0.5, 0.5, "cube"), "reading"),
    (lambda: readings.filter_factor(4.0, 1.0, 1.0, "none", "cube"), "form"),
    (lambda: readings.filter_factor(4.0, 1.0, 1.0, "cube", "sum"), "floor"),
    (lambda: readings.noise_scales(1.0, 0.5, 0.5, ["power"]), "reading"),
])
def test_unknown_name_lists_every_name(call, what):
    methods = MAPPINGS[what][0]
    with pytest.raises(MethodError) as info:
        call()
    message = str(info.value)
    assert isinstance(info.value, ScanQAError) and isinstance(info.value, ValueError)
    assert message.startswith(f"{what} must be ")
    assert all(repr(name) in message for name in methods), message


def test_unknown_floor_in_a_refit_is_refused(paper_config):
    terms = optics.optical_terms(450.0, 460.0, paper_config)
    with pytest.raises(MethodError, match=r"floor must be 'none', 'one' or 'smooth', got 'half'"):
        terms.s_o_with(3.0, "half", "power")


def test_smooth_floor_by_hand():
    """F^2 = 1 + N / gamma^2 with the sum form: noise constant over cells of gamma^2
    px^2 keeps the variance share gamma^2 / (gamma^2 + N) under a kernel of
    noise-equivalent area N. By hand: N = 5, gamma = 2 -> sqrt(1 + 5/4) = 1.5; in focus
    (N -> 0) F -> 1 with no kink where "one" bends (N = gamma^2: sqrt(2), not 1)."""
    assert readings.filter_factor(5.0, 1.0, 2.0, "smooth", "sum") == pytest.approx(1.5)
    assert readings.filter_factor(4.0, 1.0, 2.0, "smooth", "sum") == pytest.approx(math.sqrt(2))
    assert readings.filter_factor(4.0, 1.0, 2.0, "one", "sum") == pytest.approx(1.0)
    assert readings.filter_factor(1e-12, 1.0, 2.0, "smooth", "sum") == pytest.approx(1.0)
    f = readings.filter_factor(np.array([[1.0], [9.0]]), 1.0, np.sqrt(3.0), "smooth", "sum")
    np.testing.assert_allclose(f, [[2 / np.sqrt(3)], [2.0]])  # broadcasting, by hand


@pytest.mark.parametrize("reading, scene, sensor", [
    ("power", 1 / (2 * 0.16), 0.0),
    ("amplitude", 1 / (2 * 0.4), 0.0),
    ("mixed", 1 / (2 * 0.32), 0.0),
    ("two_source", 1 / (2 * 0.4), 0.5 / 0.4),
])
def test_each_reading_by_hand(reading, scene, sensor):
    got = readings.NOISE_READING_METHODS[reading](np.array(2.0), np.array(0.25),
                                                  np.array(0.64), 0.5)
    np.testing.assert_allclose(got, (scene, sensor), rtol=1e-15)  # float rounding only
    s_o = optics.optical_scale(2.0, 0.25, 0.64, reading, 0.5)
    np.testing.assert_allclose(s_o, np.hypot(scene, sensor), rtol=1e-15)


@pytest.mark.parametrize("form, floor, expected", [
    ("product", "none", np.sqrt(0.5 * 0.02) / 1.5),  # Eq. 17 as printed: 0.0667 < 1
    ("product", "one", 1.0),                          # clamped at the bound under Eq. 17
    ("sum", "none", np.sqrt(0.5) / 1.5),              # areas added, b_d held by b_c
    ("sum", "one", 1.0),
])
def test_each_filter_form_and_floor_by_hand(form, floor, expected):
    np.testing.assert_allclose(readings.filter_factor(0.5, 0.02, 1.5, floor, form),
                               expected, rtol=1e-15)


def test_nan_in_nan_out_for_every_method():
    for reading in readings.NOISE_READING_METHODS:
        scene, _ = readings.noise_scales(np.nan, 0.5, 0.5, reading, 0.1)
        assert np.isnan(scene), reading
    for floor in readings.FILTER_FLOOR_METHODS:
        for form in readings.FILTER_FORM_METHODS:
            assert np.isnan(readings.filter_factor(np.nan, 1.0, 1.0, floor, form))


@pytest.mark.parametrize("methods", [m for m, _, _ in MAPPINGS.values()])
def test_each_method_is_short_and_cites_its_equation(methods):
    for name, func in methods.items():
        doc = inspect.getdoc(func) or ""
        assert re.search(r"Eq\. 1[79]|docs/noise_model\.rst", doc), name
        body = inspect.getsource(func).split('"""')[-1]
        assert len([x for x in body.splitlines() if x.strip()]) <= 5, name


def test_codes_are_the_names_places_in_their_mappings():
    # compiled code branches on these constants; code() turns a config's name into one
    for methods, constants in ((readings.FILTER_FORM_METHODS, ("PRODUCT", "SUM")),
                               (readings.FILTER_FLOOR_METHODS, ("UNCLAMPED", "CLAMPED", "SMOOTH")),
                               (readings.NOISE_READING_METHODS,
                                ("POWER", "AMPLITUDE", "MIXED", "TWO_SOURCE"))):
        assert [readings.code(methods, name, "x") for name in methods] == \
            [getattr(readings, c) for c in constants]
