"""Seeded mutations of every input format, run through the command line in process.

Each case writes one mutated input beside the valid others (tests/smallcases.py) and
runs the command that reads it with ``scanqa.cli.main``. The promise checked: exit 0,
or exit 2 with one line ``scanqa: ...`` on stderr; never an exception escaping main;
after a failed run no output and no temporary is left behind. ``test_fuzz.py`` runs a
small slice; ``make fuzz`` runs thousands of cases.

Mutations are of two kinds: bytes (bit flips, truncation, deleted, repeated or random
spans) and structure (TOML values replaced by values of other types, keys dropped or
added, values nested hundreds deep as arrays or inline tables; PLY header tokens and
lines; npz entries dropped, retyped, reshaped, given a forged header, flagged encrypted,
declaring sizes they do not hold or deflated at deflate's limit; PNG headers declaring
other dimensions, depths or colour types; CSV cells turned to text, quoted or dropped).

A mutator returns the bytes, or (bytes, True) when the input is invalid for certain:
such a case that exits 0 is counted as *silent* (accepted with a result it cannot have).
Every case is timed: one over :data:`SLOW_S` seconds is a broken promise (a hang), and
the run reports the process's peak memory.
"""

from __future__ import annotations

import contextlib
import io
import os
import random
import resource
import sys
import time
import traceback
import warnings
import zipfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanqa.io.tomlfile import dumps_toml, tomllib

from .smallcases import command, write_inputs

FORMATS = ("ply", "phase", "table", "patterns", "layout", "config", "image", "stack",
           "csv")
#: A case running longer than this is reported as a hang [s].
SLOW_S = 30.0
#: Crashes the fuzzer still finds in code owned elsewhere, by signature (see
#: :func:`signature`), with the reason they are tolerated here. patterns.toml is read by
#: the decoder (scanqa.decoding, scanqa.io.patterns), which is being rewritten on its own
#: branch; what crashes there is listed here and reported, not fixed.
KNOWN_DECODER_CRASHES: dict[str, str] = {}
#: Flags of every run (SCANQA_FUZZ_LOUD=1 leaves -q out, for scanqa versions without it).
QUIET = () if os.environ.get("SCANQA_FUZZ_LOUD") else ("-q",)
#: The file each format's mutations replace (inside the inputs folder).
TARGET = {"ply": "cloud.ply", "phase": "phase.npz", "table": "table.npz",
          "patterns": "patterns/patterns.toml", "layout": "layout.toml",
          "config": "config.toml", "image": "patterns/p80_01.png", "stack": "stack/p80.npz",
          "csv": "cloud.csv"}
#: The folder a format's file lives in, copied whole for each case (others are linked).
FOLDER = {"patterns": "patterns", "image": "patterns", "stack": "stack"}

_VALUES = ("high", "", -1, 0, 1, -1.5, 1e308, -1e308, float("nan"), float("inf"),
           float("-inf"), 10**18, [1, 2, 3], [], ["a"], [[1, 2]], {}, {"x": 3}, True,
           0.0001, 99999, "scanqa-gauge-layout/1", [0.0, 0.0, 0.0, 0.0])
_PLY_TOKENS = ("many", "-1", "", "1e12", "999999999999", "list", "uchar", "double", "x",
               "nx", "ascii", "binary_big_endian", "float64", "vertex", "face", "0", "3")
_PLY_LINES = ("property float nx", "property uchar red", "element face 2",
              "property list uchar int vertex_indices", "format ascii 1.0", "comment hi",
              "obj_info x", "bogus line", "property float", "element vertex",
              "property double x", "format", "element vertex 1000000000000",
              "comment scanqa-meta {\"a\":", "end_header")


