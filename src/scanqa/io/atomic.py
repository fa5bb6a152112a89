"""Writing outputs so that nothing is lost and nothing is left half-written.

* One file: :func:`atomic_path` writes a temporary file in the target folder and renames
  it onto the target; a failed run leaves the previous file or none.
* Several files (a command's whole output): :func:`staged_dir` yields a hidden staging
  folder; the files are written there and moved into the output folder together when
  everything succeeded, or removed (and the previous outputs left as they were) when
  anything failed.
* Files and folders get the mode the umask gives (0644 and 0755 under umask 022), like
  any file a program creates, whatever mode an overwritten file had.
* A write that fails (a folder in the way, a read-only or full disk) raises one
  :class:`~scanqa.errors.OutputError` naming the file and the reason.

The temporaries are removed by ``finally`` clauses; the command line turns SIGTERM into
an exception so that they run on SIGTERM as on Ctrl-C. A temporary's name is registered
for removal before the file is created (``O_EXCL``), so a signal arriving just after its
creation cannot leave it behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

from scanqa.errors import InputError, OutputError
from scanqa.io.guard import refuse_input_overwrite

#: Prefix of staging folders and temporary files (hidden on Unix).
STAGE_PREFIX = ".scanqa-stage-"


def _umask() -> int:
    """The process umask, read without changing it where the OS allows."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new file under the current umask (0o644 under 022)."""
    return 0o666 & ~_umask()


def dir_mode() -> int:
    """Mode of a new folder under the current umask (0o755 under 022)."""
    return 0o777 & ~_umask()


def output_error(path: str | os.PathLike, err: OSError) -> OutputError:
    """One-line :class:`OutputError` for an OSError raised while writing ``path``."""
    reason = err.strerror
    if err.errno is None:  # numpy's tofile reports a short write without an errno
        reason = str(err)
        with contextlib.suppress(OSError):
            st = os.statvfs(Path(path).parent if str(Path(path).parent) else ".")
            if st.f_bavail * st.f_frsize < (1 << 20):
                reason = os.strerror(errno.ENOSPC)
    hint = {errno.ENOSPC: " (free some space or write elsewhere)",
            errno.EROFS: " (write to another folder)",
            errno.EACCES: " (check the folder's permissions)",
            errno.EISDIR: " (a folder of that name is in the way)"}.get(err.errno or 0, "")
    return OutputError(f"cannot write {path}: {reason or err}{hint}")


