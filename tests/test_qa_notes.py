"""pvlib's habit: every public numeric function of scanqa.qa states its formula and source.

The test walks src/scanqa/qa/ with ``ast``, takes every public module-level function,
and asserts that its docstring has a numpydoc "Notes" section that names where the
formula comes from: the paper's equation or section, a GUM clause, ISO 14253-1,
VDI/VDE 2634-2, another named standard or paper in its References, or the docs page
holding scanqa's own derivation. Functions that compute no number are listed below,
each with the reason.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

QA = Path(__file__).resolve().parents[1] / "src" / "scanqa" / "qa"

#: Public functions of qa/ that compute no number: readers, checks, text and plumbing.
NOT_NUMERIC = {
    "artefacts.load_artefact_layout": "reads a layout file",
    "artefacts.auto_layout": "builds a layout from the spec's nominal values",
    "blocks.check_sigmas": "refuses bad sigmas, returns nothing",
    "blocks.refuse_bad_sigmas": "refuses bad sigmas, returns nothing",
    "blocks.cloud_config": "chooses a config",
    "blocks.coverage_notes": "writes text",
    "budget.load_budget": "reads a budget file",
    "layout.load_layout": "reads a layout file",
    "sphere.check_points": "checks an array",
    "verdict.verdict": "counts decisions",
    "paper.table3_rows": "joins rows by block number",
    "ransac.check_positive": "refuses a bad length, returns nothing",
    "align.parse_region": "reads a region's text",
    "blocks.unmeasured_step": "records a step that was not evaluated (NaN numbers)",
}
#: What counts as naming a source in a Notes section.
SOURCE = re.compile(
    r"Eqs?\. ?\(?[A-Z]?\d|Sect\. \d|GUM|JCGM|ISO 14253-1|VDI/VDE 2634|ISO 10360|ISO 12781"
    r"|\[\d+\]_|docs/[a-z_]+\.rst|Table \d|\(\d{4}\)")


def _notes(doc: str) -> str:
    """The text of the numpydoc Notes section ('' without one)."""
    m = re.search(r"^\s*Notes\n\s*-----\n(.*?)(?=^\s*[A-Z][a-z]+\n\s*-{3,}\n|\Z)", doc,
                  re.S | re.M)
    return m.group(1) if m else ""


def _public_functions() -> list[tuple[str, str]]:
    out = []
    for path in sorted(QA.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
                out.append((f"{path.stem}.{node.name}", ast.get_docstring(node) or ""))
    return out


FUNCTIONS = _public_functions()
NUMERIC = [(name, doc) for name, doc in FUNCTIONS if name not in NOT_NUMERIC]


def test_the_walk_finds_the_qa_functions():
    names = {name for name, _ in FUNCTIONS}
    assert len(NUMERIC) >= 40
    assert {"verdict.decide", "budget.welch_satterthwaite", "vdi2634.probing_errors",
            "sphere.fit_sphere", "correlation.noise_correlation"} <= names
    assert set(NOT_NUMERIC) <= names, set(NOT_NUMERIC) - names


@pytest.mark.parametrize("name, doc", NUMERIC, ids=[n for n, _ in NUMERIC])
def test_numeric_function_has_notes_with_formula_and_source(name, doc):
    notes = _notes(doc)
    assert notes.strip(), f"{name}: no Notes section"
    assert SOURCE.search(notes), f"{name}: its Notes name no source"


def test_the_notes_parser_reads_numpydoc():
    doc = "Summary.\n\nNotes\n-----\nF = a / b (Eq. 17 in [1]_).\n\nReferences\n----------\n"
    assert _notes(doc).strip() == "F = a / b (Eq. 17 in [1]_)."
    assert _notes("Summary.\n\nReturns\n-------\nfloat\n") == ""
    assert not SOURCE.search("the mean of the points")