@dataclass
class Outcome:
    """Counts of one format's run and the failures found."""

    cases: int = 0
    exits: Counter = field(default_factory=Counter)
    tracebacks: list = field(default_factory=list)   # (case, signature, text)
    broken_promises: list = field(default_factory=list)  # (case, what)
    silent: list = field(default_factory=list)  # cases invalid for certain that exited 0
    slowest_s: float = 0.0


# ------------------------------------------------------------------------ mutations


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    """One byte-level mutation."""
    b = bytearray(data)
    kind = rng.randrange(6)
    if not b:
        return bytes(rng.randrange(256) for _ in range(8))
    i = rng.randrange(len(b))
    if kind == 0:  # bit flips
        for _ in range(rng.randint(1, 8)):
            j = rng.randrange(len(b))
            b[j] ^= 1 << rng.randrange(8)
    elif kind == 1:  # truncate
        del b[i:]
    elif kind == 2:  # delete a span
        del b[i:i + rng.randint(1, 64)]
    elif kind == 3:  # repeat a span
        b[i:i] = b[i:i + rng.randint(1, 64)]
    elif kind == 4:  # random bytes
        b[i:i + rng.randint(1, 16)] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
    else:  # an interesting token
        b[i:i] = rng.choice((b"\x00", b"\xff" * 4, b"9" * 20, b"-1", b"nan", b"\n", b"=", b"["))
    return bytes(b)


def _leaves(obj, path=()):
    """(path, value) of every leaf and table of a parsed TOML document."""
    items = obj.items() if isinstance(obj, dict) else enumerate(obj)
    for k, v in items:
        yield (*path, k), v
        if isinstance(v, (dict, list)):
            yield from _leaves(v, (*path, k))


def mutate_toml(text: str, rng: random.Random) -> str:
    """One structural mutation of a TOML document: a value replaced by one of another
    type, a key dropped or added; falls back to a text mutation."""
    data = tomllib.loads(text)
    leaves = list(_leaves(data))
    if not leaves or rng.random() < 0.25:
        lines = text.splitlines()
        i = rng.randrange(len(lines))
        op = rng.randrange(3)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[rng.randrange(len(lines))])
        else:
            lines[i] = lines[i].replace("=", "= [", 1) if "=" in lines[i] else lines[i] + " = 1"
        return "\n".join(lines) + "\n"
    if rng.random() < 0.15:
        return _nested_toml(text, rng)
    path, value = rng.choice(leaves)
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    op = rng.randrange(6)
    if op >= 4 and isinstance(value, (int, float)) and not isinstance(value, bool):
        # a number of the same type somewhere else on the line: deeper than a type error
        factor = rng.choice((0, -1, 0.5, 2, 10, 1e6, 1e-6, 1.0001))
        new = value * factor
        parent[path[-1]] = int(new) if isinstance(value, int) and abs(new) < 1e18 else new
    elif op == 0 and isinstance(parent, dict):
        del parent[path[-1]]
    elif op == 1 and isinstance(parent, dict):
        parent[rng.choice(("extra", "x", "id", "profiles", "block"))] = rng.choice(_VALUES)
    else:
        parent[path[-1]] = rng.choice(_VALUES)
    return _dump(data)


def _nested_toml(text: str, rng: random.Random):
    """Grammar-aware nesting: a value that is arrays or inline tables ``depth`` deep, at
    the top or inside a table, or a dotted table header ``depth`` keys long. Deeper
    than the reader's limit is invalid for certain."""
    from scanqa.io.tomlfile import MAX_DEPTH

    depth = rng.choice((2, 8, 31, 33, 64, 300, 1000, 5000))
    kind = rng.randrange(4)
    if kind == 0:
        value = "[" * depth + "1" + "]" * depth
    elif kind == 1:
        value = "{a = " * depth + "1" + "}" * depth
    elif kind == 2:
        value = "".join(rng.choice(("[", "{a = ")) for _ in range(depth))
        value += "1" + "".join("]" if c == "[" else "}" for c in reversed(
            [c for c in value if c in "[{"]))
    else:
        header = "[" + ".".join(f"k{i}" for i in range(depth)) + "]\nx = 1\n"
        return text + "\n" + header, False
    lines = text.splitlines()
    tables = [i for i, ln in enumerate(lines) if ln.startswith("[")]
    at = rng.choice([0, *tables]) + (1 if tables else 0)
    lines.insert(min(at, len(lines)), f"nested_{rng.randrange(99)} = {value}")
    return "\n".join(lines) + "\n", depth > MAX_DEPTH


