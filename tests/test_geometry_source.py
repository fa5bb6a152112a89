"""One geometry: a parametric calibration supplies the projector's pose wherever it is
given, the config only the rest. A config written for an older calibration (its projector
5 mm and 2.4 deg off) keeps working with a recalibration of the same scanner: the sizes
are still checked, the pose comes from the calibration, a large change is a warning, and
the cloud equals the one made with a config holding the calibration's pose (written by
hand here: -R^T T and R^T e_z of the synthetic calibration)."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from scanqa.annotation.points import annotate
from scanqa.calibration.parametric_checks import check_config, with_calibrated_geometry
from scanqa.errors import InputError

from .test_parametric import _scan, scanner  # noqa: F401 - fixture


def _by_hand(cal, cfg):
    """The config with the calibration's projector pose, at the config's reach."""
    pos = -cal.rotation.T @ cal.translation
    axis = cal.rotation[2] / np.linalg.norm(cal.rotation[2])
    reach = np.linalg.norm(np.subtract(cfg.projector.look_at_mm, cfg.projector.position_mm))
    return replace(cfg, projector=replace(cfg.projector, position_mm=tuple(pos),
                                          look_at_mm=tuple(pos + reach * axis)))


def test_an_old_pose_is_replaced_by_the_calibrations_with_a_warning(scanner, caplog):  # noqa: F811
    cal, cfg = scanner
    old = replace(cfg, projector=replace(cfg.projector, position_mm=(145.0, 0.0, 0.0),
                                         look_at_mm=(5.0, 20.0, 450.0)))
    with pytest.raises(InputError, match=r"5\.0 mm away"):
        check_config(cal, old)  # the explicit check still says how far apart they are
    scan = _scan(cal)
    with caplog.at_level(logging.WARNING, logger="scanqa"):
        cloud = annotate(scan, cal, old)
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("projector pose is taken from the calibration synthetic.xml" in m
               and "5.0 mm from the config's" in m for m in warned), warned
    expected = annotate(scan, cal, _by_hand(cal, cfg))
    np.testing.assert_array_equal(cloud.xyz, expected.xyz)
    for name, values in expected.attributes.items():
        np.testing.assert_array_equal(cloud.attributes[name], values, err_msg=name)
    pos = np.asarray(cloud.metadata["config"]["projector"]["position_mm"])
    np.testing.assert_allclose(pos, -cal.rotation.T @ cal.translation, atol=1e-9)


def test_a_matching_config_is_left_as_it_is(scanner, caplog):  # noqa: F811
    cal, cfg = scanner
    fitted = _by_hand(cal, cfg)
    with caplog.at_level(logging.WARNING, logger="scanqa"):
        again = with_calibrated_geometry(cal, fitted)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    np.testing.assert_allclose(again.projector.position_mm, fitted.projector.position_mm)


def test_sizes_are_still_checked(scanner):  # noqa: F811
    cal, cfg = scanner
    wrong = replace(cfg, camera=replace(cfg.camera, width_px=64))
    with pytest.raises(InputError, match=r"camera\.width_px x height_px is 64 x 300"):
        annotate(_scan(cal), cal, wrong)
