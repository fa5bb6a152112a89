"""Reading TOML inputs with one kind of error message for every file scanqa reads."""

from __future__ import annotations

import os
import sys
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
