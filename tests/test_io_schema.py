"""The declared TOML schemas (scanqa.io.schema, issue 28): one declaration per document,
one validator, every io reader going through it, messages naming the file and the key,
and docs/formats.rst equal to the declarations.

Run ``python tests/test_io_schema.py`` to rewrite the schema tables of docs/formats.rst
from the declarations."""

from __future__ import annotations

import ast
import importlib
import pkgutil
import re
import sys
from dataclasses import replace
from pathlib import Path

import pytest

import scanqa.io
from scanqa.errors import ConfigError, InputError, ScanQAError
from scanqa.io import schema
from scanqa.io.artefacts import read_artefact_layout
from scanqa.io.batchfiles import read_batch_manifest, read_campaign
from scanqa.io.budget import read_budget_file
from scanqa.io.designspec import read_design_spec
from scanqa.io.layout import read_layout_file
from scanqa.io.manifest import read_manifest
from scanqa.io.patterns import read_patterns_file
from scanqa.io.response import read_response_file
from scanqa.io.spec import read_spec
from scanqa.io.sweep import load_sweep
from scanqa.model.config import SCHEMA as CONFIG
from tests.source_index import nodes

ROOT = Path(__file__).resolve().parents[1]
IO = ROOT / "src" / "scanqa" / "io"
FORMATS_RST = ROOT / "docs" / "formats.rst"
BEGIN, END = ".. schema tables: begin", ".. schema tables: end"


def _manifest(path: Path):
    return read_manifest(path.parent)


#: document -> (reader, file name, error class, a file missing a required key and that
#: key, a file with a wrongly typed value and that key). Each file starts with its
#: format line, so an unknown key can be added on the second line.
CASES = {
    "sweep manifest": (
        load_sweep, "sweep.toml", InputError,
        'format = "scanqa-sweep/1"\n[[position]]\nphase = "a.npz"\n', "z_mm",
        'format = "scanqa-sweep/1"\n[[position]]\nz_mm = "430"\n', "z_mm"),
    "experiment manifest": (
        _manifest, "manifest.toml", InputError,
        'format = "scanqa-simulation/1"\n', "acquisition",
        'format = "scanqa-simulation/1"\nworking_period_px = "5"\n', "working_period_px"),
    "pattern description": (
        read_patterns_file, "patterns.toml", ConfigError,
        'format = "scanqa-patterns/2"\n[[set]]\nkind = "phase"\n', "projector_width_px",
        'format = "scanqa-patterns/2"\nprojector_width_px = "640"\n', "projector_width_px"),
    "artefact layout": (
        read_artefact_layout, "artefacts.toml", InputError,
        'format = "scanqa-artefact-layout/1"\n[[sphere]]\nid = "S1"\n', "diameter_mm",
        'format = "scanqa-artefact-layout/1"\n[[sphere]]\nid = "S1"\ndiameter_mm = "12"\n',
        "diameter_mm"),
    "batch manifest": (
        read_batch_manifest, "batch.toml", InputError,
        'format = "scanqa-batch/1"\n[[scan]]\nname = "a"\n', "path",
        'format = "scanqa-batch/1"\n[[scan]]\npath = 3\n', "path"),
    "campaign": (
        read_campaign, "campaign.toml", InputError,
        'format = "scanqa-campaign/1"\nseed = 1\n', "run",
        'format = "scanqa-campaign/1"\nseed = "1"\n', "seed"),
    "uncertainty budget": (
        read_budget_file, "budget.toml", InputError,
        'format = "scanqa-budget/1"\n[coverage]\n', "k",
        'format = "scanqa-budget/1"\n[stage]\nscale_uncertainty_ppm = "20"\n',
        "scale_uncertainty_ppm"),
    "gauge-block layout": (
        read_layout_file, "layout.toml", InputError,
        'format = "scanqa-gauge-layout/1"\nname = "x"\n', "block",
        'format = "scanqa-gauge-layout/1"\nbase_z_mm = "430"\n', "base_z_mm"),
    "projector response": (
        read_response_file, "response.toml", ConfigError,
        'format = "scanqa-response/1"\n[[set]]\nperiod_px = 5.0\n', "steps",
        'format = "scanqa-response/1"\ndescription = 3\n', "description"),
    "design spec": (
        read_design_spec, "design.toml", InputError,
        'format = "scanqa-design-spec/1"\nsigma_max_um = 3.0\n[limits]\n', "cover",
        'format = "scanqa-design-spec/1"\nsigma_max_um = 3.0\n[cover]\n'
        'min_mm = [0.0, 0.0, 1.0]\nmax_mm = [1.0, 1.0]\n', "max_mm"),
    "acceptance spec": (
        read_spec, "spec.toml", InputError,
        'format = "scanqa-spec/1"\nmpe_pf_um = 1.0\n[flat]\n', "flatness_um",
        'format = "scanqa-spec/1"\nmpe_pf_um = "15"\n', "mpe_pf_um"),
}


