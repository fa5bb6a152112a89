"""numba is optional (``pip install 'scanqa[fast]'``): the numpy paths a lean install takes.

Without numba (or with ``SCANQA_NO_NUMBA=1``, :mod:`scanqa.compiled`) the simulator
takes the numpy twins of its compiled loops (``raykernels.*_numpy``), the numpy geometry
and open3d's cast for every ray, and annotate its numpy path (that one is compared with
the compiled pass in test_annotkernels.py). Here each twin is compared with the compiled
loop it replaces, and a small scan rendered in a child process without numba with the
same scan rendered here with it. Tolerances follow the operations (tests/cpu_targets.py):
the two paths are different code, so nothing float is compared bit for bit.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scanqa import compiled
from scanqa.simulator import blur, experiments, raykernels, render
from scanqa.simulator.optics_kernels import DiscAverage

from .conftest import PAPER_CONFIG
from .cpu_targets import op_bound

ROOT = Path(__file__).resolve().parents[1]
needs_numba = pytest.mark.skipif(not compiled.HAVE_NUMBA,
                                 reason="numba not installed: nothing compiled to compare")


@needs_numba
@pytest.mark.compiled_vs_numpy
def test_frame_twins_agree_with_the_loops():
    rng = np.random.default_rng(11)
    base = rng.uniform(0, 4e4, (120, 130)).astype(np.float32)
    q_re, q_im = (rng.normal(0, 1e4, base.shape).astype(np.float32) for _ in range(2))
    c, s = np.float32(np.cos(0.7)), np.float32(np.sin(0.7))
    got, want = base.copy(), base.copy()
    raykernels.add_fringe(want, c, q_re, s, q_im)
    raykernels.add_fringe_numpy(got, c, q_re, s, q_im)
    # two float32 products and two adds on terms up to 4e4 + 2e4 |q|
    tol = op_bound(4, np.abs(base) + 5e4, np.float32)
    assert np.all(np.abs(got - want) <= tol)

    cells = rng.normal(size=(7, 9)).astype(np.float32)
    index = rng.integers(0, cells.size, base.shape).astype(np.intp)
    scale = rng.uniform(0, 300, base.shape).astype(np.float32)
    raykernels.add_cell_noise(want, cells, index, scale)
    raykernels.add_cell_noise_numpy(got, cells, index, scale)
    assert np.all(np.abs(got - want) <= tol + op_bound(2, np.abs(want), np.float32))

    fine = rng.uniform(0, 4e4, (3 * 40, 3 * 43)).astype(np.float32)
    out_c = rng.uniform(0, 4e4, (40, 43)).astype(np.float32)
    out_n = out_c.copy()
    raykernels.add_pixel_means(out_c, fine, 3)
    raykernels.add_pixel_means_numpy(out_n, fine, 3)
    # 9 adds of terms up to max(fine), a divide and the add, in float32, any order
    assert np.all(np.abs(out_c - out_n) <= op_bound(11, np.abs(out_c) + fine.max(),
                                                      np.float32))


@needs_numba
@pytest.mark.compiled_vs_numpy
def test_sample_twins_agree_with_the_loops():
    rng = np.random.default_rng(12)
    n = 5000
    world = rng.uniform(-300, 300, (n, 3))
    hit = rng.random(n) < 0.7
    hit[:3] = False  # misses before the first hit take its cell
    for cell in (0.5, 3.0):
        ix_c, iy_c = raykernels.noise_cells(world, hit, cell)
        ix_n, iy_n = raykernels.noise_cells_numpy(world, hit, cell)
        # floor(x / cell): one correctly rounded divide, the same on both paths
        np.testing.assert_array_equal(ix_n, ix_c)
        np.testing.assert_array_equal(iy_n, iy_c)

    table = DiscAverage(37)
    d_panel = rng.uniform(0, 20, n)
    x_p = rng.uniform(-0.5, 1279.5, n)
    for harmonic in (1, 3):
        c_c, a_c = raykernels.phasor_parts(hit, d_panel, x_p, harmonic, 6.0, table.u,
                                           table.m)
        c_n, a_n = raykernels.phasor_parts_numpy(hit, d_panel, x_p, harmonic, 6.0, table.u,
                                                 table.m)
        # 5 float64 operations on values <= 1 (np.interp), then the float32 rounding
        np.testing.assert_array_less(np.abs(c_n - c_c), op_bound(5, 1.0)
                                     + np.spacing(np.abs(c_c)) + 1e-300)
        # the angle: a product, a floor, a subtraction, a product on values <= 2 pi x 640;
        # near a whole cycle frac() may wrap from ~2 pi to ~0
        diff = np.abs(a_n.astype(float) - a_c)
        diff = np.minimum(diff, 2 * np.pi - diff)
        assert np.all(diff <= op_bound(4, 2 * np.pi * 640) + np.spacing(np.float32(7.0)))

    diameter = rng.uniform(0, 60, (90, 70))
    diameter.flat[0] = 4.0
    mask = rng.random(diameter.shape) < 0.8
    args = (blur._D_STEP, blur._D_LIN, float(np.log(blur._D_RATIO)))
    flat_c, frac_c, lev_c, start_c, stop_c = raykernels.ladder_groups(
        diameter.ravel(), mask.ravel(), *args)
    flat_n, frac_n, lev_n, start_n, stop_n = raykernels.ladder_groups_numpy(
        diameter.ravel(), mask.ravel(), *args)
    # the layers are floors of a log: a sample within rounding of a layer's edge could
    # change layer; none of these random diameters is (checked: the orders agree)
    for got, want in ((flat_n, flat_c), (lev_n, lev_c), (start_n, start_c),
                      (stop_n, stop_c)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(frac_n, frac_c, rtol=0, atol=op_bound(6, 60.0))


CHILD = """
import sys
import numpy as np
from scanqa import compiled
from scanqa.model.config import load_config
from scanqa.simulator import experiments, render
assert not compiled.HAVE_NUMBA and "numba" not in sys.modules
config = load_config(sys.argv[1]).replace_simulator(roi_width_px=72, roi_height_px=72)
pos = experiments.build_positions("gauge-blocks", config, [0.0])[0]
acq = experiments.acquisition(config, pos, 0, "gauge-blocks")
images = render.render_images(config, acq, experiments.pattern_description(config))
truth = render.truth_for(config, acq)
np.savez(sys.argv[2], *images, **truth.arrays())
"""


@needs_numba
@pytest.mark.slow
def test_a_scan_without_numba_agrees_with_the_compiled_one(paper_config, tmp_path):
    # the gauge blocks: box edges, walls and shadows; their scene is cast by boxcast
    # with numba and by open3d without
    out = tmp_path / "numpy.npz"
    env = {**os.environ, compiled.NO_NUMBA_ENV: "1", "PYTHONPATH": str(ROOT / "src")}
    subprocess.run([sys.executable, "-c", CHILD, str(PAPER_CONFIG), str(out)], check=True,
                   env=env, cwd=tmp_path, timeout=600)
    config = paper_config.replace_simulator(roi_width_px=72, roi_height_px=72)
    pos = experiments.build_positions("gauge-blocks", config, [0.0])[0]
    acq = experiments.acquisition(config, pos, 0, "gauge-blocks")
    images = render.render_images(config, acq, experiments.pattern_description(config))
    truth = render.truth_for(config, acq).arrays()
    with np.load(out) as ref:
        np.testing.assert_array_equal(ref["valid"], truth["valid"])
        for key in ("X", "Y", "Z", "xp_true", "yp_true", "zp"):
            # float64 geometry of coordinates up to ~600 mm (or ~1300 projector px),
            # some 30 operations, a grazing ray's condition not more than 10
            np.testing.assert_allclose(ref[key], truth[key], rtol=0,
                                       atol=op_bound(30, 1300.0) * 10, err_msg=key)
        for i, stack in enumerate(images):
            other = ref[f"arr_{i}"].astype(np.int64)
            diff = np.abs(other - stack.astype(np.int64))
            # the light differs by float32 roundings (~1e-3 e-), so a pixel's
            # quantisation (or the Poisson draw) can fall the other way: by 1 DN, rarely
            assert diff.max() <= 1 and diff.mean() < 1e-2, (i, diff.max(), diff.mean())


def test_a_long_simulation_without_numba_says_so_once(monkeypatch, caplog):
    monkeypatch.setattr(compiled, "HAVE_NUMBA", False)
    what = "a test's simulation"  # its own text: said once per process
    with caplog.at_level("INFO", logger="scanqa"):
        for _ in range(3):
            compiled.note_numpy_path(render.log, what)
    notes = [r.getMessage() for r in caplog.records]
    assert len(notes) == 1 and "pip install 'scanqa[fast]'" in notes[0], notes
    monkeypatch.setattr(compiled, "HAVE_NUMBA", True)
    compiled.note_numpy_path(render.log, "a test's annotate")  # with numba: nothing to say
    assert len(caplog.records) == 1
