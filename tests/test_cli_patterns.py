"""``scanqa patterns``: the projector images it writes, captured by a simulated camera
(here, from the written PNGs), saved under the names its patterns.toml lists and decoded
by ``scanqa decode`` - a round trip through real files, with no file written by hand."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from scanqa.cli import main
from scanqa.decoding.parsing import load_patterns
from scanqa.decoding.phasemap import load_phase_map

PANEL = (1280, 16)  # width, height [projector px]


def _capture(folder, x: np.ndarray, gamma: float, seed: int = 0) -> None:
    """Camera images of every projector image: the panel row seen at coordinate x
    (linear between columns, as a slightly blurred projector shows it), through a
    projector of response value**gamma, with noise; saved as the toml names them."""
    desc = load_patterns(folder)
    panels = sorted((folder / "projector").glob("*.png"))
    names = [n for s in desc.sets for n in s.files]
    assert len(panels) == len(names)
    rng = np.random.default_rng(seed)
    columns = np.arange(PANEL[0])
    for panel, name in zip(panels, names, strict=True):
        row = np.asarray(Image.open(panel), float)[0] / 255.0
        light = np.interp(x, columns, row) ** gamma
        frame = 20.0 + 200.0 * light + rng.normal(0.0, 0.7, x.shape)
        Image.fromarray(np.clip(np.rint(frame), 0, 255).astype(np.uint8)).save(folder / name)


def _decode(folder, tmp_path, capsys):
    out = tmp_path / f"{folder.name}.npz"
    assert main(["decode", str(folder), "--out", str(out), "--quiet"]) == 0
    return load_phase_map(out), capsys.readouterr().out


@pytest.mark.parametrize("predistort", [True, False])
def test_gray_and_phase_patterns_round_trip_through_files(tmp_path, capsys, predistort):
    folder = tmp_path / ("pre" if predistort else "plain")
    args = ["patterns", str(folder), "--width", str(PANEL[0]), "--height", str(PANEL[1]),
            "--periods", "48,40", "--steps", "3", "--gray-cell", "8", "--gray-inverse",
            "interleaved", "--reference", "--camera-suffix", ".bmp"]
    assert main(args + (["--gamma", "2.2"] if predistort else [])) == 0
    said = capsys.readouterr().out
    assert said.startswith("24 projector images of 1280 x 16 px")  # 2 + 2 x 8 + 3 + 3
    v, u = np.mgrid[0:48, 0:320]
    x = 3.0 + 3.9 * u + 0.11 * v  # a tilted flat seen by the camera [projector px]
    _capture(folder, x, gamma=2.2)
    pm, out = _decode(folder, tmp_path, capsys)
    assert pm.valid.mean() > 0.97, out
    err = np.abs(pm.xp - x)[pm.valid]
    assert err.max() < 10.0  # no fringe-order error (a period is 40 px)
    if predistort:
        assert np.sqrt(np.mean(err ** 2)) < 0.08  # px (measured 0.041, the noise): ideal fringes
    else:
        assert np.sqrt(np.mean(err ** 2)) > 0.5  # px (measured 1.3): gamma 2.2 left in the phase
    assert "noise: estimated from the images: offsets of the phase sets" in out


def test_panel_size_and_periods_from_a_config(tmp_path, capsys):
    from tests.conftest import PAPER_CONFIG

    assert main(["patterns", str(tmp_path / "p"), "--config", str(PAPER_CONFIG)]) == 0
    assert "12 projector images of 1280 x 800 px" in capsys.readouterr().out
    desc = load_patterns(tmp_path / "p")
    assert [s.period_px for s in desc.phase_sets] == [1280.0, 80.0, 5.0]
    first = Image.open(sorted((tmp_path / "p" / "projector").glob("*.png"))[0])
    assert first.size == (1280, 800) and first.mode == "L"
    assert desc.sets[0].files[0] == "000_p1280_00.png"


def test_horizontal_gray_alone_and_a_missing_panel_size(tmp_path, capsys):
    assert main(["patterns", str(tmp_path / "h"), "--width", "64", "--height", "40",
                 "--gray-cell", "1", "--gray-inverse", "grouped",
                 "--orientation", "horizontal"]) == 0
    desc = load_patterns(tmp_path / "h")
    gray = desc.gray_set
    assert gray.bits == 6 and desc.projector_width_px == 40  # rows are coded
    image = np.asarray(Image.open(sorted((tmp_path / "h" / "projector").glob("*.png"))[0]))
    assert image.shape == (40, 64) and (image == image[:, :1]).all()  # constant along rows
    capsys.readouterr()
    assert main(["patterns", str(tmp_path / "x"), "--periods", "64"]) == 2
    assert "the panel size is unknown: give --config FILE or --width and --height" in \
        capsys.readouterr().err