def _import_io() -> None:
    for mod in pkgutil.iter_modules(scanqa.io.__path__):
        importlib.import_module(f"scanqa.io.{mod.name}")


def test_the_registry_names_every_toml_document():
    """Ten io modules declare eleven documents (batchfiles holds the batch manifest and
    the campaign); the scanner config is declared by its dataclasses (model/config.py)."""
    _import_io()
    assert sorted(schema.SCHEMAS) == sorted(CASES)
    assert len(schema.SCHEMAS) == 11
    owners = {s.document: s for s in schema.SCHEMAS.values()}
    assert all(owners[d].formats for d in CASES)  # every document has a format key


def _error(tmp_path, document: str, text: str) -> ScanQAError:
    reader, name, error = CASES[document][:3]
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(error) as info:
        reader(path)
    message = str(info.value)
    assert name in message, message  # the file
    assert "\n" not in message and "Traceback" not in message
    return info.value


@pytest.mark.parametrize("document", sorted(CASES))
def test_a_missing_required_key_is_one_error_naming_file_and_key(tmp_path, document):
    text, key = CASES[document][3:5]
    message = str(_error(tmp_path, document, text))
    assert re.search(rf"\b{key} is missing \(", message), message


@pytest.mark.parametrize("document", sorted(CASES))
def test_an_unknown_key_is_one_error_naming_file_and_key(tmp_path, document):
    text = CASES[document][3]
    first, rest = text.split("\n", 1)
    message = str(_error(tmp_path, document, f"{first}\ncolour_mm = 1\n{rest}"))
    assert "unknown key 'colour_mm' (known: format, " in message, message


@pytest.mark.parametrize("document", sorted(CASES))
def test_a_wrongly_typed_value_is_one_error_naming_file_key_and_type(tmp_path, document):
    text, key = CASES[document][5:7]
    message = str(_error(tmp_path, document, text))
    field = re.search(rf"\b{key} must be (.*), got ", message)
    assert field is not None, message
    declared = _find_field(schema.SCHEMAS[document], key)
    assert field.group(1).startswith(declared.expected()), message


def _find_field(sch: schema.Schema, name: str) -> schema.Field:
    for f in sch.fields:
        if f.name == name:
            return f
        if f.table is not None:
            try:
                return _find_field(f.table, name)
            except KeyError:
                pass
    raise KeyError(name)


@pytest.mark.parametrize("document", sorted(CASES))
def test_each_reader_validates_through_its_declared_schema(tmp_path, monkeypatch, document):
    """The reader calls the declared schema's validate (spied), whatever it then does."""
    seen = []
    original = schema.Schema.validate

    def spy(self, data, path, error=InputError):
        seen.append(self.document)
        return original(self, data, path, error)

    monkeypatch.setattr(schema.Schema, "validate", spy)
    reader, name = CASES[document][:2]
    path = tmp_path / name
    path.write_text(CASES[document][5])
    with pytest.raises(ScanQAError):
        reader(path)
    assert seen[:1] == [document]


def _calls(func: ast.AST) -> set[str]:
    return {ast.unparse(n.func).rsplit(".", 1)[-1] for n in ast.walk(func)
            if isinstance(n, ast.Call)}


#: io functions that parse TOML without validating a document: the parser itself, and
#: a sniffer that reads only ``format`` to choose between the two layout readers.
NOT_READERS = {("tomlfile.py", "read_toml"), ("artefacts.py", "layout_format")}


def test_every_io_function_that_parses_toml_validates_a_schema():
    found = []
    for path in sorted(IO.glob("*.py")):
        for node in nodes(path, ast.FunctionDef):  # parsed once per process
            if {"read_toml", "loads_toml"} & _calls(node):
                if (path.name, node.name) not in NOT_READERS:
                    found.append((path.name, node.name, "validate" in _calls(node)))
    assert len({f for f, _, _ in found}) == 10  # the ten document modules
    assert [f for f in found if not f[2]] == []


def test_an_open_table_checks_the_value_of_every_key(tmp_path):
    """[limits] of a design spec takes any setting name, each a [low, high] pair."""
    path = tmp_path / "design.toml"
    path.write_text('format = "scanqa-design-spec/1"\nsigma_max_um = 3.0\n[cover]\n'
                    "min_mm = [0.0, 0.0, 1.0]\nmax_mm = [1.0, 1.0, 2.0]\n[limits]\n"
                    "angle_deg = [8.0, 20.0, 30.0]\n")
    with pytest.raises(InputError, match=r"design\.toml: limits\.angle_deg must be a list "
                                         r"of 2 finite numbers \(\[low, high\]"):
        read_design_spec(path)
    for spec in sorted((ROOT / "benchmarks" / "design_specs").glob("*.toml")):
        assert read_design_spec(spec)["limits"]


