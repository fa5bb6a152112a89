"""The written conventions (docs/STYLE, issue 28) as tests, read from the source itself:
one ISO 14253-1 decision and one noise-correlation factor in the code, frozen QA results,
library errors free of command-line flags, report modules free of statistics."""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import re

import pytest

import scanqa.qa.results as results
from tests.source_index import SRC, index, may_hold, modules, nodes, parsed, rel, text

_FUNCTIONS = ast.FunctionDef | ast.AsyncFunctionDef


def _functions(path=None):
    """(module path relative to src/scanqa, function node) of every function in src (or
    in the module at ``path``)."""
    for p in modules() if path is None else (path,):
        for node in nodes(p, _FUNCTIONS):
            yield rel(p), node


def _is_abs(node) -> bool:
    return isinstance(node, ast.Call) and ast.unparse(node.func) in ("abs", "np.abs")


_DECISION = {(ast.LtE, ast.Sub), (ast.Gt, ast.Add)}


def _decision_ops(compares) -> set:
    """(comparison, operation) of each ``abs(e) <op> a <op> b`` among ``compares``."""
    ops = set()
    for node in compares:
        if isinstance(node, ast.Compare) and _is_abs(node.left) and len(node.ops) == 1:
            right = node.comparators[0]
            if isinstance(right, ast.BinOp):
                ops.add((type(node.ops[0]), type(right.op)))
    return ops


def _writes_the_decision(func) -> bool:
    """|E| <= T - U and |E| > T + U in one function: the ISO 14253-1 rule written out."""
    return _DECISION <= _decision_ops(ast.walk(func))


def _writes_the_sandwich(func) -> bool:
    """A clustered sandwich: per-cluster sums (bincount with weights) and B @ M @ B."""
    text = ast.unparse(func)
    clusters = "bincount(" in text and "weights=" in text
    sandwich = re.search(r"\b(\w+) @ \w+ @ \1\b", text)
    return clusters and sandwich is not None


def test_one_decision_and_one_correlation_factor_in_the_code():
    # a function of a module can only write the decision if the module's comparisons
    # hold both halves, and the sandwich if its text holds "bincount" and "@" (the
    # unparsed function is made of the module's own words and operators): the
    # functions of the other modules are not looked at one by one
    found = [(m, f.name) for p in modules() if _DECISION <= _decision_ops(
        nodes(p, ast.Compare)) for m, f in _functions(p) if _writes_the_decision(f)]
    assert found == [("qa/verdict.py", "decide")]
    found = [(m, f.name) for p in modules()
             if all(w in text(p) for w in ("bincount", "weights", "@"))
             for m, f in _functions(p) if _writes_the_sandwich(f)]
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
        for node in nodes(path, ast.ClassDef):
            for dec in node.decorator_list:
                code = ast.unparse(dec)
                if "dataclass" in code and "frozen=True" not in code:
                    mutable.append(f"{path.name}:{node.name}")
    assert mutable == []


def test_library_errors_name_no_command_line_flag():
    """No "--flag" in an exception raised outside cli/ (the CLI adds its flags)."""
    found: dict[str, int] = {}
    for path in modules():
        name = rel(path)
        if name.startswith("cli/"):
            continue
        for node in nodes(path, ast.Raise):
            if node.exc is not None and re.search(r"(?<![\w-])--[a-z]", ast.unparse(node.exc)):
                found[name] = found.get(name, 0) + 1
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


@functools.cache
def _dataclasses_outside_qa() -> tuple[tuple[str, str, bool], ...]:
    """(module, class, frozen) of every dataclass declared outside qa/ (read once for the
    tests below)."""
    found = []
    for path in modules():
        name = rel(path)
        if name.startswith("qa/"):
            continue
        for node in nodes(path, ast.ClassDef):
            for dec in node.decorator_list:
                code = ast.unparse(dec)
                if "dataclass" in code:
                    found.append((name, node.name, "frozen=True" in code))
    return tuple(found)


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


# ------------------------------------------------- one way to do each thing (issue 47)

#: The one home of the robust spread, the START:STOP:STEP range and the JSON cleaning.
NUMERIC = "numeric.py"


def _sources():
    """(module path relative to src/scanqa, parsed tree) of every module but the home."""
    for path in modules():
        if rel(path) != NUMERIC:
            yield rel(path), parsed(path)


#: 1.4826 MAD written out: median(abs(x - median(x))).
_MAD = re.compile(r"median\(np\.abs\((\w+) - np\.(nan)?median\(\1\)")


