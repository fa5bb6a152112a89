"""Synthetic captures of the codings of docs/codings.rst, decoded against their truth.

The camera images are made here, independently of the decoder's own pattern
definitions: Gray-code panels come from OpenCV's ``GrayCodePattern`` (cells of 8
projector columns: OpenCV's pattern of a 160-column panel, each column repeated 8
times) or from the reflected Gray code written out below; phase frames from the
formula of each set. Each capture decodes to its truth within the predicted sigma,
with no fringe-order error among valid pixels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.decoding.chain import plan_chain
from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
)
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.phasemap import MASK_OUT_OF_RANGE, MASK_VALID

cv2 = pytest.importorskip("cv2")

SHAPE = (96, 256)
THREE = (0.0, 2 * math.pi / 3, 4 * math.pi / 3)


def _truth(width: float, seed: int, shape=SHAPE) -> np.ndarray:
    """Projector coordinate seen by every camera pixel, uniform over [0, width - 1]."""
    return np.random.default_rng(seed).uniform(0.0, width - 1.0, shape)


def _phase_frames(x: np.ndarray, period: float, shifts, a=600.0, b=400.0, gamma=1.0):
    """Frames A - B + 2 B p**gamma of p = 0.5 + 0.5 cos(2 pi x / P + delta) [DN]."""
    p = [0.5 + 0.5 * np.cos(2 * np.pi * x / period + d) for d in shifts]
    return np.stack([a - b + 2 * b * q ** gamma for q in p])


def _panel_frames(x: np.ndarray, panels: np.ndarray, a=600.0, b=400.0) -> np.ndarray:
    """Camera frames of binary panel rows (frames, columns) in {0, 1} at coordinate x."""
    column = np.clip(np.rint(x), 0, panels.shape[1] - 1).astype(int)
    return a - b + 2 * b * panels[:, column]


def _camera(frames: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Gaussian noise, 12-bit quantisation."""
    return np.clip(np.rint(frames + rng.normal(0.0, sigma, frames.shape)), 0,
                   4095).astype(np.uint16)


def _gaussian(sigma: float) -> SensorModel:
    gain = 1e9
    return SensorModel(bit_depth=12, gain_e_per_dn=gain, read_noise_e=sigma * gain)


def _check(pm, truth: np.ndarray, period: float, min_valid: float = 0.98) -> float:
    """No fringe-order error among valid pixels; return std(error / sigma)."""
    valid = pm.valid
    assert valid.mean() >= min_valid, pm.summary()
    err = pm.xp[valid] - truth[valid]
    assert np.abs(err).max() < period / 4  # a wrong order is off by a whole period
    return float(np.std(err / pm.sigma_xp[valid]))


# ------------------------------------------------------------------------- OpenCV

def _opencv_gray(cells: int, cell_px: int) -> np.ndarray:
    """OpenCV's column patterns (bit, inverse, bit, ...) of a ``cells``-wide panel,
    each column repeated ``cell_px`` times: (2 bits, cells * cell_px) in {0, 1}."""
    pattern = cv2.structured_light.GrayCodePattern.create(cells, 2)
    ok, images = pattern.generate()
    assert ok
    bits = math.ceil(math.log2(cells))
    rows = np.array([img[0] for img in images[:2 * bits]], float) / 255.0
    return np.repeat(rows, cell_px, axis=1)


