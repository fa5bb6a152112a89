"""Checks every reader makes before it opens an input: a regular file of a sane size.

A reader that opens whatever it is given can block for ever (a FIFO, a terminal, a
socket: ``open`` waits for a writer that never comes) or read without end
(``/dev/zero``); a reader that trusts a size from a header allocates what the header
claims. :func:`regular_file` refuses anything but a regular file, before it is opened,
and :func:`check_size` refuses a declared or real size above the limit of its kind
before anything is allocated or decompressed. The limits are generous for real scans
(:data:`MAX_INPUT_BYTES`, 1 GiB by default) and can be raised with the environment
variable ``SCANQA_MAX_INPUT_MB`` on a machine with the memory for it.

Every file that passes :func:`regular_file` while a command runs (inside
:func:`command_inputs`) is remembered as one of the command's inputs, and
:func:`refuse_input_overwrite` - called by every writer of :mod:`scanqa.io.atomic` - refuses
to replace one of them, with or without ``--force``: ``decode SCAN --out SCAN/p5_00.png``
or ``calibrate SWEEP --out SWEEP/sweep.toml`` would otherwise destroy the data the result
came from. A file is identified by its folder (symbolic links resolved) and its name.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from pathlib import Path

from scanqa.errors import InputError

#: Default limit of one array or image held in memory after reading [bytes].
MAX_INPUT_BYTES = 1 << 30
#: Limit of a text file (TOML, JSON sidecar) [bytes].
MAX_TEXT_BYTES = 16 << 20
#: The environment variable that raises :data:`MAX_INPUT_BYTES` [MiB].
LIMIT_VARIABLE = "SCANQA_MAX_INPUT_MB"

#: The inputs of the running command, by entry (:func:`entry`): what each was read as.
_inputs: dict[str, str] | None = None


def entry(path: str | os.PathLike) -> str:
    """The identity of a file's name: its folder with symbolic links resolved, and the name
    (the file a rename onto ``path`` would replace)."""
    p = Path(os.path.abspath(path))
    return os.path.join(os.path.realpath(p.parent), p.name)


@contextlib.contextmanager
def command_inputs() -> Iterator[dict[str, str]]:
    """Remember the files read through :func:`regular_file` until the block ends (one
    command run); yields the record {entry: what it was read as}."""
    global _inputs
    saved, _inputs = _inputs, {}
    try:
        yield _inputs
    finally:
        _inputs = saved


def refuse_input_overwrite(path: str | os.PathLike) -> None:
    """Refuse to write ``path`` when the running command read it as an input.

    Raises
    ------
    InputError
        Naming the file, what it was read as, and the fix.
    """
    record = _inputs
    if not record:
        return
    what = record.get(entry(path))
    if what is not None:
        raise InputError(f"cannot write {path}: it is one of this command's inputs (read as "
                         f"{what}), which no forcing replaces: give the output another "
                         "name or folder")


def max_input_bytes() -> int:
    """The limit of one array or image in memory [bytes]: ``SCANQA_MAX_INPUT_MB`` MiB
    when set to a positive number, else :data:`MAX_INPUT_BYTES`."""
    raw = os.environ.get(LIMIT_VARIABLE, "")
    try:
        value = float(raw)
    except ValueError:
        return MAX_INPUT_BYTES
    return int(value * (1 << 20)) if value > 0 and value < 1e12 else MAX_INPUT_BYTES


def regular_file(path: str | os.PathLike, what: str, max_bytes: int | None = None) -> Path:
    """``path`` as a Path after checking that it is a regular file (not a FIFO, device,
    socket or folder) no larger than ``max_bytes``.

    Parameters
    ----------
    path : str or PathLike
        The input.
    what : str
        What the file is, for messages ("image", "scanner config", ...).
    max_bytes : int, optional
        Largest size accepted [bytes]; default no limit.

    Raises
    ------
    InputError
        When the file does not exist, is not a regular file or is too large.
    """
    p = Path(path)
    if _inputs is not None:
        _inputs.setdefault(entry(p), what)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise InputError(f"{what} {p} does not exist") from None
    except OSError as err:
        raise InputError(f"cannot read {what} {p}: {err.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} {p} is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{what} {p} is not a regular file (a FIFO, device or socket, "
                         "which scanqa would wait on for ever); give a file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise InputError(f"{what} {p} is {st.st_size} bytes, more than the {max_bytes} a "
                         f"{what} can hold (a wrong or damaged file?)")
    return p


def check_size(nbytes: int, where: str, declared: str) -> None:
    """Refuse ``nbytes`` above :func:`max_input_bytes` before it is allocated.

    Parameters
    ----------
    nbytes : int
        The size a header declares [bytes].
    where : str
        The file (and entry) it comes from, for the message.
    declared : str
        What declares it ("its header declares shape (4, 100000, 100000) of float64").

    Raises
    ------
    InputError
        When the size exceeds the limit.
    """
    limit = max_input_bytes()
    if nbytes > limit:
        raise InputError(f"{where}: {declared}, {nbytes / (1 << 30):.3g} GiB, more than "
                         f"the {limit / (1 << 30):.3g} GiB limit (a damaged or hostile "
                         f"file; for a real input this large set {LIMIT_VARIABLE})")


def loads_json_object(text: str, where: str) -> dict:
    """A JSON object from ``text`` holding only finite numbers, or one error.

    Python's ``json`` reads ``1e999`` as inf and ``NaN``/``Infinity`` as floats, which a
    later strict write (``allow_nan=False``) refuses with a traceback, and recurses
    once per nesting level. Metadata read from a file goes through here.

    Parameters
    ----------
    text : str
        The JSON text.
    where : str
        The file and field, for messages ("cloud.ply, the scanqa-meta header comment").

    Raises
    ------
    InputError
        Not valid JSON, not an object, a non-finite number or nesting deeper than 64.
    """
    import json
    import math

    def finite(token: str) -> float:
        value = float(token)
        if not math.isfinite(value):
            raise ValueError(f"number {token} is out of range")
        return value

    def constant(token: str) -> float:
        raise ValueError(f"{token} is not a number JSON allows")

    if _json_depth(text) > 64:
        raise InputError(f"{where} is nested more than 64 deep (damaged file?); delete it "
                         "or write the file again")
    try:
        value = json.loads(text, parse_float=finite, parse_constant=constant)
    except (ValueError, RecursionError) as err:
        raise InputError(f"{where} is not valid JSON with finite numbers ({err}); delete "
                         "it or write the file again") from None
    if not isinstance(value, dict):
        raise InputError(f"{where} must be a JSON object, got {type(value).__name__}")
    return value


def _json_depth(text: str) -> int:
    """Upper bound of the nesting depth of JSON text (brackets outside strings)."""
    if text.count("[") + text.count("{") <= 64:
        return 0
    depth = deepest = 0
    in_string = escaped = False
    for c in text:
        if in_string:
            if escaped:
                escaped = False
            elif c == "\\":
                escaped = True
            elif c == '"':
                in_string = False
        elif c == '"':
            in_string = True
        elif c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth -= 1
    return deepest