def _robust_stds(tree) -> list[int]:
    """Lines that write the robust spread again: the constant 1.4826 (or its inverse
    0.6745) or a median absolute deviation."""
    lines = [n.lineno for n in index(tree).of(ast.Constant)
             if isinstance(n.value, float) and round(n.value, 4) in (1.4826, 0.6745)]
    return lines + [n.lineno for n in index(tree).of(ast.Call)
                    if may_hold(tree, n, ("median", "abs")) and _MAD.search(ast.unparse(n))]


def _json_cleanings(tree) -> list[int]:
    """Lines that turn a non-finite number into None (JSON null) themselves: ``x if
    isfinite(x) else None``, or a type test with isfinite that returns None."""
    found = []
    for n in index(tree).of(ast.IfExp, ast.If):
        test = ast.unparse(n.test)
        if isinstance(n, ast.IfExp) and isinstance(n.orelse, ast.Constant) \
                and n.orelse.value is None:
            found += [n.lineno for c in ast.walk(n.test) if isinstance(c, ast.Call)
                      and ast.unparse(c.func).endswith("isfinite") and c.args
                      and ast.unparse(c.args[0]) in ast.unparse(n.body)]
        elif isinstance(n, ast.If) and "isfinite" in test and "isinstance" in test \
                and any(isinstance(b, ast.Return) and isinstance(b.value, ast.Constant)
                        and b.value.value is None for b in n.body):
            found.append(n.lineno)
    return found


#: A START:STOP:STEP text split into numbers, or the count of an inclusive range.
_RANGE = re.compile(r"float\(\w+\) for \w+ in \w+\.split\(['\"]:['\"]\)|"
                    r"\(\w+ - \w+\) / \w+ \+ 1e-0?9")


def _range_parsers(tree) -> list[int]:
    # the first form needs "float" and "split" in the statement's lines, the second a
    # subtraction, a division and an addition
    return sorted({n.lineno for n in index(tree).of(ast.stmt)
                   if not isinstance(n, ast.FunctionDef | ast.ClassDef | ast.If | ast.For
                                     | ast.While | ast.With | ast.Try)
                   and (may_hold(tree, n, ("float", "split"))
                        or may_hold(tree, n, ("-", "/", "+")))
                   and _RANGE.search(ast.unparse(n))})


@pytest.mark.parametrize("finder", [_robust_stds, _json_cleanings, _range_parsers])
def test_one_robust_std_json_cleaning_and_range_parser(finder):
    """scanqa.numeric's robust_std, json_ready and inclusive_range / parse_range are the
    only ones: a second copy elsewhere in src fails here."""
    found = {name: lines for name, tree in _sources() if (lines := finder(tree))}
    assert found == {}


def test_the_one_way_finders_are_not_blind():
    """Each finder sees the copies it replaced, and the home module itself."""
    assert _robust_stds(ast.parse("s = 1.4826 * float(np.median(np.abs(z)))"))
    assert _robust_stds(ast.parse("s = k * np.median(np.abs(r - np.median(r)))"))
    assert _json_cleanings(ast.parse("x = v if np.isfinite(v) else None"))
    assert _json_cleanings(ast.parse(
        "def c(v):\n    if isinstance(v, float) and not math.isfinite(v):\n"
        "        return None\n    return v\n"))
    assert _range_parsers(ast.parse("a, b, c = (float(t) for t in text.split(':'))"))
    assert _range_parsers(ast.parse("n = int(np.floor((stop - start) / step + 1e-9)) + 1"))
    home = ast.parse((SRC / NUMERIC).read_text())
    assert _robust_stds(home) and _json_cleanings(home) and _range_parsers(home)


def test_benchmarks_hold_speed_and_memory_benchmarks_only():
    """One-off studies live in docs/studies/ beside the pages that keep their numbers
    (docs/studies.rst); benchmarks/ holds what ``make bench`` times, and no test imports
    a study."""
    root = SRC.parents[1]
    others = [p.name for p in sorted((root / "benchmarks").glob("*.py"))
              if not re.fullmatch(r"(bench_\w+|profile_\w+|run_all)\.py", p.name)]
    assert others == []
    studies = {p.stem for p in (root / "docs" / "studies").glob("*.py")}
    # a file that names no study anywhere in its text imports none (not parsed)
    importing = [p.name for p in sorted((root / "tests").glob("*.py"))
                 if any(stem in text(p) for stem in studies)
                 and any(studies & {*(a.name.split(".")[-1] for a in n.names),
                                    *(str(getattr(n, "module", "") or "").split("."))}
                         for n in nodes(p, ast.Import, ast.ImportFrom))]
    assert importing == []