def test_opencv_gray_cells_order_two_non_nested_three_step_sets():
    # projector 1280 px: OpenCV Gray code of 8 px cells with interleaved inverses,
    # white and black frames, 3-step sets of 48 and 40 px (neither divides the other)
    width, cell = 1280, 8
    panels = _opencv_gray(width // cell, cell)
    bits = panels.shape[0] // 2
    desc = PatternDescription(width, (
        ReferenceSet("wb"), GrayCodeSet("g", bits, cell_px=float(cell), inverse="interleaved"),
        PhaseSet("p48", 48.0, 3), PhaseSet("p40", 40.0, 3)))
    x = _truth(width, 1)
    rng = np.random.default_rng(1)
    white_black = np.stack([np.full(SHAPE, 1000.0), np.full(SHAPE, 200.0)])
    images = [_camera(white_black, rng, 4.0), _camera(_panel_frames(x, panels), rng, 4.0),
              _camera(_phase_frames(x, 48.0, THREE), rng, 4.0),
              _camera(_phase_frames(x, 40.0, THREE), rng, 4.0)]
    pm = decode_images(desc, images)
    ratio = _check(pm, x, 40.0)
    assert ratio == pytest.approx(1.0, abs=0.12)  # predicted sigma within 12 %
    assert pm.period_px == 40.0
    # the noise came from the two phase sets' offsets (the phase frames' own noise),
    # and the summary says so
    assert "offsets of the phase sets" in pm.summary()
    # OpenCV's own decoder finds the same cell; it also wants the row code, which
    # this capture does not have: the frames of projector row 0 stand in for it
    gray = cv2.structured_light.GrayCodePattern.create(width // cell, 2)
    rows = [np.full(SHAPE, 62 if img[0, 0] else 12, np.uint8)
            for img in gray.generate()[1][2 * bits:]]
    stack = [(img // 16).astype(np.uint8) for img in images[1]] + rows
    for v, u in [(5, 7), (40, 100), (90, 250), (17, 33), (60, 128)]:
        err, (col, _) = gray.getProjPixel(stack, u, v)
        assert not err and pm.valid[v, u]
        assert abs(col * cell + (cell - 1) / 2 - pm.xp[v, u]) <= cell / 2 + 0.5


def test_gray_cell_equal_to_the_period_orders_its_set():
    # m = 1: cells as wide as the period; pixels too close to a cell edge for their
    # noise are masked, every other pixel is ordered right
    width, cell = 1024, 32
    desc = PatternDescription(width, (GrayCodeSet("g", 5, cell_px=32.0, inverse="grouped"),
                                      PhaseSet("p32", 32.0, 4)))
    x = _truth(width, 2)
    rng = np.random.default_rng(2)
    images = [_camera(_panel_frames(x, _gray_panels(width, cell, 5, "grouped")), rng, 3.0),
              _camera(_phase_frames(x, 32.0, [k * math.pi / 2 for k in range(4)]), rng, 3.0)]
    pm = decode_images(desc, images)
    _check(pm, x, 32.0, min_valid=0.9)


# ------------------------------------------------------------------- Gray alone

def _gray_panels(width: int, cell: int, bits: int, inverse: str = "none") -> np.ndarray:
    """Reflected Gray code of the column's cell, most significant bit first."""
    c = np.arange(width) // cell
    code = c ^ (c >> 1)
    planes = np.array([(code >> (bits - 1 - b)) & 1 for b in range(bits)], float)
    if inverse == "grouped":
        return np.concatenate([planes, 1 - planes])
    if inverse == "interleaved":
        return np.stack([p for plane in planes for p in (plane, 1 - plane)])
    return planes


def test_gray_code_alone_gives_cell_centres_with_quantisation_noise():
    # SLStudio's layout: white, black, then 10 bit planes of 2-column cells
    width = 1824
    desc = PatternDescription(width, (ReferenceSet("wb", ("white", "black")),
                                      GrayCodeSet("g", 10, cell_px=2.0)))
    x = _truth(width, 3, (128, 512))
    rng = np.random.default_rng(3)
    images = [_camera(np.stack([np.full(x.shape, 900.0), np.full(x.shape, 100.0)]), rng, 3.0),
              _camera(_panel_frames(x, _gray_panels(width, 2, 10), 500.0, 400.0), rng, 3.0)]
    pm = decode_images(desc, images)
    assert pm.valid.mean() > 0.99
    column = np.rint(x)
    centre = (column // 2) * 2 + 0.5  # cell of the column the pixel sees
    np.testing.assert_allclose(pm.xp[pm.valid], centre[pm.valid], atol=1e-9)
    # sigma is the quantisation of the cell, 2 / sqrt(12) px, and holds against truth
    np.testing.assert_allclose(pm.sigma_xp[pm.valid], 2 / math.sqrt(12), rtol=1e-6)
    err = pm.xp[pm.valid] - x[pm.valid]
    assert np.std(err) == pytest.approx(2 / math.sqrt(12), rel=0.03)
    assert np.abs(err).max() <= 1.5  # half a cell plus the rounding to a column
    assert pm.period_px == 2.0


def test_gray_alone_without_a_threshold_is_refused():
    from scanqa.errors import ConfigError

    with pytest.raises(ConfigError, match="a Gray code alone needs a threshold per pixel"):
        PatternDescription(64, (GrayCodeSet("g", 6, cell_px=1.0),))


# -------------------------------------------------------------------- heterodyne

def test_heterodyne_triple_unwraps_without_a_coarse_period():
    # 70, 64 and 59 fringes over 1280 px: no period covers the panel; the beat
    # (70 - 2 x 64 + 59) does, the beat of 70 and 59 bridges to the sets
    width = 1280
    periods = [width / v for v in (59, 64, 70)]
    sets = tuple(PhaseSet(f"v{v}", width / v, 4) for v in (59, 64, 70))
    desc = PatternDescription(width, sets, sensor=_gaussian(2.0))
    steps = plan_chain(periods, ["v59", "v64", "v70"], width, 64.0)
    assert [s.name for s in steps] == ["beat(v59+v70-2 v64)", "beat(v70-v59)", "v59", "v64",
                                       "v70"]
    assert steps[0].period_px == pytest.approx(1280.0)
    x = _truth(width, 4)
    rng = np.random.default_rng(4)
    shifts = [k * math.pi / 2 for k in range(4)]
    images = [_camera(_phase_frames(x, p, shifts, 1500.0, 1000.0), rng, 2.0) for p in periods]
    pm = decode_images(desc, images)
    assert _check(pm, x, periods[-1]) == pytest.approx(1.0, abs=0.1)


def test_two_frequency_heterodyne_of_66_7_and_100():
    width = 200
    desc = PatternDescription(width, (PhaseSet("p100", 100.0, 4),
                                      PhaseSet("p66", 200 / 3, 4)), sensor=_gaussian(2.0))
    x = _truth(width, 5)
    rng = np.random.default_rng(5)
    shifts = [k * math.pi / 2 for k in range(4)]
    images = [_camera(_phase_frames(x, p, shifts, 1500.0, 1000.0), rng, 2.0)
              for p in (100.0, 200 / 3)]
    pm = decode_images(desc, images)
    assert _check(pm, x, 200 / 3) == pytest.approx(1.0, abs=0.1)


# -------------------------------------------------------------- misstatements

def _hierarchy_scan(panel: int, periods, seed: int, sigma: float = 2.0):
    x = _truth(panel, seed)
    rng = np.random.default_rng(seed)
    shifts = [k * math.pi / 2 for k in range(4)]
    return x, [_camera(_phase_frames(x, p, shifts, 1500.0, 1000.0), rng, sigma)
               for p in periods]


def _never_valid_wrong(pm, x):
    """Every valid pixel is right (within 1 px); return the valid share."""
    err = np.abs(pm.xp - x)[pm.valid]
    assert err.size == 0 or err.max() < 1.0, (err.max(), pm.summary())
    return float(pm.valid.mean())


def test_misstated_width_is_masked_or_refused():
    from scanqa.errors import ConfigError

    # a 1280 px panel coded by 1280/96/16, stated as 1000 px wide: the pixels beyond
    # are out of range, none is valid and wrong
    x, images = _hierarchy_scan(1280, (1280.0, 96.0, 16.0), 6)
    sets = tuple(PhaseSet(f"p{p:g}", p, 4) for p in (1280.0, 96.0, 16.0))
    pm = decode_images(PatternDescription(1000, sets, sensor=_gaussian(2.0)), images)
    assert _never_valid_wrong(pm, x) > 0.7
    assert not pm.valid[x > 1000.0].any()
    assert (pm.mask[(x > 1000.0) & (x < 1139.0)] == MASK_OUT_OF_RANGE).all()
    # a 1824 px panel coded by 1280/96/16 (the coarse period does not cover it) stated
    # as 1280 px to pass the check: where the coarse phase wraps, the 96 px set
    # disagrees by 1280/96 - 13 = 1/3 cycle, so those pixels are inconsistent
    x, images = _hierarchy_scan(1824, (1280.0, 96.0, 16.0), 7)
    pm = decode_images(PatternDescription(1280, sets, sensor=_gaussian(2.0)), images)
    _never_valid_wrong(pm, x)
    assert pm.valid[x < 1279.0].mean() > 0.98
    # stated wider than the coarse period: refused, naming both
    with pytest.raises(ConfigError, match=r"coarsest period_px = 1280 .* shorter than "
                                          r"projector_width_px = 1824, .* check "
                                          r"projector_width_px and period_px"):
        PatternDescription(1824, sets)


def test_misstated_gray_width_is_masked_or_refused():
    from scanqa.errors import ConfigError

    width = 1824
    x = _truth(width, 8, (64, 256))
    rng = np.random.default_rng(8)
    images = [_camera(np.stack([np.full(x.shape, 900.0), np.full(x.shape, 100.0)]), rng, 3.0),
              _camera(_panel_frames(x, _gray_panels(width, 2, 10), 500.0, 400.0), rng, 3.0)]
    sets = (ReferenceSet("wb"), GrayCodeSet("g", 10, cell_px=2.0))
    pm = decode_images(PatternDescription(1200, sets), images)
    assert (pm.mask[x > 1201.0] == MASK_OUT_OF_RANGE).all()
    assert np.abs(pm.xp - x)[pm.valid].max() <= 1.5
    with pytest.raises(ConfigError, match=r"codes 1024 cells of 2 px = 2048 px \(bits = "
                                          r"10, 10 frames\) < projector_width_px = 3000; "
                                          r"check projector_width_px") as err:
        PatternDescription(3000, sets)
    assert "bits =" not in str(err.value).split("; check")[1]  # no impossible fix


@pytest.mark.parametrize("stated_cell", [4.0, 16.0])
def test_misstated_gray_cell_width_is_masked(stated_cell):
    # the OpenCV-style capture of 8 px cells, described with cells of 4 or 16 px
    width, cell = 1280, 8
    panels = _opencv_gray(width // cell, cell)
    bits = panels.shape[0] // 2
    x = _truth(width, 9)
    rng = np.random.default_rng(9)
    images = [_camera(_panel_frames(x, panels), rng, 3.0),
              _camera(_phase_frames(x, 48.0, THREE), rng, 3.0)]
    sets = (GrayCodeSet("g", bits, cell_px=stated_cell, inverse="interleaved"),
            PhaseSet("p48", 48.0, 3))
    if 2 ** bits * stated_cell < width:  # 4 px cells cannot cover the panel: refused
        from scanqa.errors import ConfigError

        with pytest.raises(ConfigError, match="check projector_width_px"):
            PatternDescription(width, sets)
        return
    pm = decode_images(PatternDescription(width, sets), images)
    _never_valid_wrong(pm, x)
    assert pm.valid.mean() < 0.01
    assert "misstated coding?" in pm.summary()


@pytest.mark.parametrize("stated", [(1280.0, 88.0, 16.0), (1280.0, 96.0, 17.6),
                                    (1408.0, 96.0, 16.0), (1200.0, 96.0, 16.0)])
def test_misstated_period_is_masked_or_refused(stated):
    # captured with 1280/96/16 px; one period stated 10 % off
    from scanqa.errors import ConfigError

    x, images = _hierarchy_scan(1280, (1280.0, 96.0, 16.0), 10)
    sets = tuple(PhaseSet(f"s{i}", p, 4) for i, p in enumerate(stated))
    if stated[0] < 1280:  # the coarse period no longer covers the panel: refused
        with pytest.raises(ConfigError, match="periods cannot be unwrapped"):
            PatternDescription(1280, sets)
        return
    pm = decode_images(PatternDescription(1280, sets, sensor=_gaussian(2.0)), images)
    assert _never_valid_wrong(pm, x) < 0.01
    assert "misstated coding?" in pm.summary()


def test_misstated_gray_period_is_masked():
    width, cell = 1280, 8
    panels = _opencv_gray(width // cell, cell)
    x = _truth(width, 11)
    rng = np.random.default_rng(11)
    images = [_camera(_panel_frames(x, panels), rng, 3.0),
              _camera(_phase_frames(x, 48.0, THREE), rng, 3.0)]
    sets = (GrayCodeSet("g", panels.shape[0] // 2, cell_px=8.0, inverse="interleaved"),
            PhaseSet("p", 52.0, 3))
    pm = decode_images(PatternDescription(width, sets), images)
    _never_valid_wrong(pm, x)
    assert pm.valid.mean() < 0.01
    assert pm.mask[~pm.valid].max() > MASK_VALID
