"""Artefact layout files: every key read back, one clear error per mistake, and the
layouts the simulator writes read by the QA's loader."""

from __future__ import annotations

import pytest

from scanqa.errors import InputError
from scanqa.io.artefacts import FORMAT, layout_format, read_artefact_layout
from scanqa.qa.artefacts import load_artefact_layout

FULL = f'''format = "{FORMAT}"
name = "bench"
frame = "scanner"

[[sphere]]
id = "S1"
diameter_mm = 25.4
centre_mm = [1.0, -2.0, 450.0]
scan = "p000"

[[sphere]]
id = "S2"
diameter_mm = 12

[[ball_bar]]
id = "P1"
diameter_mm = 12.0
distance_mm = 40
centre_a_mm = [-14.0, -12.0, 442.0]
centre_b_mm = [14.0, 12.0, 458.0]
bar_diameter_mm = 4.0
scan = "p001"

[[flat]]
id = "F1"
centre_mm = [0.0, 0.0, 450.0]
normal = [0.0, 0.17, -0.98]
size_mm = [50.0, 40.0]
'''


def write(tmp_path, text, name="layout.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_every_key_is_read(tmp_path):
    data = read_artefact_layout(write(tmp_path, FULL))
    assert data["name"] == "bench" and data["source"].endswith("layout.toml")
    s1, s2 = data["sphere"]
    assert s1 == {"id": "S1", "scan": "p000", "diameter_mm": 25.4,
                  "centre_mm": (1.0, -2.0, 450.0), "centre_a_mm": None, "centre_b_mm": None,
                  "normal": None, "size_mm": None}
    assert s2["diameter_mm"] == 12.0 and s2["centre_mm"] is None and s2["scan"] == ""
    bar = data["ball_bar"][0]
    assert (bar["distance_mm"], bar["bar_diameter_mm"]) == (40.0, 4.0)
    assert bar["centre_b_mm"] == (14.0, 12.0, 458.0)
    flat = data["flat"][0]
    assert flat["normal"] == (0.0, 0.17, -0.98) and flat["size_mm"] == (50.0, 40.0)
    assert layout_format(tmp_path / "layout.toml") == FORMAT


def test_the_qa_loader_keeps_kinds_and_scans(tmp_path):
    layout = load_artefact_layout(write(tmp_path, FULL))
    assert [(a.kind, a.id) for a in layout.artefacts] == [
        ("sphere", "S1"), ("sphere", "S2"), ("ball_bar", "P1"), ("flat", "F1")]
    s1, s2, bar, _ = layout.artefacts
    assert s1.applies_to("p000_r3") and not s1.applies_to("p001_r0")
    assert s2.applies_to("anything")  # no scan key: every scan
    assert bar.centre_mm == (-14.0, -12.0, 442.0) and bar.centre_b_mm == (14.0, 12.0, 458.0)


@pytest.mark.parametrize("edit, message", [
    (("scanqa-artefact-layout/1", "scanqa-gauge-layout/1"), "format must be"),
    (('name = "bench"', 'name = "bench"\nunits = "mm"'), "unknown key 'units'"),
    (('id = "S2"\ndiameter_mm = 12', 'id = "S2"\ndiameter_mm = -12'),
     r"\[\[sphere\]\] 2 \('S2'\): diameter_mm must be a finite number > 0 \[mm\] "
     r"\(nominal diameter\), got -12"),
    (('id = "S2"\ndiameter_mm = 12', 'id = "S2"'),
     r"\[\[sphere\]\] 2 \('S2'\): diameter_mm is missing"),
    (("centre_mm = [1.0, -2.0, 450.0]", "centre_mm = [1.0, 450.0]"),
     "centre_mm must be a list of 3 finite numbers"),
    (("centre_b_mm = [14.0, 12.0, 458.0]\n", ""), "give both centre_a_mm and centre_b_mm"),
    (("bar_diameter_mm = 4.0", "bar_diameter_mm = 12.0"),
     "bar_diameter_mm must be smaller than diameter_mm"),
    (("normal = [0.0, 0.17, -0.98]", "normal = [0.0, 0.0, 0.0]"), "normal must not be zero"),
    (('centre_mm = [0.0, 0.0, 450.0]\nnormal', 'normal'), "normal needs centre_mm"),
    (('id = "S2"', 'id = "S1"'), "'S1' appears twice"),
    (("size_mm = [50.0, 40.0]", "size_mm = [50.0, 0.0]"),
     "size_mm must be a list of 2 finite numbers > 0"),
    (('diameter_mm = 25.4\ncentre_mm', 'diameter_mm = 25.4\ncolour = 1\ncentre_mm'),
     r"\[\[sphere\]\] 1 \('S1'\): unknown key 'colour'"),
])
def test_each_mistake_gets_one_clear_error(tmp_path, edit, message):
    old, new = edit
    assert old in FULL
    with pytest.raises(InputError, match=message) as err:
        read_artefact_layout(write(tmp_path, FULL.replace(old, new, 1)))
    assert "layout.toml" in str(err.value)


def test_a_layout_needs_an_artefact(tmp_path):
    with pytest.raises(InputError, match="no artefact: add a"):
        read_artefact_layout(write(tmp_path, f'format = "{FORMAT}"\nname = "x"\n'))
    with pytest.raises(InputError, match="cannot read artefact layout"):
        read_artefact_layout(tmp_path / "missing.toml")
