"""The Gray code's edge rule, against captures whose x_p is known.

A pixel with exactly one undecidable bit whose two candidate codes are neighbouring
cells k and k + 1 is decoded to their shared edge ``(k + 1) cell_px - 1/2`` with
sigma_xp = 2 cell_px / sqrt(12) (uniform over the two cells); every other undecidable
pixel stays masked. The camera images are made here from the reflected Gray code
written out below, seen through a projector with a Gaussian blur (the exact integral of
each panel column over the blur, with ``scipy.special.ndtr``), so that the truth is
known to every pixel; the decoder knows nothing of the blur.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtr

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
)
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.phasemap import MASK_LOW_MODULATION

WIDTH, CELL, BITS = 512, 2.0, 8
WHITE, BLACK = 160.0, 40.0  # a dim capture: contrast 120 DN against 3 DN of noise
SIGMA_DN = 3.0


def _sensor(sigma_dn: float) -> SensorModel:
    """A camera with Gaussian noise of sigma_dn [DN] at every level."""
    gain = 1e9
    return SensorModel(bit_depth=12, gain_e_per_dn=gain, read_noise_e=sigma_dn * gain)


def _panels(width: int, cell: float, bits: int) -> np.ndarray:
    """(bits, width) panel rows in {0, 1}: bit planes of the reflected Gray code of each
    column's cell floor(j / cell), most significant first."""
    c = (np.arange(width) // cell).astype(np.int64)
    code = c ^ (c >> 1)
    return np.array([(code >> (bits - 1 - b)) & 1 for b in range(bits)], float)


def _blurred(panels: np.ndarray, x: np.ndarray, blur_px: float) -> np.ndarray:
    """(bits, *x.shape) panel values seen at x through a Gaussian of blur_px: column j
    (covering [j - 1/2, j + 1/2)) weighs Phi((j + 1/2 - x) / b) - Phi((j - 1/2 - x) / b)."""
    reach = math.ceil(8 * blur_px) + 1
    out = np.zeros((panels.shape[0], *x.shape))
    for offset in range(-reach, reach + 1):
        j = np.floor(x).astype(int) + offset
        weight = ndtr((j + 0.5 - x) / blur_px) - ndtr((j - 0.5 - x) / blur_px)
        out += panels[:, np.clip(j, 0, panels.shape[1] - 1)] * weight
    return out


def _capture(x: np.ndarray, blur_px: float, seed: int) -> list[np.ndarray]:
    """White, black and the Gray frames of a blurred projector, with Gaussian noise."""
    rng = np.random.default_rng(seed)
    seen = _blurred(_panels(WIDTH, CELL, BITS), x, blur_px)
    ref = np.stack([np.full(x.shape, WHITE), np.full(x.shape, BLACK)])
    gray = BLACK + (WHITE - BLACK) * seen
    return [f + rng.normal(0.0, SIGMA_DN, f.shape) for f in (ref, gray)]


def _coding(**kw) -> PatternDescription:
    return PatternDescription(WIDTH, (ReferenceSet("wb", ("white", "black")),
                                      GrayCodeSet("g", BITS, cell_px=CELL)),
                              sensor=_sensor(SIGMA_DN), **kw)


def _on_edge(pm) -> np.ndarray:
    """Valid pixels whose x_p is a cell edge, (k + 1) cell - 1/2 (not a centre)."""
    return pm.valid & np.isclose(np.mod(pm.xp + 0.5, CELL), 0.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("blur_px", [0.8, 2.0])
def test_edge_pixels_take_the_edge_within_their_sigma(blur_px):
    # measured: 0.8 px of blur, 19 % of the pixels are edge pixels, rms error 0.13 px,
    # at most 0.41 px; 2.0 px (the finest stripes, 4 px wide, keep about a third of their
    # contrast), 57 %, rms 0.41 px, at most 1.66 px - deep into their cells, as the
    # stated distribution allows (with 2.5 px the code itself fails: cell pixels, too,
    # leave their cell)
    x = np.random.default_rng(1).uniform(0.0, WIDTH - 1.0, (96, 512))
    pm = decode_images(_coding(), _capture(x, blur_px, 2))
    edge, cell = _on_edge(pm), pm.valid & ~_on_edge(pm)
    sigma = 2 * CELL / math.sqrt(12)
    np.testing.assert_allclose(pm.sigma_xp[edge], sigma, rtol=1e-6)
    np.testing.assert_allclose(pm.sigma_xp[cell], CELL / math.sqrt(12), rtol=1e-6)
    err = (pm.xp - x)[edge]
    print(f"blur {blur_px} px: {100 * pm.valid.mean():.1f} % valid, {edge.sum()} edge "
          f"pixels, rms error {np.sqrt(np.mean(err ** 2)):.3f} px (stated {sigma:.3f}), "
          f"max {np.abs(err).max():.3f} px")
    assert edge.sum() > 0.15 * x.size
    # the stated distribution (uniform over the two cells) holds: every error within its
    # support of one cell, and no more spread than stated
    assert np.abs(err).max() <= CELL
    assert np.sqrt(np.mean(err ** 2)) <= sigma
    assert np.mean(np.abs(err) <= sigma) >= 0.95
    # cell pixels keep their centre: the truth lies in the decoded cell
    inside = np.abs(pm.xp - x)[cell] <= 0.5 * CELL
    assert np.mean(inside) > 0.999
    line = next(s for s in pm.summary().splitlines() if s.startswith("x_p:"))
    assert f"; {edge.sum()} edge pixels (" in line


def test_edge_pixels_near_their_edge_under_light_blur():
    # with a 0.8 px blur a bit reads grey only close to its edge: edge pixels lie within
    # 0.5 px of the edge given to them (their stated sigma is 1.15 px: conservative)
    x = np.random.default_rng(3).uniform(0.0, WIDTH - 1.0, (64, 512))
    pm = decode_images(_coding(), _capture(x, 0.8, 4))
    edge = _on_edge(pm)
    truth_edge = np.rint((x + 0.5) / CELL) * CELL - 0.5  # the nearest cell edge
    np.testing.assert_array_equal(pm.xp[edge], truth_edge[edge])
    assert np.abs(pm.xp - x)[edge].max() < 0.5
    # without the rule (every undecidable bit masks its pixel) they would be masked
    assert pm.valid.mean() > 0.99 and edge.mean() > 0.15


def _frames_of(cells_and_grey: list[tuple[int, tuple[int, ...]]], bits: int) -> np.ndarray:
    """(bits, 1, n) Gray frames: pixel i shows cell c_i, with the listed bits grey."""
    mid = 0.5 * (WHITE + BLACK)
    out = np.empty((bits, 1, len(cells_and_grey)))
    for i, (c, grey) in enumerate(cells_and_grey):
        code = c ^ (c >> 1)
        for b in range(bits):
            out[b, 0, i] = mid if b in grey else (WHITE if code >> (bits - 1 - b) & 1
                                                   else BLACK)
    return out


def test_only_a_single_bit_between_neighbouring_cells_is_an_edge():
    # 4 bits, cells of 2 px. Flipping Gray bit b (most significant first) flips binary
    # bits b and below: cell 7 = 0111 and 8 = 1000 differ in the top Gray bit only, as do
    # 5 = 0101 and 10 = 1010 (not neighbours); 6 = 0110 and 5 in bit 2, 4 = 0100 and 7 too
    pixels = [(5, (3,)),        # least significant bit: always neighbours, 4 | 5
              (7, (0,)),        # top bit: 7 | 8
              (6, (2,)),        # 5 | 6
              (5, (0,)),        # top bit, candidates 5 and 10: masked
              (4, (2,)),        # candidates 4 and 7: masked
              (5, (2, 3)),      # two undecidable bits: masked
              (0, (0, 1, 2, 3)),  # dark: masked
              (9, ())]          # every bit decided: the centre of cell 9
    gray = _frames_of(pixels, 4)
    ref = np.stack([np.full((1, len(pixels)), WHITE), np.full((1, len(pixels)), BLACK)])
    desc = PatternDescription(32, (ReferenceSet("wb", ("white", "black")),
                                   GrayCodeSet("g", 4, cell_px=2.0)), sensor=_sensor(1.0))
    pm = decode_images(desc, [ref, gray])
    edge, centre = 4 / math.sqrt(12), 2 / math.sqrt(12)
    expected = [9.5, 15.5, 11.5, np.nan, np.nan, np.nan, np.nan, 18.5]
    np.testing.assert_array_equal(pm.xp[0], expected)
    np.testing.assert_allclose(pm.sigma_xp[0], [edge, edge, edge, np.nan, np.nan, np.nan,
                                                np.nan, centre], rtol=1e-6)
    assert (pm.mask[0, 3:7] == MASK_LOW_MODULATION).all()
    assert "3 edge pixels (75.0 % of the valid" in pm.summary()


def test_the_phase_orders_an_edge_pixel_unless_it_wraps_inside_the_two_cells():
    # cells of 8 px ordering a 16 px phase: an edge pixel lies in one of two cells,
    # 16 px together; the phase names one place in them unless it falls within the
    # edge tolerance (gray_edge_cells) of their ends, where it wraps
    width, a, b = 128, 100.0, 60.0
    x = np.array([[7.5, 20.0, 12.0, 0.0]])  # edge 0|1 at its middle; inside cell 2;
    # edge 1|2 (x 7.5..23.5) 3.5 px from its middle; edge 0|1 0.5 px from its end
    phase = PhaseSet("p16", 16.0, 4)
    shifts = np.asarray(phase.shifts_rad)[:, None, None]
    fringes = a + b * np.cos(2 * np.pi * x / 16.0 + shifts)
    cells = np.floor((x + 0.5) / 8.0).astype(int)
    code = cells ^ (cells >> 1)
    gray = np.stack([np.where(code >> (4 - 1 - k) & 1, a + b, a - b) for k in range(4)])
    gray[3, 0, 0] = a  # the least significant bit reads grey: edge of cells 0 | 1
    gray[2, 0, 2] = a  # bit 2 reads grey: edge of cells 1 | 2
    gray[3, 0, 3] = a
    desc = PatternDescription(width, (phase, GrayCodeSet("g", 4, cell_px=8.0)),
                              sensor=_sensor(1.0))
    pm = decode_images(desc, [fringes, gray.astype(float)])
    assert pm.valid[0, :3].all()
    np.testing.assert_allclose(pm.xp[0, :3], x[0, :3], atol=0.05)
    assert pm.mask[0, 3] == MASK_LOW_MODULATION


def test_the_span_of_a_pixel_is_the_block_its_undecidable_bits_reach():
    # 4 bits; by hand: cell 5 = Gray 0111. Bit 1 (of 0..3, most significant first)
    # undecidable leaves the aligned block of 8 cells 0..7; bits 2 and 3 the block 4..7;
    # bit 3 alone is an edge pixel of cells 5 | 4 (Gray 0111 / 0110): span 2 from 4;
    # nothing undecidable: span 1
    from scanqa.decoding.gray import decode_gray

    gray = GrayCodeSet("g", 4, cell_px=1.0, inverse="grouped")
    code = np.array([0, 1, 1, 1], float)
    bits = np.tile(code[:, None], (1, 4))
    bits[1, 0] = 0.5
    bits[2:, 1] = 0.5
    bits[3, 2] = 0.5
    frames = np.concatenate([bits, 1.0 - bits]) * 100.0
    dec = decode_gray(gray, frames, _sensor(1.0), False, 3.0)
    np.testing.assert_array_equal(dec.first, [0, 4, 4, 5])
    np.testing.assert_array_equal(dec.span, [8, 4, 2, 1])
    np.testing.assert_array_equal(dec.edge, [False, False, True, False])
