"""The report's maps of many points drawn as one image (:func:`scanqa.report.plots.cell_map`):
the cell from the points' own spacing (:func:`scanqa.qa.results.map_cell_mm`), each cell
the value of its last point (what a scatter drawn in order shows on top), cells without
points blank, and the image where the points are."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from scanqa.qa.results import MAP_CELLS, map_cell_mm
from scanqa.report.plots import cell_map, new_figure


def test_the_cell_is_one_and_a_half_spacings_of_a_grid():
    x, y = np.meshgrid(np.arange(0, 20, 0.25), np.arange(-5, 5, 0.25))
    assert abs(map_cell_mm(x.ravel(), y.ravel()) - 0.375) < 1e-12
    # a sparse line of points: at least the span over MAP_CELLS
    xs = np.linspace(0.0, 800.0, 5)
    assert map_cell_mm(xs, np.zeros(5)) == 1.5 * 200.0
    # a dense one: 1.5 x 0.2 mm is less than the span over MAP_CELLS
    xs = np.linspace(0.0, 800.0, 4001)
    assert map_cell_mm(xs, np.zeros(4001)) == 800.0 / MAP_CELLS == 2.0


def test_each_cell_holds_its_last_point_and_empty_cells_are_blank():
    # cells of 1 mm from the lowest x and y (0.2, 0.1): points put by hand in three of
    # the six cells
    x = np.array([0.2, 0.7, 0.9, 1.5, 2.5, 2.6])
    y = np.array([0.1, 0.8, 0.3, 0.5, 1.5, 1.2])
    v = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    fig, ax = new_figure()
    im = cell_map(ax[0][0], x, y, v, 1.0, cmap="RdBu_r", vmin=-6, vmax=6)
    grid = np.ma.filled(im.get_array(), np.nan)
    want = np.array([[3.0, 4.0, np.nan],  # first row: the last of 1, 2, 3; then 4
                     [np.nan, np.nan, 6.0]])  # second row: 5 then 6 in the third cell
    np.testing.assert_array_equal(grid, want)
    assert im.get_extent() == [0.2, 3.2, 0.1, 2.1]
    assert im.norm.vmin == -6 and im.norm.vmax == 6
    plt.close(fig)
