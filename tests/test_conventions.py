"""The written conventions (docs/STYLE, issue 28) as tests, read from the source itself:
one ISO 14253-1 decision and one noise-correlation factor in the code, frozen QA results,
library errors free of command-line flags, report modules free of statistics."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
from pathlib import Path

import pytest

import scanqa.qa.results as results

SRC = Path(__file__).resolve().parents[1] / "src" / "scanqa"


def _functions():
    """(module path relative to src/scanqa, function node) of every function in src."""
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                yield path.relative_to(SRC).as_posix(), node


def _is_abs(node) -> bool:
    return isinstance(node, ast.Call) and ast.unparse(node.func) in ("abs", "np.abs")


def _writes_the_decision(func) -> bool:
    """|E| <= T - U and |E| > T + U in one function: the ISO 14253-1 rule written out."""
    ops = set()
    for node in ast.walk(func):
        if isinstance(node, ast.Compare) and _is_abs(node.left) and len(node.ops) == 1:
            right = node.comparators[0]
            if isinstance(right, ast.BinOp):
                ops.add((type(node.ops[0]), type(right.op)))
    return {(ast.LtE, ast.Sub), (ast.Gt, ast.Add)} <= ops


def _writes_the_sandwich(func) -> bool:
    """A clustered sandwich: per-cluster sums (bincount with weights) and B @ M @ B."""
    text = ast.unparse(func)
    clusters = "bincount(" in text and "weights=" in text
    sandwich = re.search(r"\b(\w+) @ \w+ @ \1\b", text)
    return clusters and sandwich is not None


def test_one_decision_and_one_correlation_factor_in_the_code():
    found = [(m, f.name) for m, f in _functions() if _writes_the_decision(f)]
    assert found == [("qa/verdict.py", "decide")]
    found = [(m, f.name) for m, f in _functions() if _writes_the_sandwich(f)]
    assert found == [("qa/correlation.py", "noise_correlation")]


def test_the_finders_see_the_rule_written_out():
    """The finders above are not blind: a second copy of either rule is found."""
    copy = ast.parse("def d(e, u, t):\n    if abs(e) <= t - u: return 1\n"
                     "    return abs(e) > t + u\n").body[0]
    assert _writes_the_decision(copy)
    copy = ast.parse("def k(a, r, c):\n    s = np.bincount(c, weights=a * r)\n"
                     "    return bread @ meat @ bread\n").body[0]
    assert _writes_the_sandwich(copy)


@pytest.mark.parametrize("name", [n for n, c in inspect.getmembers(results, inspect.isclass)
                                  if dataclasses.is_dataclass(c)
                                  and c.__module__ == results.__name__])
def test_qa_results_are_frozen(name):
    cls = getattr(results, name)
    assert cls.__dataclass_params__.frozen, f"{name} is a mutable dataclass"


def test_every_result_dataclass_of_qa_is_frozen():
    """Every dataclass declared in qa/ is frozen (results, fits, specs alike)."""
    mutable = []
    for path in sorted((SRC / "qa").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                for dec in node.decorator_list:
                    text = ast.unparse(dec)
                    if "dataclass" in text and "frozen=True" not in text:
                        mutable.append(f"{path.name}:{node.name}")
    assert mutable == []


#: Library errors that still name a command-line flag (issue 28 item 2: move the hint to
#: the CLI layer, then take the module off this list). Shrinks, never grows.
FLAG_ERRORS_LEFT = {
    "calibration/parametric_checks.py": 1, "cluster.py": 2, "decoding/describe.py": 1,
    "decoding/projection.py": 1, "decoding/response.py": 1, "io/sweep.py": 1,
    "model/characterization.py": 2, "report/pdf.py": 1, "runs/boardnoise.py": 1,
    "runs/demo.py": 1, "runs/onboarding.py": 1,
}


def test_library_errors_name_no_command_line_flag():
    """No "--flag" in an exception raised outside cli/ (the CLI adds its flags)."""
    found: dict[str, int] = {}
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel.startswith("cli/"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None and re.search(
                    r"(?<![\w-])--[a-z]", ast.unparse(node.exc)):
                found[rel] = found.get(rel, 0) + 1
    assert not any(m.startswith("qa/") for m in found), found
    assert found == FLAG_ERRORS_LEFT


#: numpy reductions (statistics) a report module must not compute.
REDUCTIONS = re.compile(r"\bnp\.(nan)?(mean|median|std|var|percentile|quantile|sum|average|"
                        r"histogram|corrcoef|polyfit)\(")
#: Report modules that still compute a statistic (issue 28 item 2: the colour-scale
#: limits of residual maps and two calibration summary numbers). Shrinks, never grows.
STATISTICS_LEFT = {"report/artefacts.py": 1, "report/calibration.py": 2,
                   "report/compare.py": 1, "report/qa.py": 1}


def test_report_modules_compute_no_statistics():
    found = {}
    for path in sorted((SRC / "report").glob("*.py")):
        n = len(REDUCTIONS.findall(path.read_text()))
        if n:
            found[path.relative_to(SRC).as_posix()] = n
    assert found == STATISTICS_LEFT