def _dump(data) -> str:
    try:
        return dumps_toml(data)
    except TypeError:
        return "x = 1\n"


def mutate_ply(data: bytes, rng: random.Random) -> bytes:
    """One mutation of a PLY header (token, line) or of its body's length."""
    end = data.find(b"end_header\n")
    if end < 0 or rng.random() < 0.3:
        return mutate_bytes(data, rng)
    header = data[:end].decode("ascii").split("\n")
    body = data[end + len(b"end_header\n"):]
    op = rng.randrange(5)
    i = rng.randrange(1, len(header)) if len(header) > 1 else 0
    if op == 0:
        tokens = header[i].split(" ")
        tokens[rng.randrange(len(tokens))] = rng.choice(_PLY_TOKENS)
        header[i] = " ".join(tokens)
    elif op == 1:
        del header[i]
    elif op == 2:
        header.insert(i, rng.choice(_PLY_LINES))
    elif op == 3:
        header.insert(i, header[i])
    else:
        body = body[:rng.randrange(len(body) + 1)]
    return ("\n".join(header) + "\nend_header\n").encode("ascii", "replace") + body


def _npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _forged_entry(name: str, shape: tuple) -> tuple[str, bytes]:
    """An .npy entry whose header declares ``shape`` but holds 16 bytes."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False,
                                               "shape": shape})
    return f"{name}.npy", buf.getvalue() + bytes(16)


def mutate_npz(data: bytes, rng: random.Random) -> bytes:
    """One mutation of an npz archive: an entry dropped, retyped, reshaped, emptied,
    filled with NaN, replaced by an object array or a forged header; or bytes."""
    if rng.random() < 0.3:
        return mutate_bytes(data, rng)
    if rng.random() < 0.25:
        return mutate_zip(data, rng)
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    key = rng.choice(sorted(arrays))
    a = arrays[key]
    op = rng.randrange(9)
    if op == 0:
        del arrays[key]
    elif op == 1:
        arrays[key] = np.array("garbage")
    elif op == 2:
        arrays[key] = a.reshape(-1) if a.ndim else np.zeros((2, 3))
    elif op == 3:
        arrays[key] = a[:0] if a.ndim else np.array([])
    elif op == 4 and a.dtype.kind == "f":
        arrays[key] = np.full_like(a, rng.choice((np.nan, np.inf, -1e308, 0.0)))
    elif op == 5:
        arrays[key] = np.array([{"x": 1}, None], dtype=object)
        return _npz_bytes_pickled(arrays), True
    elif op == 6 and a.dtype.kind == "U" and a.ndim == 0:
        text = str(a)
        i = rng.randrange(len(text) + 1)
        arrays[key] = np.array(text[:i] + rng.choice(('"x"', "}", "1e999", '"width_px": -1',
                                                      "null", "[")) + text[i:])
    elif op == 7:
        shape = rng.choice(((10**12,), (10**6, 10**6), (-5,), (3, 0), (4, 10**5, 10**5),
                            (2**62, 4)))
        name, raw = _forged_entry(key, shape)
        del arrays[key]
        buf = io.BytesIO(_npz_bytes(arrays))
        with zipfile.ZipFile(buf, "a") as zf:
            zf.writestr(name, raw)
        return buf.getvalue(), shape != (3, 0)
    else:
        arrays[key] = a.astype(rng.choice((np.int8, np.float32, np.bool_, "U3"))) \
            if a.dtype.kind in "biuf" else np.array(3.5)
    return _npz_bytes(arrays)


def mutate_zip(data: bytes, rng: random.Random):
    """A mutation of the zip container of an npz: the encrypted flag, another compression
    method, sizes in the directory that the entry does not hold, or an entry deflated at
    deflate's own limit (~1030:1) declaring more than the reader's size limit."""
    b = bytearray(data)
    headers = [(m, 6 if sig == b"PK\x03\x04" else 8)
               for sig in (b"PK\x03\x04", b"PK\x01\x02") for m in _find_all(b, sig)]
    if not headers:
        return mutate_bytes(data, rng)
    op = rng.randrange(4)
    if op == 0:  # general-purpose flags: encrypted (bit 0), data descriptor, UTF-8 ...
        bit = rng.choice((0, 0, 3, 6, 11, 13))
        for at, offset in headers:
            b[at + offset] |= 1 << (bit % 8) if bit < 8 else 0
            b[at + offset + 1] |= 1 << (bit - 8) if bit >= 8 else 0
        return bytes(b), bit in (0, 6, 13)  # encryption flags: unreadable for certain
    if op == 1:  # compression method: stored, deflate, bzip2, lzma, unknown
        method = rng.choice((0, 8, 12, 14, 99))
        for at, offset in headers:
            b[at + offset + 2:at + offset + 4] = method.to_bytes(2, "little")
        return bytes(b)
    if op == 2:  # uncompressed size in the central directory: 0, small, 2^32 - 1
        at = rng.choice([m for m in _find_all(b, b"PK\x01\x02")] or [headers[0][0]])
        size = rng.choice((0, 1, 2**31, 2**32 - 1))
        b[at + 24:at + 28] = size.to_bytes(4, "little")
        return bytes(b)
    return _deflate_bomb(), True


def _find_all(data: bytes | bytearray, sig: bytes) -> list[int]:
    found, at = [], data.find(sig)
    while at >= 0:
        found.append(at)
        at = data.find(sig, at + 1)
    return found


def _deflate_bomb() -> bytes:
    """An npz whose one entry is an honest deflate stream of zeros declaring 1.25 GiB
    (1.3 MB of file; the reader must refuse it from the directory, before inflating).

    Built without deflating 1.25 GiB (6.6 s of CPU): each 16 MiB of zeros is deflated
    once and ended with a full flush, which resets the compressor, so that every further
    16 MiB is the same bytes again; the CRC-32 of the zeros comes from the CRC's own
    algebra (:func:`_crc32_zeros`). The stream inflates to the header and 1.25 GiB of
    zeros at deflate's ratio limit (1028:1, as one deflated in a piece; same CRC)."""
    global _BOMB
    if _BOMB is None:
        import zlib

        header = io.BytesIO()
        n = (5 << 28) // 4  # float32 elements: 1.25 GiB
        np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order":
                                                      False, "shape": (n,)})
        head = header.getvalue()
        comp = zlib.compressobj(9, zlib.DEFLATED, -15)
        first = comp.compress(head) + comp.flush(zlib.Z_FULL_FLUSH)
        chunk = comp.compress(bytes(1 << 24)) + comp.flush(zlib.Z_FULL_FLUSH)
        body = first + chunk * ((5 << 28) >> 24) + comp.flush()
        crc = _crc32_zeros(zlib.crc32(head), 5 << 28)
        info = zipfile.ZipInfo("xp.npy")
        info.compress_type = zipfile.ZIP_DEFLATED
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as zf:  # write the raw stream with its true sizes
            info.file_size, info.CRC = len(head) + (5 << 28), crc
            info.compress_size = len(body)
            zf.fp.write(info.FileHeader(zip64=True))
            zf.fp.write(body)
            zf.filelist.append(info)
            zf.NameToInfo[info.filename] = info
            info.header_offset = 0
            zf.start_dir = zf.fp.tell()
        _BOMB = buf.getvalue()
    return _BOMB


