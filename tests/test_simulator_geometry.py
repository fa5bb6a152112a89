"""The samples' geometry per row of tiles (scanqa.simulator.geometry): a tile's part of
its strip is bit for bit the tile's own geometry, so the images and the truth do not
change when the renderer casts strips instead of tiles (issue 31)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from scanqa.simulator import devices, experiments, render
from scanqa.simulator.geometry import (
    Points,
    StripGeometry,
    sample_geometry,
    strips,
    supersample_grid,
)


@pytest.mark.parametrize("name, offset", [("gauge-blocks", 0.0), ("camera-sweep", 7.0)])
def test_a_tiles_part_of_its_strip_is_its_own_geometry(paper_config, name, offset):
    """Gauge blocks (edges, shadows: every field varies) and a moved camera (a rotated
    camera pose); a window 1.2 tiles wide and a little over one tile high, so that there
    are whole and partial tiles and the second, shorter strip reuses the first's
    buffers."""
    config = paper_config.replace_simulator(roi_width_px=int(1.2 * render.TILE_PX),
                                            roi_height_px=render.TILE_PX + 4)
    pos = experiments.build_positions(name, config, [offset])[0]
    acq = experiments.acquisition(config, pos, 0)
    win = devices.sensor_window(config)
    halo = render.halo_px(config, acq)
    tiles = render._tiles(win)
    assert strips(tiles) == [[0, 1], [2, 3]]
    strip = StripGeometry()
    lit = 0
    with ThreadPoolExecutor(2) as pool:
        for row in strips(tiles):
            strip.cast(config, acq, win, tiles[row[0]], halo, pool, threads=1)
            for tile in (tiles[n] for n in row):
                uu, vv = supersample_grid(config, win, tile, halo)
                own = sample_geometry(config, acq, uu, vv, threads=1)
                su, sv, part = strip.tile(config, win, tile, halo)
                np.testing.assert_array_equal(su, uu)
                np.testing.assert_array_equal(sv, vv)
                for field in Points.__dataclass_fields__:
                    a, b = getattr(part, field), getattr(own, field)
                    assert a.shape == b.shape and a.flags.c_contiguous, field
                    assert np.array_equal(a, b, equal_nan=True), field  # bit for bit
                assert own.hit.any()
                lit += int(own.lit.sum())
    assert lit > 0
