"""A plain binary code (``code = "binary"``), decoded against captures whose x_p is known.

The bit planes are written out here from the cell index in base 2 (most significant
first); the phase is a 4-step set whose period is two cells. A reflected Gray code reads
such a capture with wrong cells (binary 0110 is Gray for cell 4, not 6), so the
description's ``code`` decides.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
)
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.parsing import load_patterns
from scanqa.errors import ConfigError

WHITE, BLACK = 180.0, 30.0


def _sensor(sigma_dn: float) -> SensorModel:
    gain = 1e9
    return SensorModel(bit_depth=12, gain_e_per_dn=gain, read_noise_e=sigma_dn * gain)


def _binary_frames(cells: np.ndarray, bits: int) -> np.ndarray:
    """(bits, ...) intensities of the plain binary bit planes of ``cells`` [DN]."""
    return np.stack([np.where((cells >> (bits - 1 - b)) & 1, WHITE, BLACK)
                     for b in range(bits)]).astype(float)


def _capture(x: np.ndarray, cell: float, bits: int, period: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    cells = np.floor((x + 0.5) / cell).astype(np.int64)
    shifts = 2 * np.pi * np.arange(4)[:, None, None] / 4
    mid, amp = 0.5 * (WHITE + BLACK), 0.5 * (WHITE - BLACK)
    fringes = mid + amp * np.cos(2 * np.pi * x / period + shifts)
    ref = np.stack([np.full(x.shape, WHITE), np.full(x.shape, BLACK)])
    return [f + rng.normal(0.0, 1.0, f.shape) for f in (ref, _binary_frames(cells, bits),
                                                        fringes)]


def _coding(code: str, width: int = 512, cell: float = 16.0, bits: int = 5) -> PatternDescription:
    return PatternDescription(width, (ReferenceSet("wb", ("white", "black")),
                                      GrayCodeSet("g", bits, cell_px=cell, code=code),
                                      PhaseSet("p32", 2 * cell, 4)), sensor=_sensor(1.0))


def test_a_plain_binary_code_orders_the_phase_only_when_stated():
    x = np.linspace(3.0, 505.0, 1500)[None, :]
    stacks = _capture(x, 16.0, 5, 32.0)
    pm = decode_images(_coding("binary"), stacks)
    assert pm.valid.mean() > 0.95
    np.testing.assert_allclose(pm.xp[pm.valid], x[pm.valid], atol=0.3)  # sigma 0.05 px
    wrong = decode_images(_coding("reflected"), stacks)  # read as Gray: orders off
    right = wrong.valid & (np.abs(wrong.xp - x) < 1.0)
    assert right.sum() < 0.5 * pm.valid.sum()


def test_only_the_least_significant_bit_of_a_binary_code_makes_an_edge_pixel():
    # 4 bits of 2-px cells, alone: 6 = 0110 | 7 = 0111 differ in the least significant bit
    # (an edge pixel at 13.5 px); 7 = 0111 | 8 = 1000 differ in all four bits, so a grey
    # top bit alone names 7 and 15 = 1111, no neighbours (masked); every bit decided: the
    # centre of cell 9 = 1001, 18.5 px (cells 2 = 0010 and 12 = 1100 make every bit plane
    # differ from the others)
    cells = np.array([[6, 7, 9, 2, 12]])
    frames = _binary_frames(cells, 4)
    frames[3, 0, 0] = 0.5 * (WHITE + BLACK)
    frames[0, 0, 1] = 0.5 * (WHITE + BLACK)
    ref = np.stack([np.full(cells.shape, WHITE), np.full(cells.shape, BLACK)])
    desc = PatternDescription(32, (ReferenceSet("wb", ("white", "black")),
                                   GrayCodeSet("g", 4, cell_px=2.0, code="binary")),
                              sensor=_sensor(1.0))
    pm = decode_images(desc, [ref, frames])
    np.testing.assert_array_equal(pm.xp[0], [13.5, np.nan, 18.5, 4.5, 24.5])
    np.testing.assert_allclose(pm.sigma_xp[0, [0, 2]], [4 / math.sqrt(12), 2 / math.sqrt(12)],
                               rtol=1e-6)


def test_the_code_key_round_trips_and_is_checked(tmp_path):
    desc = _coding("binary")
    assert desc.to_dict()["set"][1]["code"] == "binary"
    assert "code" not in _coding("reflected").to_dict()["set"][1]  # the default, unwritten
    path = tmp_path / "patterns.toml"
    path.write_text('format = "scanqa-patterns/2"\nprojector_width_px = 512\n'
                    '[[set]]\nkind = "phase"\nperiod_px = 32\nsteps = 4\n'
                    'files = ["p0.png", "p1.png", "p2.png", "p3.png"]\n'
                    '[[set]]\nkind = "gray"\nbits = 5\ncode = "binary"\n'
                    'files = ["g0.png", "g1.png", "g2.png", "g3.png", "g4.png"]\n')
    assert load_patterns(path).gray_set.code == "binary"
    with pytest.raises(ConfigError, match="code"):
        GrayCodeSet("g", 4, code="gray")
