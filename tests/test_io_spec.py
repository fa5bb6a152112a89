"""Acceptance spec files: round trip of every field and one clear error per mistake."""

from __future__ import annotations

import math

import pytest

from scanqa.errors import InputError
from scanqa.io.spec import FORMAT, Mpe, read_spec

FULL = f'''format = "{FORMAT}"
name = "maker sheet"
mpe_pf_um = 15.0
mpe_ps_um = 10
mpe_sd_um = {{ a = 20.0, b = 1000.0 }}
mpe_f_um = 25.0

[sphere]
diameter_mm = 25.4013
diameter_uncertainty_um = 1.0
form_um = 1.5

[ball_bar]
distance_mm = 300.0042
distance_uncertainty_um = 2.0
k = 2.5
diameter_mm = 25.4

[flat]
flatness_um = 2.0
'''


def write(tmp_path, text, name="spec.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_every_field_is_read(tmp_path):
    spec = read_spec(write(tmp_path, FULL))
    assert spec.name == "maker sheet" and spec.source.endswith("spec.toml")
    assert spec.mpe["PF"] == Mpe(15.0) and spec.mpe["PS"].at() == pytest.approx(0.010)
    assert spec.mpe["SD"].at(300.0) == pytest.approx(0.0203)  # 20 + 300/1000 um, in mm
    assert spec.mpe["F"].at(500.0) == pytest.approx(0.025)  # constant: no length term
    assert spec.sphere.diameter_mm == 25.4013 and spec.sphere.k == 2.0
    assert spec.sphere.form_um == 1.5 and spec.sphere.diameter_uncertainty_um == 1.0
    assert spec.ball_bar.k == 2.5 and spec.ball_bar.diameter_mm == 25.4
    assert spec.flat.flatness_um == 2.0


def test_certificates_are_optional(tmp_path):
    spec = read_spec(write(tmp_path, f'format = "{FORMAT}"\nmpe_pf_um = 12\n'))
    assert spec.sphere is None and spec.ball_bar is None and spec.flat is None
    assert spec.name == "spec" and set(spec.mpe) == {"PF"}
    assert math.isinf(spec.mpe["PF"].b)


@pytest.mark.parametrize("text, message", [
    ('format = "scanqa-spec/1"\n[sphere]\ndiameter_mm = 25.4\ndiameter_uncertainty_um = 1\n',
     r"no MPE given: set at least one of mpe_pf_um, mpe_ps_um, mpe_sd_um, mpe_f_um"),
    ('format = "scanqa-spec/2"\nmpe_pf_um = 1\n', r"format must be 'scanqa-spec/1'"),
    ('format = "scanqa-spec/1"\nmpe_pf = 1\n', r"unknown key 'mpe_pf'"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = -3\n',
     r"mpe_pf_um must be a finite number > 0 \[um\] .*, got -3"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = "5"\n', r"mpe_pf_um must be a finite number > 0"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = {a = 1, b = 2}\n',
     r"mpe_pf_um must be a finite number > 0 \[um\] .*only mpe_sd_um may depend on "
     "the length"),
    ('format = "scanqa-spec/1"\nmpe_sd_um = {a = 1, c = 2}\n', r"A \+ L/K \[um\] with L in mm"),
    ('format = "scanqa-spec/1"\nmpe_sd_um = {a = 1, b = 0}\n',
     r"mpe_sd_um.b must be a finite number > 0"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = 1\n[sphere]\ndiameter_mm = 25.4\n',
     r"\[sphere\]: diameter_uncertainty_um is missing \(the certificate's value\)"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = 1\n[ball_bar]\nlength_mm = 300\n',
     r"\[ball_bar\]: unknown key 'length_mm' \(known: distance_mm"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = 1\nflat = 3\n', r"\[flat\] must be a table"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = 1\n[flat]\nflatness_um = -1\n',
     r"flat.flatness_um must be a finite number >= 0"),
    ('format = "scanqa-spec/1"\nmpe_pf_um = [1\n', r"is not valid TOML"),
])
def test_each_mistake_gets_one_clear_message(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(InputError, match=message) as err:
        read_spec(path)
    assert str(path) in str(err.value)  # the message names the file


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"cannot read acceptance spec .*nope\.toml"):
        read_spec(tmp_path / "nope.toml")