def _crc32_zeros(crc: int, n: int) -> int:
    """``zlib.crc32(bytes(n), crc)`` without reading n bytes: over a zero byte the CRC's
    register moves linearly (a 32 x 32 matrix over GF(2)), so n bytes are that matrix to
    the n-th power, by repeated squaring (zlib's crc32_combine)."""

    def times(matrix: list[int], vector: int) -> int:
        out, bit = 0, 0
        while vector:
            if vector & 1:
                out ^= matrix[bit]
            vector, bit = vector >> 1, bit + 1
        return out

    step = [0xEDB88320] + [1 << k for k in range(31)]  # one zero bit: shift, reduce
    for _ in range(3):  # one zero byte: eight bits
        step = [times(step, column) for column in step]
    register = crc ^ 0xFFFFFFFF
    while n:
        if n & 1:
            register = times(step, register)
        step = [times(step, column) for column in step]
        n >>= 1
    return register ^ 0xFFFFFFFF


_BOMB: bytes | None = None


def mutate_png(data: bytes, rng: random.Random):
    """One mutation of a PNG: its IHDR dimensions, bit depth or colour type (with the CRC
    made right, so that only the value is wrong), a truncated or dropped IDAT; or bytes.
    Dimensions of a gigapixel or more are invalid for certain."""
    import struct
    import zlib

    if rng.random() < 0.3 or data[12:16] != b"IHDR":
        return mutate_bytes(data, rng)
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    op = rng.randrange(4)
    must_fail = False
    if op == 0:
        width, height = (rng.choice((0, 1, width, 30000, 100000, 2**31 - 1, 2**32 - 1))
                         for _ in range(2))
        must_fail = width * height >= 1 << 30
    elif op == 1:
        depth = rng.choice((1, 2, 4, 8, 16, 32, 0))
    elif op == 2:
        colour = rng.choice((0, 2, 3, 4, 6, 7))
    else:
        at = data.find(b"IDAT") - 4
        cut = rng.randrange(at, len(data))
        return data[:cut] + (data[-12:] if rng.random() < 0.5 else b"")
    ihdr = struct.pack(">IIBB", width, height, depth, colour) + data[26:29]
    crc = struct.pack(">I", zlib.crc32(b"IHDR" + ihdr) & 0xFFFFFFFF)
    return data[:16] + ihdr + crc + data[33:], must_fail