def check_out_dir(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path after checking that it can be a new file.

    Parameters
    ----------
    path : str or PathLike
        Output file path.

    Raises
    ------
    InputError
        When the parent folder does not exist.
    OutputError
        When ``path`` is an existing folder.
    """
    out = Path(path)
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(
            f"cannot write {out}: folder {parent} does not exist (create it first)"
        )
    if out.is_dir():
        raise OutputError(f"cannot write {out}: it is a folder (give a file name)")
    return out


def make_out_dir(path: str | os.PathLike) -> Path:
    """Create an output folder (and its parents) or raise one clear error."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputError(f"cannot create output folder {out}: a file of that name is in "
                          "the way")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"cannot create output folder {out}: {err.strerror}") from None
    return out


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path : str or PathLike
        Final destination.
    suffix : str, optional
        Suffix of the temporary file (some writers choose the format by suffix);
        defaults to the suffix of ``path``.

    Raises
    ------
    OutputError
        When the temporary cannot be created, written or renamed (the temporary is
        removed).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with atomic_path(d / "a.txt") as tmp:
    ...     _ = tmp.write_text("ok")
    >>> (d / "a.txt").read_text()
    'ok'
    """
    out = check_out_dir(path)
    refuse_input_overwrite(out)
    suffix = out.suffix if suffix is None else suffix
    held: list[Path] = []  # the temporary, registered before it exists (module notes)
    try:
        try:
            tmp = _new_temp(out.parent, f".{out.name}.", suffix, held, directory=False)
            yield tmp
            os.chmod(tmp, file_mode())
            os.replace(tmp, out)
        except OSError as err:
            raise output_error(out, err) from None
    finally:
        for tmp in held:
            with contextlib.suppress(OSError):
                tmp.unlink()


def _new_temp(folder: Path, prefix: str, suffix: str, held: list[Path], directory: bool
              ) -> Path:
    """Create a new hidden file (or folder) in ``folder``, its name appended to ``held``
    *before* it is created, so that the caller's ``finally`` removes it whenever a signal
    (SIGTERM through the command line, Ctrl-C) interrupts: there is no moment at which
    the temporary exists and nobody will remove it."""
    for _ in range(100):
        name = Path(folder or ".") / f"{prefix}{secrets.token_hex(8)}{suffix}"
        held.append(name)
        try:
            if directory:
                os.mkdir(name, 0o700)
            else:
                os.close(os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            return name
        except FileExistsError:  # someone else's: not ours to remove
            held.remove(name)
    raise FileExistsError(errno.EEXIST, "no unused temporary name", str(folder))


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically and return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


# ------------------------------------------------------------------ several outputs


def _existing_ancestor(path: Path) -> Path:
    """The nearest folder among ``path`` and its parents that exists."""
    for p in (path, *path.parents):
        if p.is_dir():
            return p
        if p.exists():
            raise OutputError(f"cannot create output folder {path}: {p} is a file")
    return Path(".")


@contextlib.contextmanager
def staged_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a hidden staging folder whose content becomes ``path``'s when all went well.

    Write every output of a command into the yielded folder. On success its files are
    moved into ``path`` (created with its parents when missing), replacing files of the
    same names and leaving other files of ``path`` alone; on any failure (an exception,
    Ctrl-C, SIGTERM through the command line) the staging folder is removed and ``path``
    is as it was. Staging folders nest (a command may stage what a library function
    stages again).

    Parameters
    ----------
    path : str or PathLike
        The output folder.

    Raises
    ------
    OutputError
        When the staging folder cannot be created (read-only or full disk, no
        permission, a file in the way) or the outputs cannot be moved into place (the
        previous files are then restored).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp()) / "out"
    >>> with staged_dir(d) as stage:
    ...     _ = write_text(stage / "a.txt", "ok")
    >>> sorted(p.name for p in d.iterdir())
    ['a.txt']
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise OutputError(f"cannot write into {target}: it is a file, not a folder")
    anchor = _existing_ancestor(target)
    held: list[Path] = []
    try:
        try:
            stage = _new_temp(anchor, STAGE_PREFIX, "", held, directory=True)
        except OSError as err:
            raise output_error(target, err) from None
        yield stage
        _publish(stage, target)
    except OutputError as err:  # name the file the user asked for, not its staged copy
        raise OutputError(str(err).replace(str(held[-1]) if held else "\0", str(target))
                          ) from None
    finally:
        for stage in held:
            shutil.rmtree(stage, ignore_errors=True)


def _publish(stage: Path, target: Path) -> None:
    """Move the staged outputs into ``target`` together (undone on failure)."""
    try:
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            os.chmod(stage, dir_mode())
            os.rename(stage, target)
            return
        moves = _plan(stage, target, stage / ".replaced")
        _apply(moves)
    except OSError as err:
        raise output_error(target, err) from None


def _plan(stage: Path, target: Path, backup: Path) -> list[tuple[Path, Path, Path | None]]:
    """(staged, final, backup of the file replaced or None) for every staged entry; a
    staged folder whose counterpart does not exist moves as a whole."""
    moves = []
    for src in sorted(stage.iterdir()):
        if src == backup:
            continue
        dst = target / src.name
        if src.is_dir() and dst.is_dir():
            moves += _plan(src, dst, backup / src.name)
        elif dst.exists() and dst.is_dir() != src.is_dir():
            kind = "folder" if dst.is_dir() else "file"
            raise OutputError(f"cannot write {dst}: a {kind} of that name is in the way")
        else:
            refuse_input_overwrite(dst)
            moves.append((src, dst, backup / src.name if dst.exists() else None))
    return moves


def _apply(moves: list[tuple[Path, Path, Path | None]]) -> None:
    """Rename every staged entry into place, keeping the replaced ones until all moved;
    on any failure put everything back.

    Crash-safe at every line: a replaced file is first hard-linked (copied where links
    are not supported) to its backup and then renamed over, so that the final name
    always holds the previous file or the new one, never nothing; and each move is
    registered as begun *before* its first operation, so that an interrupt between any
    two lines (Ctrl-C, SIGTERM through the command line) is undone from what is on disk:
    a new entry already in place goes back to the stage, a backup goes back over its
    name.
    """
    begun: list[tuple[Path, Path, Path | None]] = []
    try:
        for src, dst, old in moves:
            begun.append((src, dst, old))
            if old is not None:
                old.parent.mkdir(parents=True, exist_ok=True)
                _keep(dst, old)
            os.replace(src, dst)
    except BaseException:
        for src, dst, old in reversed(begun):
            with contextlib.suppress(OSError):
                if not src.exists() and (dst.exists() or dst.is_symlink()):
                    os.replace(dst, src)  # the new one moved: take it back
                if old is not None and (old.exists() or old.is_symlink()):
                    os.replace(old, dst)
        raise


def _keep(path: Path, backup: Path) -> None:
    """A backup of ``path`` at ``backup`` that leaves ``path`` in place: a hard link, or a
    copy on a file system without links."""
    with contextlib.suppress(FileNotFoundError):
        backup.unlink()
    try:
        os.link(path, backup, follow_symlinks=False)
    except OSError:
        shutil.copy2(path, backup, follow_symlinks=False)
