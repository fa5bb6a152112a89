"""The package's layers, read from the source with ``ast``: no import cycle, and no import
from a lower layer to a higher one (docs/development.rst draws the layers)."""

from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import pytest

from tests.source_index import nodes

SRC = Path(__file__).resolve().parents[1] / "src" / "scanqa"

#: Layer of every module or subpackage, lowest first: one entry per room (a folder of
#: the package, or a module of its own). A module may import from its own layer or lower
#: ones. Longest prefix wins. The rooms follow the pipeline - io, decoding, the model,
#: calibration, annotation, qa, report - with description, design and characterization
#: beside it; qa stands below annotation because it reads any annotated cloud
#: (io.annotated_cloud), not annotation's code. Rooms are nouns: scanqa.annotate,
#: scanqa.characterize and scanqa.describe are the public API's functions.
LAYERS = {
    "scanqa.errors": 0, "scanqa.chunks": 0, "scanqa.compiled": 0, "scanqa.progress": 0,
    "scanqa._version": 0, "scanqa.numeric": 0,
    "scanqa.io": 1,
    "scanqa.decoding": 2, "scanqa.decoding.phasekernel": 2, "scanqa.model": 2,
    "scanqa.provenance": 2,
    "scanqa.description": 3, "scanqa.calibration": 3, "scanqa.design": 3,
    "scanqa.characterization": 4, "scanqa.qa": 4, "scanqa.simulator": 4,
    "scanqa.simulator.boardfringes": 4,  # board poses under fringes, for the board path
    "scanqa.simulator.boardkernels": 4,  # the board renderers' compiled loops
    "scanqa.annotation": 5,
    "scanqa.report": 6,
    "scanqa.runs": 7, "scanqa.cluster": 7, "scanqa.api": 7, "scanqa": 7,
    "scanqa.cli": 8, "scanqa.__main__": 8,
}


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(name: str) -> int:
    best = max((p for p in LAYERS if name == p or name.startswith(p + ".")), key=len)
    return LAYERS[best]


def imports(path: Path) -> list[tuple[str, int, tuple[str, ...]]]:
    """(imported scanqa module, line, names) of every import statement, nested ones too."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rsplit(".", 1)[0]
    out = []
    for node in nodes(path, ast.Import, ast.ImportFrom):  # parsed once per process
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno, ()) for a in node.names if a.name.startswith("scanqa")]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[:len(package.split(".")) - node.level + 1]
                                + ([base] if base else []))
            if base.startswith("scanqa"):
                names = tuple(a.name for a in node.names)
                # "from scanqa.x import y" may import the submodule scanqa.x.y
                subs = [f"{base}.{n}" for n in names if (SRC.parent / f"{base}.{n}".replace(
                    ".", "/")).with_suffix(".py").exists() or (SRC.parent / f"{base}.{n}"
                                                            .replace(".", "/")).is_dir()]
                out += [(s, node.lineno, ()) for s in subs]
                if len(subs) < len(names):
                    out.append((base, node.lineno, names))
    return out


def graph() -> dict[str, list[tuple[str, int, tuple[str, ...]]]]:
    """Every module's imports (read-only: shared by the tests, ~1.2 s of CPU to build)."""
    return _graph(SRC)


@functools.cache
def _graph(src: Path) -> dict[str, list[tuple[str, int, tuple[str, ...]]]]:
    assert src == SRC  # imports() and module_name() read the module's SRC
    return {module_name(p): imports(p) for p in sorted(src.rglob("*.py"))}


def test_every_module_has_a_layer():
    for name in graph():
        assert layer(name) >= 0, name


def test_no_import_runs_upwards():
    bad = []
    for name, deps in graph().items():
        for dep, line, _ in deps:
            if layer(dep) > layer(name):
                bad.append(f"{name}:{line} imports {dep} (layer {layer(name)} -> {layer(dep)})")
    assert not bad, "\n".join(bad)


def test_io_holds_formats_only():
    for name, deps in graph().items():
        if name.startswith("scanqa.io"):
            for dep, line, _ in deps:
                assert dep.startswith(("scanqa.io", "scanqa.errors")), f"{name}:{line}: {dep}"


def test_no_import_cycle():
    edges = {name: {d for d, _, _ in deps if d != name} for name, deps in graph().items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                cycle = [*stack[stack.index(nxt):], nxt]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if nxt in edges and not state.get(nxt):
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(edges):
        if not state.get(node):
            visit(node)


def test_the_test_can_see_a_cycle_and_an_upward_import(tmp_path, monkeypatch):
    """The checks above must be able to fail: a planted cycle and upward import are found."""
    pkg = tmp_path / "scanqa"
    (pkg / "io").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "io" / "__init__.py").write_text("")
    (pkg / "io" / "a.py").write_text("from scanqa.model.optics import x\n")
    (pkg / "model").mkdir()
    (pkg / "model" / "__init__.py").write_text("")
    (pkg / "model" / "optics.py").write_text("from scanqa.io import a\n")
    monkeypatch.setattr(sys.modules[__name__], "SRC", pkg)
    deps = graph()
    assert ("scanqa.model.optics", 1, ("x",)) in deps["scanqa.io.a"]
    with pytest.raises(AssertionError, match="layer 1 -> 2"):
        test_no_import_runs_upwards()
    with pytest.raises(pytest.fail.Exception, match="import cycle"):
        test_no_import_cycle()


def private_imports(deps: dict) -> list[str]:
    """``module:line imports _name`` for every private (single-underscore) name imported
    from another scanqa module."""
    return [f"{name}:{line} imports {n} from {dep}" for name, rows in deps.items()
            for dep, line, names in rows if dep != name
            for n in names if n.startswith("_") and not n.startswith("__")]


def test_no_private_name_is_imported_across_modules():
    """A name another module needs is public (issue 47): splitting a file to stay under
    600 lines makes the pieces it shares public, not ``from .x import _y``."""
    assert private_imports(graph()) == []


def test_the_private_import_finder_is_not_blind():
    rows = {"scanqa.a": [("scanqa.b", 3, ("_helper", "public", "__version__"))]}
    assert private_imports(rows) == ["scanqa.a:3 imports _helper from scanqa.b"]


def test_every_module_fits_in_600_lines():
    """A module past 600 lines is split by what it does (docs/development.rst), so that a
    newcomer reads one job per file; the limit held by a test, not by memory."""
    long = {p.relative_to(SRC).as_posix(): n for p in SRC.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 600}
    assert long == {}