_CSV_CELLS = ("x", "nan", "inf", "-inf", "", '"1,5"', "1e999", "0x10", " 3 ", "1;2", "TRUE",
              "NaN", "null", "#", '"', "1.5.5")


def mutate_csv(text: str, rng: random.Random):
    """One mutation of a CSV point table: a cell replaced (text, quoted commas, overflow),
    a row shortened or lengthened, a column renamed or dropped, a comment line. A word in
    a numeric cell is invalid for certain."""
    lines = text.splitlines()
    i = rng.randrange(1, len(lines))
    cells = lines[i].split(",")
    op = rng.randrange(5)
    must_fail = False
    if op == 0:
        j, cell = rng.randrange(len(cells)), rng.choice(_CSV_CELLS)
        cells[j] = cell
        must_fail = cell in ("x", "0x10", "1;2", "TRUE", "#", "1.5.5")
    elif op == 1:
        del cells[rng.randrange(len(cells)):]
    elif op == 2:
        cells.append(rng.choice(_CSV_CELLS))
    elif op == 3:
        header = lines[0].split(",")
        header[rng.randrange(len(header))] = rng.choice(("x_mm", "", "z", "sigma_model_um"))
        lines[0] = ",".join(header)
    else:
        lines.insert(i, rng.choice(("# scanqa-meta {", "# comment", "", ",,,")))
    lines[i] = ",".join(cells) if op != 4 else lines[i]
    return "\n".join(lines) + "\n", must_fail


