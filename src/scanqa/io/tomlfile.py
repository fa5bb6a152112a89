"""TOML files: reading with one kind of error message for every file scanqa reads, and
writing the plain tables scanqa writes (manifests, pattern descriptions)."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

from scanqa.errors import InputError, ScanQAError

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
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise error(missing or f"cannot read {what} {p}: No such file or directory") from None
    except OSError as err:
        raise error(f"cannot read {what} {p}: {err.strerror}") from None
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise error(f"{p} is not valid TOML: {err}") from None


def loads_toml(text: str, what: str, error: type[ScanQAError] = InputError) -> dict:
    """Parse TOML text (e.g. a file a browser uploaded), raising one clear ``error``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(f"the {what} is not valid TOML: {err}") from None


def known_table(table: object, name: str, keys, fail: Callable[[str], Exception]
                ) -> dict | None:
    """An optional ``[name]`` sub-table holding only ``keys`` (a copy), or None when
    absent; otherwise ``fail(message)`` is raised."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise fail(f"[{name}] must be a table")
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise fail(f"[{name}]: unknown key {unknown[0]!r} (known: {', '.join(keys)})")
    return dict(table)


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
