"""A disk cache for expensive, deterministic computations the suite repeats.

Several test files run the same costly computation on the same inputs (the same real
board poses decoded and calibrated by the command and by the API, ...). Each such
result is computed once per ``make test`` and kept in ``build/test-cache`` (gitignored,
removed by ``make clean``), where every other test that needs it reads it back.

A cached result can never hide a regression: its key is the SHA-256 of

* every source file of the package (``src/scanqa``: any edit of scanqa recomputes it),
* the versions of Python and of the numerical libraries the computations call,
* the function's name and its arguments (files and folders by their bytes).

so a hit is what the current code would return on the current inputs. Two xdist workers
that want the same result wait for one another (a lock file) instead of computing it
twice; a result is written to a temporary file and renamed into place, so a reader sees
a whole file or none. ``SCANQA_TEST_CACHE=0`` turns the cache off (every call computes).
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import pickle
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
#: The cache folder (``/build/`` is gitignored; ``make clean`` removes it).
CACHE = ROOT / "build" / "test-cache"
#: Entries not read for this long are removed when a process first uses the cache [s].
MAX_AGE_S = 7 * 24 * 3600
#: The libraries whose versions enter every key (what the cached computations call).
LIBRARIES = ("numpy", "scipy", "cv2", "numba", "llvmlite", "open3d")


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of the package's sources (paths and bytes) and the libraries' versions."""
    h = hashlib.sha256(sys.version.encode())
    src = ROOT / "src" / "scanqa"
    for path in sorted(p for p in src.rglob("*") if p.is_file()
                       and "__pycache__" not in p.parts and p.suffix != ".pyc"):
        h.update(str(path.relative_to(src)).encode() + b"\0")
        h.update(path.read_bytes())
    for name in LIBRARIES:
        try:
            module = __import__(name)
        except ImportError:
            version = "absent"
        else:
            version = str(getattr(module, "__version__", "?"))
        h.update(f"{name}={version}\0".encode())
    _prune()
    return h.hexdigest()


def _update(h, value: Any) -> None:
    """Feed ``value`` to the hash: paths by their content, containers item by item."""
    if isinstance(value, os.PathLike):
        path = Path(value)
        if path.is_dir():
            h.update(b"dir\0")
            for p in sorted(q for q in path.rglob("*") if q.is_file()):
                h.update(str(p.relative_to(path)).encode() + b"\0")
                h.update(p.read_bytes())
        elif path.is_file():
            h.update(b"file\0" + path.read_bytes())
        else:
            h.update(b"missing\0" + str(path).encode())
    elif isinstance(value, (list, tuple)):
        h.update(f"seq{len(value)}\0".encode())
        for item in value:
            _update(h, item)
    elif isinstance(value, dict):
        h.update(f"map{len(value)}\0".encode())
        for k in sorted(value):
            _update(h, k)
            _update(h, value[k])
    elif isinstance(value, bytes):
        h.update(b"bytes\0" + value)
    elif type(value).__module__ == "numpy" and hasattr(value, "tobytes"):  # repr abridges
        h.update(f"array{value.dtype}{value.shape}\0".encode() + value.tobytes())
    else:  # numbers, strings, None, frozen dataclasses: their repr is their value
        h.update(repr(value).encode() + b"\0")


def key(name: str, *inputs: Any) -> str:
    """The cache key of ``name`` computed from ``inputs`` by the current sources."""
    h = hashlib.sha256(source_digest().encode())
    _update(h, name)
    for value in inputs:
        _update(h, value)
    return h.hexdigest()[:32]


def cached(name: str, build: Callable[[], Any], *inputs: Any) -> Any:
    """``build()``, computed once for the current sources and ``inputs`` and kept on disk.

    Parameters
    ----------
    name : str
        What is computed (a file-name-safe label, part of the key).
    build : callable
        Computes the value (picklable) from ``inputs``, which it must not read beyond.
    *inputs
        Everything the value depends on besides the package's sources: paths (their
        bytes are hashed), numbers, strings, sequences and dicts of them, objects whose
        repr is their value.
    """
    if os.environ.get("SCANQA_TEST_CACHE", "1") == "0":
        return build()
    path = CACHE / f"{name}-{key(name, *inputs)}.pickle"
    value = _read(path)
    if value is not None:
        return value[0]
    try:
        CACHE.mkdir(parents=True, exist_ok=True)
        lock = open(path.with_suffix(".lock"), "w")  # closed by the with below
    except OSError:  # a read-only checkout: no cache, the value is computed
        return build()
    me = (path, threading.get_ident())
    if me in _BUILDING:  # flock would wait for this very thread: say so instead
        lock.close()
        raise RuntimeError(f"{name}: asked for again while it is being computed (a patched "
                           "function that comes back to the cache)")
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the other worker computes it: wait for it
        value = _read(path)
        if value is not None:
            return value[0]
        _BUILDING.add(me)
        try:
            result = build()
        finally:
            _BUILDING.discard(me)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as fh:
                pickle.dump(result, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        except OSError:  # a full disk: the value is still right, only not kept
            tmp.unlink(missing_ok=True)
    return result


#: The entries each thread of this process is computing (the same thread asking for one
#: again, from inside its computation, would wait on its own lock for ever).
_BUILDING: set[tuple[Path, int]] = set()


def memoized(name: str, function: Callable, key_of: Callable[..., tuple]) -> Callable:
    """``function`` with its results cached under ``name``; ``key_of(*args, **kwargs)``
    gives the inputs of the key (what the result depends on: files by path)."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        return cached(name, lambda: function(*args, **kwargs), *key_of(*args, **kwargs))

    return wrapper


def _read(path: Path) -> tuple[Any] | None:
    try:
        with open(path, "rb") as fh:
            value = pickle.load(fh)
    except (FileNotFoundError, EOFError, pickle.UnpicklingError):
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # read now: kept by _prune
    return (value,)


def _prune() -> None:
    """Remove entries (and stale temporaries) not read for MAX_AGE_S."""
    if not CACHE.is_dir():
        return
    now = time.time()
    for p in CACHE.iterdir():
        try:
            if now - p.stat().st_mtime > MAX_AGE_S:
                p.unlink()
        except OSError:
            pass