def _npz_bytes_pickled(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # np.savez pickles object arrays: the reader must refuse them
    return buf.getvalue()


MUTATORS = {"ply": mutate_ply, "phase": mutate_npz, "table": mutate_npz,
            "patterns": lambda d, r: _text(mutate_toml, d, r),
            "layout": lambda d, r: _text(mutate_toml, d, r),
            "config": lambda d, r: _text(mutate_toml, d, r),
            "image": mutate_png, "stack": mutate_npz,
            "csv": lambda d, r: _text(mutate_csv, d, r)}


def _text(mutator, data: bytes, rng: random.Random):
    if rng.random() < 0.3:
        return mutate_bytes(data, rng)
    try:
        out = mutator(data.decode("utf-8"), rng)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return mutate_bytes(data, rng)
    text, must_fail = out if isinstance(out, tuple) else (out, False)
    return text.encode("utf-8"), must_fail


# --------------------------------------------------------------------------- running


def signature(err: BaseException) -> str:
    """Exception type and the innermost scanqa frame: one key per distinct crash."""
    frames = [f for f in traceback.extract_tb(err.__traceback__) if "scanqa" in f.filename]
    where = f"{Path(frames[-1].filename).name}:{frames[-1].name}" if frames else "?"
    return f"{type(err).__name__} in {where}"


def run_case(argv: list[str]) -> tuple[int | None, str, BaseException | None]:
    """(exit code, stderr, escaped exception) of one in-process run."""
    from scanqa.cli import main

    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(err):
        warnings.simplefilter("ignore")
        try:
            return main(argv), err.getvalue(), None
        except BaseException as exc:  # the test's whole point: nothing may escape
            return None, err.getvalue(), exc


def _promise_kept(code: int | None, stderr: str, out: Path, case_dir: Path) -> str:
    """'' when the run kept the promise, else what it broke."""
    lines = [ln for ln in stderr.splitlines() if not ln.startswith("scanqa: warning:")]
    if code not in (0, 2):
        return f"exit code {code}"
    if code == 2 and (len(lines) != 1 or not lines[0].startswith("scanqa: ")):
        return f"stderr is not one 'scanqa: ' line: {stderr[:300]!r}"
    leftovers = [p.name for p in case_dir.rglob(".*")]
    if leftovers:
        return f"temporaries left: {leftovers}"
    if code == 2 and out.exists() and any(out.iterdir()):
        return f"partial output left: {sorted(p.name for p in out.iterdir())}"
    return ""


def fuzz_format(kind: str, cases: int, seed: int, work: Path, render_every: int = 25
                ) -> Outcome:
    """Run ``cases`` seeded mutations of format ``kind`` (module notes)."""
    rng = random.Random(f"{seed}-{kind}")
    base = work / "base"
    if not base.exists():
        write_inputs(base)
    original = (base / TARGET[kind]).read_bytes()
    result = Outcome()
    for i in range(cases):
        case_dir = work / f"{kind}-{i}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # casts of extreme values while mutating
            mutated = MUTATORS[kind](original, rng)
        data, must_fail = mutated if isinstance(mutated, tuple) else (mutated, False)
        paths = _case_inputs(base, case_dir, kind, data)
        out = case_dir / "out"
        if kind not in ("ply", "layout", "csv"):  # qa creates its folder, others need one
            out.mkdir()
        start = time.monotonic()
        with _fast_reports(i % render_every != 0):
            code, stderr, exc = run_case([*command(kind, paths, out), *QUIET])
        took = time.monotonic() - start
        result.slowest_s = max(result.slowest_s, took)
        result.cases += 1
        result.exits[code] += 1
        if exc is not None:
            text = "".join(traceback.format_exception(exc))
            result.tracebacks.append((i, signature(exc), text))
        else:
            broken = _promise_kept(code, stderr, out, case_dir)
            if took > SLOW_S:
                broken = f"{broken}; " if broken else "" + f"took {took:.0f} s (a hang)"
            if broken:
                result.broken_promises.append((i, broken))
            if must_fail and code == 0:
                result.silent.append(i)
        _remove(case_dir)
    return result


def _case_inputs(base: Path, case_dir: Path, kind: str, data: bytes) -> dict[str, Path]:
    """The inputs of one case: links to the valid files, the mutated one written."""
    import shutil

    case_dir.mkdir(parents=True)
    names = {"ply": "cloud.ply", "layout": "layout.toml", "config": "config.toml",
             "table": "table.npz", "phase": "phase.npz", "patterns": "patterns",
             "stack": "stack", "csv": "cloud.csv"}
    paths = {k: base / v for k, v in names.items()}
    if kind in FOLDER:
        shutil.copytree(base / FOLDER[kind], case_dir / FOLDER[kind])
        paths[FOLDER[kind]] = case_dir / FOLDER[kind]
    else:
        paths[kind] = case_dir / names[kind]
        if kind == "csv":  # its metadata sidecar goes along
            shutil.copy(base / "cloud.csv.json", case_dir / "cloud.csv.json")
    (case_dir / TARGET[kind]).write_bytes(data)
    return paths


@contextlib.contextmanager
def _fast_reports(fast: bool):
    """Skip the PNG rasterisation of report figures (the plots are still built): it
    costs seconds per report and reads no input."""
    from scanqa.report import html

    if not fast:
        yield
        return
    real = html.figure_data_uri

    def quick(fig, dpi: int = 100) -> str:
        import matplotlib.pyplot as plt

        plt.close(fig)
        return "data:image/png;base64,"

    html.figure_data_uri = quick
    try:
        yield
    finally:
        html.figure_data_uri = real


def _remove(folder: Path) -> None:
    import shutil

    shutil.rmtree(folder, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    """``python -m tests.fuzz CASES [SEED [FORMAT,...]]``: the nightly-size run with a
    report (every format by default)."""
    import tempfile

    args = argv if argv is not None else sys.argv[1:]
    cases = int(args[0]) if args else 400
    seed = int(args[1]) if len(args) > 1 else 0
    from .fuzz_physical import KINDS, fuzz_physical

    kinds = args[2].split(",") if len(args) > 2 else (*FORMATS, *(f"physical-{k}"
                                                                   for k in KINDS))
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        for kind in kinds:
            res = fuzz_physical(kind.split("-", 1)[1], cases, seed, Path(tmp)) \
                if kind.startswith("physical-") else fuzz_format(kind, cases, seed, Path(tmp))
            sigs = Counter(s for _, s, _ in res.tracebacks)
            print(f"{kind:16s} {res.cases} cases, exits {dict(res.exits)}, "
                  f"{len(res.tracebacks)} tracebacks {dict(sigs)}, "
                  f"{len(res.broken_promises)} broken promises, {len(res.silent)} silent "
                  f"{res.silent[:5]}, slowest {res.slowest_s:.1f} s", flush=True)
            for case, what in res.broken_promises[:5]:
                print(f"    case {case}: {what}")
            for silent in res.silent[:5] if kind.startswith("physical-") else ():
                print(f"    silent: {silent}")
            for sig in sigs:
                text = next(t for _, s, t in res.tracebacks if s == sig)
                print(f"    {sig}:\n" + "".join("      " + ln for ln in
                                                 text.splitlines(True)[-6:]))
            known = KNOWN_DECODER_CRASHES if kind == "patterns" else {}
            failures += len([t for t in res.tracebacks if t[1] not in known])
            failures += len(res.broken_promises) + len(res.silent)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak memory of the run: {peak_mb:.0f} MB")
    return 1 if failures or peak_mb > 1024 else 0


if __name__ == "__main__":
    sys.exit(main())
