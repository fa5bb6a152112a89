"""The package's sources parsed once per test process and their nodes indexed by type.

The convention tests (test_conventions.py, test_architecture.py, test_failures.py,
test_progress.py, ...) read the same ~180 modules' trees: each used to parse them and
walk every tree once per rule (~300 000 nodes a walk, ~1 s of CPU). Here each module is
parsed once and walked once; a rule asks for the nodes of the types it reads, in
:func:`ast.walk`'s order, so it finds what a walk of its own would find.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "scanqa"


@functools.cache
def modules() -> tuple[Path, ...]:
    """Every module of the package (``src/scanqa/**/*.py``), sorted."""
    return tuple(sorted(SRC.rglob("*.py")))


def rel(path: Path) -> str:
    """A module's path relative to ``src/scanqa`` (``"qa/verdict.py"``)."""
    return path.relative_to(SRC).as_posix()


@functools.cache
def text(path: Path) -> str:
    """A source file's text."""
    return path.read_text(encoding="utf-8")


@functools.cache
def parsed(path: Path) -> ast.Module:
    """A source file's tree (read-only: shared by every test of the process)."""
    tree = ast.parse(text(path))
    _LINES[id(tree)] = (tree, text(path).split("\n"))
    return tree


_LINES: dict[int, tuple[ast.AST, list[str]]] = {}


def may_hold(tree: ast.AST, node: ast.AST, words: tuple[str, ...]) -> bool:
    """False only when ``ast.unparse(node)`` cannot hold every one of ``words``: the node's
    lines of source lack one (unparse writes the node's own names, strings, operators,
    all within its lines). Always True for a tree not read by :func:`parsed` (no source
    to look at)."""
    kept = _LINES.get(id(tree))
    if kept is None or kept[0] is not tree:
        return True
    span = "\n".join(kept[1][node.lineno - 1:node.end_lineno])
    return all(w in span for w in words)


class Index:
    """A tree's nodes by exact type, each list in :func:`ast.walk` order, and the
    top-level statement that holds each node."""

    def __init__(self, tree: ast.AST):
        self.tree = tree
        self.by_type: dict[type, list[tuple[int, ast.AST]]] = defaultdict(list)
        for order, node in enumerate(ast.walk(tree)):
            self.by_type[type(node)].append((order, node))
        self._top: dict[int, ast.AST] | None = None

    def of(self, *types: type) -> list:
        """The nodes that are instances of ``types``, in :func:`ast.walk` order."""
        lists = [entries for kind, entries in self.by_type.items() if issubclass(kind, types)]
        if len(lists) == 1:
            return [node for _, node in lists[0]]
        return [node for _, node in sorted((e for entries in lists for e in entries),
                                           key=lambda entry: entry[0])]

    def top(self, node: ast.AST) -> ast.AST:
        """The statement of the module's body that holds ``node``."""
        if self._top is None:
            self._top = {id(n): stmt for stmt in self.tree.body for n in ast.walk(stmt)}
        return self._top[id(node)]


_INDEXES: dict[int, tuple[ast.AST, Index]] = {}


def index(tree: ast.AST) -> Index:
    """``tree``'s :class:`Index`, built once per tree (the tree is kept with it, so the
    id stays its own)."""
    kept = _INDEXES.get(id(tree))
    if kept is None or kept[0] is not tree:
        kept = _INDEXES[id(tree)] = (tree, Index(tree))
    return kept[1]


def nodes(path: Path, *types: type) -> list:
    """The nodes of ``types`` in the module at ``path``, in :func:`ast.walk` order."""
    return index(parsed(path)).of(*types)
