"""What the marker fit's uncertainty does to a marker table (issue 25): Eq. 4 of
:mod:`scanqa.calibration.uncertainty` against a Monte Carlo of the same fit's covariance
registered by Kabsch (nonlinear, independent of the linearised sigma points), and several
marker frames per position read from a sweep manifest and averaged.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration import uncertainty as un
from scanqa.calibration.sweep_fit import fit_sweep_geometry

from .test_sweep_fit import (
    _sweep,
    cfg,  # noqa: F401  (the fixture)
)

ZS = [float(z) for z in np.arange(424.0, 477.0, 4.0)]


@pytest.fixture(scope="module")
def geometry(cfg):  # noqa: F811
    # simulated corners with white noise of 0.02 px (the marker fit's residual is 0.024)
    return fit_sweep_geometry(_sweep(cfg, 0.02, ZS), ZS, cfg, 306, 256)


def _kabsch_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of a - b after the rigid motion of a that best matches b [mm]."""
    ca, cb = a.mean(0), b.mean(0)
    uu, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    rot = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ uu.T))]) @ uu.T
    return float(np.sqrt(np.mean(np.sum(((a - ca) @ rot.T + cb - b) ** 2, axis=1))))


def _monte_carlo(geometry, parameters, draws: int = 300) -> np.ndarray:
    """Registered RMS of the plane points for parameter vectors drawn from the fit's
    covariance (the selected block), each registered onto the fit's points [mm]."""
    v, u = np.mgrid[0:256:8, 0:306:8].astype(float)
    u, v = np.tile(u.ravel(), len(ZS)), np.tile(v.ravel(), len(ZS))
    s = np.repeat(ZS, u.size // len(ZS))
    base = geometry.ray_points(u, v, s)
    sel = np.zeros(15, bool)
    sel[list(parameters)] = True
    cov = np.where(np.outer(sel, sel), geometry.covariance, 0.0)
    rng = np.random.default_rng(3)
    out = []
    for theta in rng.multivariate_normal(geometry.parameters, cov, draws):
        moved = geometry.with_parameters(theta).ray_points(u, v, s)
        ok = np.isfinite(moved).all(1) & np.isfinite(base).all(1)
        out.append(_kabsch_rms(moved[ok], base[ok]))
    return np.array(out)


@pytest.mark.parametrize("parameters", [range(15), un.ROTATION_PARAMETERS],
                         ids=["whole fit", "rotation"])
def test_registered_error_matches_monte_carlo(geometry, parameters):
    spread = un.registered_error_spread(geometry, ZS, parameters)
    draws = _monte_carlo(geometry, parameters)
    rms, mc_rms = un.registered_error_mm(spread), float(np.sqrt(np.mean(draws**2)))
    q95, mc_q95 = un.registered_error_mm(spread, 0.95), float(np.quantile(draws, 0.95))
    print(f"\n[marker_error] {list(parameters)}: RMS {1e3 * rms:.3f} um (Monte Carlo "
          f"{1e3 * mc_rms:.3f}), 95 % {1e3 * q95:.3f} um ({1e3 * mc_q95:.3f}); "
          f"eigenvalues {np.round(1e6 * spread[:3], 4)} um^2")
    # 300 draws of a spread with two main axes: the Monte Carlo's RMS is known to ~6 %
    # (1 std) and its 95 % quantile to ~8 %; 20 % is 3 std
    assert rms == pytest.approx(mc_rms, rel=0.2)
    assert q95 == pytest.approx(mc_q95, rel=0.2)
    assert spread[0] > 0 and np.all(np.diff(spread) <= 0)  # largest first


def test_more_frames_scale_the_error(geometry):
    """N frames per position divide the fit's covariance by N: the expectation falls by
    sqrt(N), and the frames the summary asks for bring the quantile within the bound."""
    spread = un.registered_error_spread(geometry, ZS)
    one, four = un.registered_error_mm(spread), un.registered_error_mm(spread, scale=0.25)
    assert four == pytest.approx(one / 2, rel=1e-12)
    bound = 0.51 * un.registered_error_mm(spread, 0.95)  # about half: 4 frames needed
    summary = un.marker_error_summary(geometry, ZS, 1, bound)
    assert summary["exceeds_bound"] and summary["frames_needed"] == 4
    again = un.marker_error_summary(geometry, ZS, 4, bound)
    # 4 frames: its own covariance is the same here (the same corners), so 16 are asked
    assert again["frames_needed"] == 16


def test_marker_frames_listed_and_averaged(cfg, tmp_path):  # noqa: F811
    from scanqa.calibration.sweep import marker_image
    from scanqa.errors import InputError
    from scanqa.io.images import write_image
    from scanqa.io.sweep import load_sweep

    h, w = cfg.camera.height_px, cfg.camera.width_px
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 4000, (h, w)).astype(np.uint16) for _ in range(3)]
    names = []
    for k, frame in enumerate(frames):
        write_image(tmp_path / f"m{k}.png", frame)
        names.append(f"m{k}.png")
    (tmp_path / "scan").mkdir()
    rows = "".join(f'[[position]]\nz_mm = {z}\npatterns = ["scan"]\nmarkers = {names!r}\n'
                   .replace("'", '"') for z in (430.0, 440.0, 450.0))
    head = 'format = "scanqa-sweep/1"\n[target]\nkind = "chessboard"\nsquare_mm = 2.0\n'
    (tmp_path / "sweep.toml").write_text(head + rows)
    sweep = load_sweep(tmp_path)
    pos = sweep.positions[0]
    assert pos.marker_frames == tuple(tmp_path / n for n in names)
    assert pos.marker_frames[0] == tmp_path / "m0.png" and sweep.has_markers
    np.testing.assert_allclose(marker_image(pos.marker_frames, cfg),
                               np.mean(np.array(frames, float), axis=0))  # exact mean
    (tmp_path / "sweep.toml").write_text(head + rows.replace("m2.png", "gone.png"))
    with pytest.raises(InputError, match=r"marker frame 'gone\.png' does not exist"):
        load_sweep(tmp_path)
    # one position with fewer frames: refused, naming the position and both counts
    fewer = rows.replace(', "m2.png"]', ']', 1)
    (tmp_path / "sweep.toml").write_text(head + fewer)
    with pytest.raises(InputError, match=r"position 2 \(z_mm = 440.0\) lists 3 marker "
                                         r"frames, position 1 lists 2"):
        load_sweep(tmp_path)


def test_sweep_manifest_groups_marker_frames():
    from scanqa.errors import InputError
    from scanqa.io.sweep import sweep_manifest

    caps, zs = ["a", "b", "c"], [430.0, 440.0, 450.0]
    marks = [f"m{z:g}_{k}.png" for z in zs for k in range(2)]  # name order = reading order
    rows = sweep_manifest(caps, zs, marks, 2.0, False)["position"]
    assert [r["markers"] for r in rows] == [marks[0:2], marks[2:4], marks[4:6]]
    assert sweep_manifest(caps, zs, marks[::2], 2.0, False)["position"][1]["markers"] == \
        "m440_0.png"  # one a position: a plain string, as before
    with pytest.raises(InputError, match="5 marker frames but 3 distinct stage readings"):
        sweep_manifest(caps, zs, marks[:5], 2.0, False)