# ------------------------------------------ one field-declaration system (issue 47)

#: The one home of field declarations: a key's name, type, unit, limits, default and
#: meaning are one :class:`scanqa.io.schema.Field` (the scanner config's too).
SCHEMA_HOME = "io/schema.py"
#: Names of a limit (as parameters, record fields or dict keys) and what a unit looks like.
_LIMITS = {"gt", "ge", "lt", "le", "low", "high", "lower", "upper", "min", "max"}
_UNIT = re.compile(r"(mm|um|nm|px|deg|rad|bit|e-|e-/DN|DN|DN\^2|ms|s|-|%|ppm)")

#: Declarations outside the home that remain, each with the reason. Shrinks, never grows.
OTHER_DECLARATIONS = {
    "cli/common.py:number": "an argparse type: one flag's bound, given where the flag is "
                            "declared; no table of keys",
}


def _number(node) -> bool:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        node = node.operand
    return isinstance(node, ast.Constant) and type(node.value) in (int, float)


def _row(node) -> bool:
    """A row of a declaration table: a tuple or a call giving a unit and two numbers."""
    items = (node.elts if isinstance(node, ast.Tuple) else [
        *node.args, *(k.value for k in node.keywords)] if isinstance(node, ast.Call) else [])
    unit = any(isinstance(i, ast.Constant) and isinstance(i.value, str)
               and _UNIT.fullmatch(i.value) for i in items)
    return unit and sum(map(_number, items)) >= 2


def _declares(node) -> bool:
    """A record type (class) or a helper (function) taking a unit and a limit, a dict
    with a unit and a limit as keys, or a table (dict, tuple or list) of >= 3 rows."""
    if isinstance(node, ast.ClassDef):
        names = {s.target.id for s in node.body
                 if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
    elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
        names = {a.arg for a in (*node.args.args, *node.args.kwonlyargs)}
    elif isinstance(node, ast.Dict):
        names = {k.value for k in node.keys if isinstance(k, ast.Constant)}
    else:
        names = set()
    rows = (node.values if isinstance(node, ast.Dict)
            else node.elts if isinstance(node, ast.Tuple | ast.List) else [])
    return ("unit" in names and bool(names & _LIMITS)) or sum(map(_row, rows)) >= 3


def _field_declarations(tree) -> list[str]:
    """Names of the top-level statements of a module that declare fields by a system of
    their own (:func:`_declares` anywhere inside them)."""
    tops = index(tree)
    declaring = {id(tops.top(n)) for n in tops.of(ast.ClassDef, _FUNCTIONS, ast.Dict,
                                                   ast.Tuple, ast.List) if _declares(n)}
    found = []
    for stmt in tree.body:  # the other nodes declare nothing (_declares)
        name = getattr(stmt, "name", None) or ast.unparse(
            getattr(stmt, "target", None) or (getattr(stmt, "targets", None) or [stmt])[0])
        if id(stmt) in declaring:
            found.append(name)
    return found


def test_one_field_declaration_system():
    """Keys with a unit and limits are declared as io.schema.Field records only: a second
    system (a spec helper, a metadata dict, a table of (name, unit, low, high)) fails."""
    found = {f"{rel(path)}:{name}" for path in modules() if rel(path) != SCHEMA_HOME
             for name in _field_declarations(parsed(path))}
    assert found == set(OTHER_DECLARATIONS)


def test_the_declaration_finder_is_not_blind():
    """It sees the scanner config's former system (a _spec helper filling a metadata dict
    of unit and bounds), a record type and a table of (unit, low, high) rows."""
    old = ast.parse(
        "def _spec(unit='', gt=None, ge=None, le=None, kind='float', default=dataclass):\n"
        "    meta = {'unit': unit, 'gt': gt, 'ge': ge, 'le': le, 'kind': kind}\n"
        "    return field(metadata=meta)\n"
        "class CameraConfig(_Section):\n"
        "    focal_mm: float = _spec('mm', ge=0.5, le=5000)\n")
    assert _field_declarations(old) == ["_spec"]
    assert _field_declarations(ast.parse("class S:\n    unit: str\n    low: float\n"))
    assert _field_declarations(ast.parse(
        "T = {'a_mm': ('mm', 0, 1), 'b_deg': ('deg', -5, 5), 'c': ('-', 0.1, 2.0)}"))
    assert not _field_declarations(ast.parse(
        "x: float = _spec('number', 'mm', within(0.5, 5000), 'focal length', 3)"))
