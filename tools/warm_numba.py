"""Compile scanqa's numba loops into numba's cache once (make setup runs this).

    python tools/warm_numba.py

On a fresh clone every compiled loop is compiled on its first call, and under
``pytest -n 2`` both workers meet the same loops at about the same time and compile them
twice. Here they are compiled once, in one process, for this CPU and for numba's generic
CPU target (tests/cpu_targets.py reruns the compiled-vs-numpy tests there), and so is the
``fringes`` reference decoder when installed. The caches live beside the sources
(``__pycache__``) and follow them: an edited loop is compiled again on its next call.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def warm() -> None:
    """Call each family of loops once with the argument types scanqa gives them."""
    import numpy as np

    from scanqa.annotation import kernels
    from scanqa.model.config import load_config
    from scanqa.simulator import experiments

    kernels.load()  # the annotate loop
    from scanqa.model.normals import grid_normals, pixel_index

    grid_normals(np.zeros((4, 3)), pixel_index(np.ones((2, 2), bool)), 1.0)  # normals
    config = load_config(ROOT / "calib" / "paper_scanner.toml").replace_simulator(
        roi_width_px=24, roi_height_px=24)
    with tempfile.TemporaryDirectory() as tmp:  # the renderer's loops, the box cast
        experiments.run_experiment("gauge-blocks", config, Path(tmp) / "g", repeats=1)
        experiments.run_experiment("sphere", config, Path(tmp) / "s", positions=[450.0],
                                   repeats=1)
    _warm_board()
    try:
        import fringes
    except ImportError:
        return
    import logging

    logging.getLogger("fringes").setLevel(logging.ERROR)
    # as tests/test_fringes_agreement.py calls it (12 frames stacked, uint16); a failure
    # here costs only the head start
    f = fringes.Fringes(X=1280, Y=16, K=3, N=4, v=(1.0, 16.0, 80.0), axes=(1,),
                        reverse=True, p0=0.0, dtype="uint16")
    try:
        f.decode(np.full((12, 32, 128), 1000, np.uint16))
    except Exception as err:  # not scanqa's: say so and go on
        print(f"numba: fringes' decoder not compiled ahead ({err})")


def _warm_board() -> None:
    """The board renderers' loops: a Gray-code pose and a fringe frame on a tiny camera."""
    from dataclasses import replace

    import numpy as np

    from scanqa.simulator import boardfringes, boardposes

    sim = boardposes.simulate(1, n_poses=1)
    truth = replace(sim.truth, sizes=dict(sim.truth.sizes, frameWidth=16, frameHeight=12))
    rng = np.random.default_rng(0)
    rvec, tvec = np.zeros(3), np.array([-50.0, -40.0, 400.0])
    boardposes.gray_frames(truth, boardposes.BOARD, rvec, tvec, (1, 1), rng, bow=sim.bow)
    view = boardposes.board_view(truth, boardposes.BOARD, rvec, tvec, squares=False)
    columns, _ = boardfringes.fringe_descriptions((912, 1140), (96.0,), 3)
    boardfringes.frames(view, columns, rng)
    boardposes.gaussian_blur(np.zeros((4, 5)), 0.7)


def main() -> int:
    if os.environ.get("NUMBA_CPU_NAME") or len(sys.argv) > 1:
        warm()
        return 0
    t0 = time.process_time()
    warm()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CPU_FEATURES"}
    env["NUMBA_CPU_NAME"] = "generic"
    child = subprocess.run([sys.executable, __file__], env=env, check=False)
    print(f"numba: loops compiled and cached for this CPU and the generic target "
          f"({time.process_time() - t0:.0f} s of CPU here)")
    return child.returncode


if __name__ == "__main__":
    sys.exit(main())
