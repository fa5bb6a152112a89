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
    assert found == {}


def test_the_cli_names_the_flag_the_library_leaves_out():
    """cli.common.flags re-raises a library error with the parameter as its flag, same
    type, and leaves an error it has no words for untouched."""
    from scanqa.cli.common import flags
    from scanqa.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^x: check --pitch-um$"):
        with flags({"check pitch_um": "check --pitch-um"}):
            raise ConfigError("x: check pitch_um")
    original = ConfigError("x: check focus_mm")
    with pytest.raises(ConfigError) as info:
        with flags({"check pitch_um": "check --pitch-um"}):
            raise original
    assert info.value is original


#: numpy reductions (statistics) a report module must not compute.
REDUCTIONS = re.compile(r"\bnp\.(nan)?(mean|median|std|var|percentile|quantile|sum|average|"
                        r"histogram|corrcoef|polyfit)\(")
def test_report_modules_compute_no_statistics():
    found = {}
    for path in sorted((SRC / "report").glob("*.py")):
        n = len(REDUCTIONS.findall(path.read_text()))
        if n:
            found[path.relative_to(SRC).as_posix()] = n
    assert found == {}


def test_the_statistics_finder_is_not_blind():
    assert REDUCTIONS.findall("lim = float(np.percentile(np.abs(res), 99.5))")
    assert REDUCTIONS.findall("m = np.nanmedian(sig)")


def _dataclasses_outside_qa():
    """(module, class, frozen) of every dataclass declared outside qa/."""
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel.startswith("qa/"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                for dec in node.decorator_list:
                    text = ast.unparse(dec)
                    if "dataclass" in text:
                        yield rel, node.name, "frozen=True" in text


#: Dataclasses outside qa/ left mutable, each because something changes it after
#: construction (issue 28). Shrinks, never grows.
MUTABLE_BY_DESIGN = {
    "calibration/build.py:BuildReport": "counts added position by position during a build",
    "cluster.py:EngineReport": "seconds and worker peaks set when the run ends",
    "description/inference.py:_Group": "questions appended while the frames are read",
    "decoding/unwrap.py:ChainStats": "merge() and per-step counts accumulate into it",
    "decoding/unwrap.py:_Flags": "mask bits or-ed in place (flags.low |= ...) per stage",
    "io/ply.py:_Element": "properties appended as the PLY header is parsed",
    "design/optimisation.py:Evaluator": "a memo cache and a call counter",
}


def test_dataclasses_outside_qa_are_frozen_unless_mutated_by_design():
    mutable = {f"{m}:{c}" for m, c, frozen in _dataclasses_outside_qa() if not frozen}
    assert mutable == set(MUTABLE_BY_DESIGN)


@pytest.mark.parametrize("name", ["calibration/build.py:_CellStats",
                                  "decoding/decoder.py:_Run", "runs/batch.py:BatchResult",
                                  "runs/demo.py:DemoResult", "io/sweep.py:Sweep",
                                  "io/schema.py:Field", "io/schema.py:Schema"])
def test_results_outside_qa_are_frozen(name):
    frozen = {f"{m}:{c}": f for m, c, f in _dataclasses_outside_qa()}
    assert frozen[name], f"{name} is a mutable dataclass"
