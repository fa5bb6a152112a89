"""Nothing silent, round 2 (issue 27): the classes an independent adversary found.

Each test crafts the adversary's input in ``tmp_path`` (small, in milliseconds) and
checks the promise: one line ``scanqa: ...`` naming the file, the field and the fix, exit
2, no traceback, no allocation or decompression beyond the limit, no temporary left.
"""

from __future__ import annotations

import io
import os
import shutil
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from scanqa.cli import main
from scanqa.errors import InputError
from scanqa.io.guard import LIMIT_VARIABLE
from scanqa.io.images import read_image, read_stack
from scanqa.io.npzfile import load_npz
from scanqa.io.tomlfile import read_toml

from .smallcases import command, write_inputs


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    return write_inputs(tmp_path_factory.mktemp("inputs"))


def one_line_error(capsys, code: int) -> str:
    """The one stderr line of a failed run (asserts the promise)."""
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln and not ln.startswith("scanqa: warning:")]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("scanqa: "), err
    return lines[0]


def _patterns(inputs, tmp_path: Path) -> Path:
    folder = tmp_path / "patterns"
    shutil.copytree(inputs["patterns"], folder)
    return folder


def _decode(folder: Path, tmp_path: Path) -> list[str]:
    (tmp_path / "out").mkdir(exist_ok=True)
    return ["decode", str(folder), "--out", str(tmp_path / "out" / "phase.npz"), "-q"]


# ------------------------------------------------------------------ TOML


@pytest.mark.parametrize("opening", ["[", "{a = "])
def test_deeply_nested_toml_is_one_error(opening, inputs, tmp_path, capsys):
    closing = "]" if opening == "[" else "}"
    config = tmp_path / "config.toml"
    config.write_text(inputs["config"].read_text() + "deep = " + opening * 400
                      + closing * 400 + "\n")
    paths = {**inputs, "config": config}
    code = main([*command("config", paths, tmp_path), "-q"])
    message = one_line_error(capsys, code)
    assert str(config) in message and "nested 400 deep" in message


def test_toml_nesting_count_skips_strings_and_comments(tmp_path):
    path = tmp_path / "a.toml"
    path.write_text('a = "' + "[" * 100 + '"  # ' + "{" * 100 + "\nb = [[1], [2]]\n"
                    "c = '''" + "[" * 50 + "'''\n")
    assert read_toml(path, "test")["b"] == [[1], [2]]


def test_a_fifo_in_place_of_a_toml_file_is_refused(tmp_path):
    fifo = tmp_path / "config.toml"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        read_toml(fifo, "scanner config")


# ------------------------------------------------------------------ images


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR declares ``width`` x ``height`` 8-bit grey pixels and whose
    image data is a few bytes (the adversary's header-only bomb)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("side", [30000, 100000])
def test_png_header_claiming_huge_dimensions(side, inputs, tmp_path, capsys):
    folder = _patterns(inputs, tmp_path)
    (folder / "p1280_00.png").write_bytes(_png_header(side, side))
    message = one_line_error(capsys, main(_decode(folder, tmp_path)))
    assert "p1280_00.png" in message
    assert not any((tmp_path / "out").iterdir())


def test_image_size_limit_is_checked_before_decoding(tmp_path, monkeypatch):
    """Below Pillow's own bomb limit, scanqa's size limit refuses before decoding."""
    path = tmp_path / "big.png"
    path.write_bytes(_png_header(4000, 4000))
    monkeypatch.setenv(LIMIT_VARIABLE, "1")
    with pytest.raises(InputError, match=r"declares 4000 x 4000 px.*SCANQA_MAX_INPUT_MB"):
        read_image(path)


def test_a_fifo_named_in_patterns_toml_does_not_block_decode(inputs, tmp_path, capsys):
    folder = _patterns(inputs, tmp_path)
    (folder / "p80_02.png").unlink()
    os.mkfifo(folder / "p80_02.png")
    message = one_line_error(capsys, main(_decode(folder, tmp_path)))  # returns at once
    assert "p80_02.png" in message and "not a regular file" in message


# ------------------------------------------------------------------ stacks and npz


def _npy_header(shape: tuple, dtype: str = "<u2") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue() + bytes(64)


def test_stack_npy_header_claiming_149_gib(tmp_path):
    path = tmp_path / "stack.npy"
    path.write_bytes(_npy_header((4, 100000, 100000), "<f4"))
    with pytest.raises(InputError, match=r"stack.npy.*declares shape \(4, 100000, 100000\)"):
        read_stack(path)


def test_stack_npz_header_claiming_149_gib(tmp_path):
    path = tmp_path / "stack.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("frames.npy", _npy_header((4, 100000, 100000), "<f4"))
    with pytest.raises(InputError, match=r"stack.npz, entry 'frames'.*declares shape"):
        read_stack(path)


def test_truncated_stack_npz(tmp_path):
    path = tmp_path / "stack.npz"
    np.savez(path, frames=np.zeros((4, 8, 8), np.uint8))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(InputError, match=r"stack\.npz: damaged or not an \.npz file"):
        read_stack(path)


def test_npz_entry_with_the_encrypted_flag(inputs, tmp_path, capsys):
    data = bytearray(inputs["phase"].read_bytes())
    # set bit 0 (encrypted) of the general-purpose flags in every local and central header
    for sig, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        start = 0
        while (start := data.find(sig, start)) >= 0:
            data[start + offset] |= 1
            start += 4
    phase = tmp_path / "phase.npz"
    phase.write_bytes(bytes(data))
    out = tmp_path / "out"
    out.mkdir()
    code = main([*command("phase", {**inputs, "phase": phase}, out), "-q"])
    message = one_line_error(capsys, code)
    assert "phase.npz" in message and "encrypted" in message


def test_deflate_bomb_is_refused_before_decompression(tmp_path, monkeypatch):
    """An honest deflate stream at ~1000:1 (deflate's own limit) declaring more than the
    limit is refused from the archive's directory: nothing is decompressed."""
    monkeypatch.setenv(LIMIT_VARIABLE, "1")  # 1 MiB, so that a 4 MiB bomb suffices
    path = tmp_path / "bomb.npz"
    np.savez_compressed(path, xp=np.zeros((1024, 1024), np.float32))
    assert path.stat().st_size < 10_000
    import tracemalloc

    tracemalloc.start()
    with pytest.raises(InputError, match=r"bomb.npz: its entries declare 4194\d+ bytes"):
        load_npz(path, "phase map")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20