def test_the_decoder_reads_no_pattern_key_the_schema_does_not_declare():
    """decoding.parsing keeps which set kind (and version) takes which key; every such key
    is declared in io.patterns.SCHEMA, and its top-level keys are the declared ones."""
    from scanqa.decoding.parsing import _SET_KEYS, _TOP_KEYS
    from scanqa.io.patterns import SCHEMA

    declared = {f.name for f in SCHEMA.field("set").table.fields}
    used = {k for kinds in _SET_KEYS.values() for keys in kinds.values() for k in keys}
    assert used == declared
    assert set(_TOP_KEYS["scanqa-patterns/2"]) == {f.name for f in SCHEMA.fields}


def test_io_schema_imports_nothing_of_scanqa_but_errors():
    tree = ast.parse((IO / "schema.py").read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert {m for m in imported if m and m.startswith("scanqa")} == {"scanqa.errors"}


def test_a_declared_limit_and_a_nested_entry_are_named():
    """Messages come from the declaration: the limit, the unit, the entry's name."""
    sch = schema.Schema("t", (
        schema.Field("format", "string", required=True),
        schema.Field("item", "tables", table=schema.Schema("[[item]]", (
            schema.Field("id", "string", required=True),
            schema.Field("size_mm", "number", "mm", check=schema.greater(0), doc="its size"),
        ), name_key="id")),
    ), formats=("t/1",))
    good = {"format": "t/1", "item": [{"id": "a", "size_mm": 2}]}
    assert sch.validate(good, "f.toml") is good
    bad = {"format": "t/1", "item": [{"id": "a", "size_mm": 2}, {"id": "b", "size_mm": 0}]}
    with pytest.raises(InputError, match=re.escape(
            "f.toml: [[item]] 2 ('b'): size_mm must be a finite number > 0 [mm] (its size), "
            "got 0")):
        sch.validate(bad, "f.toml")
    with pytest.raises(InputError, match=r"f\.toml: format must be 't/1' \(the t format\)"):
        sch.validate({"format": "t/2"}, "f.toml")
    with pytest.raises(InputError, match="size_mm must be a finite number"):
        sch.validate({"format": "t/1", "item": [{"id": "a", "size_mm": float("nan")}]}, "f")


# ------------------------------------------------------------------------------ docs


def schema_docs() -> str:
    """The schema tables of docs/formats.rst, generated from the declarations."""
    _import_io()
    parts = [BEGIN, ""]
    for name in sorted(schema.SCHEMAS):
        parts += [schema.rst_table(schema.SCHEMAS[name]), ""]
    return "\n".join([*parts, END])


def config_docs() -> str:
    """The scanner config's table (its [simulator] keys are docs/simulator.rst's)."""
    sim = CONFIG.field("simulator")
    top = replace(CONFIG, fields=tuple(replace(f, table=None) if f is sim else f
                                       for f in CONFIG.fields))
    return "\n".join([".. config table: begin", "", schema.rst_table(top),
                      ".. config table: end"])


def simulator_docs() -> str:
    """The [simulator] keys' table of docs/simulator.rst."""
    return "\n".join([".. simulator table: begin", "",
                      schema.rst_table(CONFIG.field("simulator").table),
                      ".. simulator table: end"])


#: The generated blocks of the docs: (file, the block's text), the block from the first
#: line of its text to its last.
BLOCKS = ((FORMATS_RST, config_docs), (FORMATS_RST, schema_docs),
          (ROOT / "docs" / "simulator.rst", simulator_docs))


@pytest.mark.parametrize("path, block", BLOCKS, ids=lambda x: getattr(x, "__name__", ""))
def test_the_docs_show_every_declared_schema(path, block):
    want = block()
    begin, end = want.split("\n")[0], want.split("\n")[-1]
    text = path.read_text()
    assert begin in text and end in text, "run python tests/test_io_schema.py"
    assert text[text.index(begin):text.index(end) + len(end)] == want, \
        f"{path.name} is stale: run python tests/test_io_schema.py to regenerate its tables"


if __name__ == "__main__":  # rewrite the generated blocks of the docs
    sys.path.insert(0, str(ROOT / "src"))
    for path, block in BLOCKS:
        want = block()
        begin, end = want.split("\n")[0], want.split("\n")[-1]
        text = path.read_text()
        text = text[:text.index(begin)] + want + text[text.index(end) + len(end):]
        path.write_text(text)
