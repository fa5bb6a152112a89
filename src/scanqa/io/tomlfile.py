"""TOML files: reading with one kind of error message for every file scanqa reads, and
writing the plain tables scanqa writes (manifests, pattern descriptions)."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

from scanqa.errors import InputError, ScanQAError
from scanqa.io.guard import MAX_TEXT_BYTES, regular_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


def read_toml(path: str | os.PathLike, what: str, error: type[ScanQAError] = InputError,
              missing: str | None = None) -> dict:
    """Parse a TOML file, raising one clear ``error`` when it cannot be read or parsed.

    Parameters
    ----------
    path : str or PathLike
        The file.
    what : str
        What the file is, for messages ("scanner config", "sweep manifest", ...).
    error : ScanQAError subclass
        The exception raised.
    missing : str, optional
        Message used when the file does not exist (default: "cannot read ...").
    """
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise error(missing or f"cannot read {what} {p}: No such file or directory")
    try:
        regular_file(p, what, MAX_TEXT_BYTES)
        raw = p.read_bytes()
    except InputError as err:
        raise error(str(err)) from None
    except OSError as err:
        raise error(f"cannot read {what} {p}: {err.strerror}") from None
    return loads_toml(raw, p, error)


def loads_toml(raw: bytes, where: str | os.PathLike, error: type[ScanQAError] = InputError
               ) -> dict:
    """Parse TOML bytes; every failure (bad syntax, not UTF-8, nesting deeper than
    :data:`MAX_DEPTH`) is one ``error`` naming ``where``."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"{where} is not valid TOML: {err}") from None
    depth = _nesting(text)
    if depth > MAX_DEPTH:
        raise error(f"{where} is not valid scanqa TOML: arrays or inline tables nested "
                    f"{depth} deep (scanqa reads at most {MAX_DEPTH}; a damaged file?)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(f"{where} is not valid TOML: {err}") from None
    except RecursionError:  # pragma: no cover - _nesting bounds the depth first
        raise error(f"{where} is not valid scanqa TOML: nested too deeply") from None


#: Deepest nesting of arrays and inline tables read (scanqa's formats use 2).
MAX_DEPTH = 32


def _nesting(text: str) -> int:
    """Deepest nesting of ``[`` and ``{`` in values, skipping strings and comments (an
    upper bound: a table header ``[a]`` counts 1, ``[[a]]`` 2)."""
    if text.count("[") + text.count("{") <= MAX_DEPTH:
        return 0
    depth = deepest = 0
    quote = ""
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if quote:
            if c == "\\" and quote[0] == '"':
                i += 1
            elif text.startswith(quote, i):
                i += len(quote) - 1
                quote = ""
        elif c in "\"'":
            quote = c * 3 if text.startswith(c * 3, i) else c
            i += len(quote) - 1
        elif c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(depth - 1, 0)
        i += 1
    return deepest


def dumps_toml(data: dict) -> str:
    """TOML text of a dict of scalars, lists, tables and arrays of tables.

    Scalars come first, then tables, then arrays of tables, each in insertion order.
    Numbers may be numpy scalars; a non-finite float is written as ``nan``/``inf``.

    Examples
    --------
    >>> print(dumps_toml({"format": "x/1", "set": [{"kind": "phase", "steps": 4}]}), end="")
    format = "x/1"
    <BLANKLINE>
    [[set]]
    kind = "phase"
    steps = 4
    """
    lines: list[str] = []
    _dump_table(data, "", lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _dump_table(data: dict, prefix: str, lines: list[str]) -> None:
    for k, v in data.items():
        if not isinstance(v, dict) and not _is_aot(v):
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in data.items():
        if isinstance(v, dict):
            lines += ["", f"[{prefix}{k}]"]
            _dump_table(v, f"{prefix}{k}.", lines)
    for k, v in data.items():
        if _is_aot(v):
            for item in v:
                lines += ["", f"[[{prefix}{k}]]"]
                _dump_table(item, f"{prefix}{k}.", lines)


def _is_aot(value: object) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _toml_value(value: object) -> str:
    """A TOML literal for a bool, number, string or (nested) list."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if hasattr(value, "dtype") and getattr(value, "ndim", 1) == 0:  # numpy scalar
        value = value.item()
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isfinite(value):
            return repr(value)
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{escaped}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")
