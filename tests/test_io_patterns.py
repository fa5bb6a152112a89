"""patterns.toml parsing and validation, image reading, the writer and ideal patterns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    SensorModel,
)
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.decoding.parsing import load_patterns, patterns_from_dict
from scanqa.decoding.patternset import (
    ideal_patterns,
    projector_patterns,
    read_pattern_images,
    synthesize_images,
    write_pattern_set,
)
from scanqa.errors import ConfigError, InputError
from scanqa.io.images import read_image, read_stack, write_image
from scanqa.io.patterns import dumps_patterns

WIDTH = 640


def _desc(**kw) -> PatternDescription:
    sets = (PhaseSet("coarse", 640.0, 4), PhaseSet("fine", 32.0, 3, (0.0, 2.0, 4.0)))
    return PatternDescription(WIDTH, sets, sensor=SensorModel(bit_depth=12), **kw)


def _images(desc: PatternDescription, dtype=np.uint16, shape=(12, 40)) -> list[np.ndarray]:
    xp = np.broadcast_to(np.linspace(2.0, WIDTH - 3.0, shape[1]), shape)
    a, b = (120.0, 100.0) if dtype == np.uint8 else (1500.0, 1000.0)
    return [np.rint(im).astype(dtype) for im in synthesize_images(desc, xp, a, b)]


def _toml(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "patterns.toml"
    path.write_text(text)
    return path


_HEADER = 'format = "scanqa-patterns/1"\nprojector_width_px = 640\n'
_SET = ('[[set]]\nkind = "phase"\nperiod_px = 640.0\nsteps = 3\n'
        'files = ["a.png", "b.png", "c.png"]\n')


# ---------------------------------------------------------------------- round trips

@pytest.mark.parametrize("fmt", ["png", "tif", "npy", "npz"])
def test_write_then_read_round_trip(tmp_path, fmt):
    desc = _desc()
    images = _images(desc)
    written = write_pattern_set(tmp_path / "scan", desc, images, image_format=fmt)
    loaded = load_patterns(tmp_path / "scan")
    assert loaded.source == str(tmp_path / "scan" / "patterns.toml")
    assert loaded.sets == written.sets and loaded.sensor == desc.sensor
    for got, want in zip(read_pattern_images(loaded), images, strict=True):
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, want)
    pm = decode_pattern_dir(tmp_path / "scan")
    assert pm.valid.all()
    expected = np.broadcast_to(np.linspace(2.0, WIDTH - 3.0, 40), (12, 40))
    np.testing.assert_allclose(pm.xp, expected, atol=0.01)  # rounding to integer DN


def test_an_image_read_again_is_the_file_as_it_is_now(tmp_path):
    """read_image keeps decoded images for files read again (by their bytes): each
    caller gets its own array, and a file rewritten in place - same size, maybe the same
    time stamp - is read as it is now."""
    path = tmp_path / "frame.bmp"  # BMP: the same size whatever the pixels
    first = np.arange(12 * 40, dtype=np.uint8).reshape(12, 40)
    write_image(path, first)
    got = read_image(path)
    got[0, 0] = 99
    np.testing.assert_array_equal(read_image(path), first)
    second = first[::-1].copy()
    data = path.read_bytes()
    write_image(tmp_path / "other.bmp", second)
    path.write_bytes((tmp_path / "other.bmp").read_bytes())
    assert path.stat().st_size == len(data)
    np.testing.assert_array_equal(read_image(path), second)
    np.testing.assert_array_equal(read_image(tmp_path / "other.bmp"), second)


def test_eight_bit_png_and_float_npz(tmp_path):
    desc = _desc()
    eight = _images(desc, np.uint8)
    write_pattern_set(tmp_path / "u8", desc, eight, image_format="png")
    assert read_pattern_images(load_patterns(tmp_path / "u8"))[0].dtype == np.uint8
    floats = [im.astype(np.float32) for im in eight]
    write_pattern_set(tmp_path / "f", desc, floats, image_format="npz")
    got = read_pattern_images(load_patterns(tmp_path / "f" / "patterns.toml"))
    assert got[1].dtype == np.float32 and got[1].shape == (3, 12, 40)


def test_dumps_is_the_inverse_of_parsing():
    desc = PatternDescription(
        WIDTH, (PhaseSet("p", 40.0, 4, files=("a", "b", "c", "d")),
                GrayCodeSet("g", 5, inverse=True, stack="g.npz", stack_key="g")),
        description='say "hi"')
    import tomllib

    again = patterns_from_dict(tomllib.loads(dumps_patterns(desc.to_dict())))
    assert again.sets == desc.sets and again.description == desc.description
    assert again.thresholds == desc.thresholds


def test_sensor_defaults_resolve_from_the_image_type():
    assert SensorModel().resolved(np.uint8).saturation_dn == 255
    assert SensorModel().resolved(np.uint16).saturation_dn == 65535
    assert SensorModel(bit_depth=12).resolved(np.uint16).saturation_dn == 4095
    assert SensorModel(bit_depth=12, saturation_dn=4000).resolved(np.uint16).saturation_dn \
        == 4000


# -------------------------------------------------------------------- ideal patterns

def test_phase_pattern_convention():
    # projector column x shows 0.5 + 0.5 cos(2 pi x / period + 2 pi k / N)
    desc = PatternDescription(8, (PhaseSet("p", 8.0, 4),))
    got = ideal_patterns(desc, 0, np.arange(8.0))
    x, k = np.meshgrid(np.arange(8.0), np.arange(4.0))
    np.testing.assert_allclose(got, 0.5 + 0.5 * np.cos(2 * np.pi * x / 8 + np.pi * k / 2))


def test_gray_patterns_code_half_periods_and_change_one_bit_at_a_time():
    desc = PatternDescription(64, (PhaseSet("p", 16.0, 4), GrayCodeSet("g", 3, inverse=True)))
    x = np.arange(64.0)
    frames = ideal_patterns(desc, 1, x)
    assert frames.shape == (6, 64)
    np.testing.assert_array_equal(frames[3:], 1 - frames[:3])
    codes = (frames[:3] * np.array([[4], [2], [1]])).sum(axis=0).astype(int)
    half = np.floor(2 * x / 16).astype(int)
    np.testing.assert_array_equal(codes, half ^ (half >> 1))
    changes = np.abs(np.diff(frames[:3], axis=1)).sum(axis=0)
    assert set(changes.tolist()) == {0.0, 1.0}


def test_projector_patterns_follow_the_orientation():
    vertical = PatternDescription(20, (PhaseSet("p", 20.0, 3),))
    horizontal = PatternDescription(20, (PhaseSet("p", 20.0, 3, orientation="horizontal"),))
    v = projector_patterns(vertical, 0, across_px=5)
    h = projector_patterns(horizontal, 0, across_px=5)
    assert v.shape == (3, 5, 20) and h.shape == (3, 20, 5)
    np.testing.assert_allclose(v, np.swapaxes(h, 1, 2))
    np.testing.assert_allclose(v[:, 2, :], ideal_patterns(vertical, 0, np.arange(20.0)))


# -------------------------------------------------------------------- errors: toml

@pytest.mark.parametrize("text,match", [
    (_HEADER + "colour = 1\n" + _SET, r"patterns\.toml: unknown key 'colour'"),
    (_HEADER + _SET + "perod_px = 5\n", r"patterns\.toml: \[\[set\]\] 1: unknown key 'perod_px'"),
    (_HEADER + "[sensor]\ngain = 2\n" + _SET, r"unknown key sensor\.gain "),
    (_HEADER + "[thresholds]\nmin_mod = 2\n" + _SET, r"unknown key thresholds\.min_mod "),
    (_HEADER.replace("/1", "/3") + _SET,
     "format must be one of 'scanqa-patterns/1', 'scanqa-patterns/2'"),
    (_HEADER + _SET.replace('"c.png"]', '"c.png", "d.png"]'),
     r"wrong count of files in set\[0\] \('phase0'\): got 4, need 3 \(steps = 3\)"),
    (_HEADER + _SET.replace("steps = 3", "steps = 2"), "steps must be a whole number >= 3"),
    (_HEADER + _SET.replace("640.0", "64.0"),
     r"periods cannot be unwrapped: the coarsest period_px = 64 .* shorter than "
     r"projector_width_px = 640"),
    (_HEADER + _SET + _SET.replace("640.0", "5.0"),
     r"set 'phase0' \(period_px = 640\) cannot unwrap set 'phase1' \(period_px = 5\): "
     r"the ratio 128"),
    (_HEADER + _SET.replace("steps", 'name = "x"\nsteps') * 2, "set names must be unique"),
    (_HEADER + _SET.replace('kind = "phase"', 'kind = "phase"\norientation = "diagonal"'),
     "orientation must be 'vertical' or 'horizontal'"),
    (_HEADER + _SET.replace("steps = 3", "steps = 3\nshifts_rad = [0.0, 0.0, 0.0]"),
     "do not determine the phase"),
    (_HEADER + _SET.replace('files = ["a.png", "b.png", "c.png"]',
                            'files = ["a.png", "b.png", "c.png"]\nstack = "s.npy"'),
     "either files"),
    ('projector_width_px = 640\n' + _SET, "format must be"),
    (_HEADER, r"set is missing \(one or more \[\[set\]\] tables"),
    (_HEADER + "[sensor]\ngain_e_per_dn = -1\n" + _SET, r"sensor\.gain_e_per_dn must be > 0"),
    (_HEADER + "projector_width_px = 3\n", "not valid TOML"),
])
def test_bad_patterns_toml_gives_one_clear_error(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_patterns(_toml(tmp_path, text))


def test_gray_bits_must_cover_the_range(tmp_path):
    # 4 bits were captured (4 files): the fixes offered are the width and the cell, never
    # "use bits = 6", which would need frames that do not exist
    text = (_HEADER + _SET.replace("640.0", "32.0")
            + '[[set]]\nkind = "gray"\nbits = 4\nfiles = ["1", "2", "3", "4"]\n')
    with pytest.raises(ConfigError, match=r"'gray1' codes 16 cells of 16 px = 256 px "
                                          r"\(bits = 4, 4 frames\) < projector_width_px = "
                                          r"640; check projector_width_px .* cell_px") as err:
        load_patterns(_toml(tmp_path, text))
    assert "use bits" not in str(err.value)


def test_gray_must_order_an_existing_coarsest_set(tmp_path):
    gray = '[[set]]\nkind = "gray"\nbits = 8\norders = "nope"\nfiles = [{}]\n'.format(
        ", ".join(f'"{i}"' for i in range(8)))
    with pytest.raises(ConfigError, match=r"orders must be the name of a phase set"):
        load_patterns(_toml(tmp_path, _HEADER + _SET + gray))


def test_mixed_orientation_is_refused():
    sets = (PhaseSet("a", 640.0, 3), PhaseSet("b", 32.0, 3, orientation="horizontal"))
    with pytest.raises(ConfigError, match="orientation must be the same for every set"):
        PatternDescription(WIDTH, sets)


def test_missing_patterns_file(tmp_path):
    with pytest.raises(ConfigError, match=r"no pattern description .*patterns\.toml"):
        load_patterns(tmp_path)


# ------------------------------------------------------------------ errors: images

def test_unreadable_and_missing_files(tmp_path):
    desc = _desc()
    write_pattern_set(tmp_path, desc, _images(desc))
    (tmp_path / "fine_01.png").write_bytes(b"not a png at all")
    with pytest.raises(InputError, match=r"cannot read image .*fine_01\.png"):
        read_pattern_images(load_patterns(tmp_path))
    (tmp_path / "fine_01.png").unlink()
    with pytest.raises(InputError, match=r"image file .*fine_01\.png does not exist"):
        read_pattern_images(load_patterns(tmp_path))


def test_mismatched_image_sizes(tmp_path):
    desc = _desc()
    images = _images(desc)
    write_pattern_set(tmp_path / "a", desc, images)
    write_image(tmp_path / "a" / "fine_02.png", images[1][2, :, :30])
    with pytest.raises(InputError, match=r"mismatched image sizes in set 'fine'.*fine_02"):
        read_pattern_images(load_patterns(tmp_path / "a"))
    small = [images[0], images[1][:, :, :30]]
    write_pattern_set(tmp_path / "b", desc, small, image_format="npy")
    with pytest.raises(InputError, match=r"mismatched image sizes: set 'fine' has images "
                                         r"of 30 x 12 px, set 'coarse' of 40 x 12 px"):
        read_pattern_images(load_patterns(tmp_path / "b"))


def test_stack_errors(tmp_path):
    desc = _desc()
    images = _images(desc)
    write_pattern_set(tmp_path, desc, images, image_format="npy")
    np.save(tmp_path / "fine.npy", images[1][:2])
    with pytest.raises(InputError, match=r"wrong count of images in stack .*fine\.npy for "
                                         r"set 'fine': got 2, need 3"):
        read_pattern_images(load_patterns(tmp_path))
    np.savez(tmp_path / "s.npz", a=images[1], b=images[1])
    with pytest.raises(InputError, match=r"has no array '' .*name one with stack_key"):
        read_stack(tmp_path / "s.npz")
    bad = images[1].astype(float)
    bad[0, 0, 0] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="contains NaN"):
        read_stack(tmp_path / "nan.npy")


def test_colour_image_is_refused(tmp_path):
    from PIL import Image

    Image.fromarray(np.zeros((4, 5, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(InputError, match=r"colour image \(mode 'RGB'\); name the channel"):
        read_image(tmp_path / "rgb.png")


def test_writer_rejects_float_png(tmp_path):
    desc = _desc()
    with pytest.raises(InputError, match=r"need a 2-D uint8 .* array"):
        write_pattern_set(tmp_path, desc, [im.astype(float) for im in _images(desc)])


# ------------------------------------------------------------- formats, versions

def test_bmp_round_trip_decodes(tmp_path):
    desc = _desc()
    images = _images(desc, np.uint8)
    write_pattern_set(tmp_path / "bmp", desc, images, image_format="bmp")
    loaded = load_patterns(tmp_path / "bmp")
    assert loaded.sets[0].files[0].endswith(".bmp")
    for got, want in zip(read_pattern_images(loaded), images, strict=True):
        np.testing.assert_array_equal(got, want)
    assert decode_pattern_dir(tmp_path / "bmp").valid.all()


def test_jpeg_is_read_with_a_warning(tmp_path):
    from PIL import Image

    desc = _desc()
    written = write_pattern_set(tmp_path, desc, _images(desc, np.uint8), image_format="png")
    for pset in written.sets:
        for name in pset.files:
            Image.open(tmp_path / name).save(tmp_path / name.replace(".png", ".jpg"),
                                             quality=95)
    toml = tmp_path / "patterns.toml"
    toml.write_text(toml.read_text().replace(".png", ".jpg"))
    summary = decode_pattern_dir(tmp_path).summary()
    assert "images are lossy-compressed (coarse_00.jpg, ...): JPEG-like compression " \
           "biases the phase" in summary


def test_colour_images_need_a_channel_key(tmp_path):
    from PIL import Image

    desc = _desc()
    images = _images(desc, np.uint8)
    written = write_pattern_set(tmp_path, desc, images, image_format="png")
    for pset, stack in zip(written.sets, images, strict=True):
        for name, frame in zip(pset.files, stack, strict=True):
            rgb = np.stack([frame // 2, frame, np.zeros_like(frame)], axis=-1)
            Image.fromarray(rgb).save(tmp_path / name)  # fringes in the green channel
    with pytest.raises(InputError, match=r"colour image \(mode 'RGB'\); name the channel "
                                         r"that carries the fringes with channel = "):
        read_pattern_images(load_patterns(tmp_path))
    toml = tmp_path / "patterns.toml"
    toml.write_text(toml.read_text().replace('channel = ""', 'channel = "green"'))
    got = read_pattern_images(load_patterns(tmp_path))
    np.testing.assert_array_equal(got[1], images[1])
    assert read_image(tmp_path / written.sets[0].files[0], "red").max() < 128


def test_version_1_files_keep_their_meaning(tmp_path):
    text = ('format = "scanqa-patterns/1"\nprojector_width_px = 640\n'
            '[thresholds]\ngray_max_residual = 0.4\n'
            '[sensor]\ngain_e_per_dn = 2.0\n'
            + _SET.replace("640.0", "32.0")
            + '[[set]]\nkind = "gray"\nbits = 6\ninverse = true\n'
              f'files = [{", ".join(f"{chr(34)}{i}{chr(34)}" for i in range(12))}]\n')
    desc = load_patterns(_toml(tmp_path, text))
    gray = desc.gray_set
    assert gray.inverse == "grouped" and gray.cell_px is None
    assert desc.gray_cell_px == 16.0  # half the ordered period, as version 1 defined it
    # cycles of the ordered period beyond the 1/4 quantisation, in cells of half a period
    assert desc.thresholds.gray_edge_cells == pytest.approx(0.3)
    assert desc.thresholds.unwrap_sigma_margin == 2.0  # not stated: today's default
    assert desc.sensor.read_noise_e == 8.0  # version 1 filled in the missing one
    assert desc.to_dict()["format"] == "scanqa-patterns/2"
    with pytest.raises(ConfigError, match=r"unknown key set\[1\]\.cell_px"):
        load_patterns(_toml(tmp_path, text.replace("bits = 6", "bits = 6\ncell_px = 4.0")))


def test_committed_sample_scans_still_load():
    from tests.conftest import ROOT

    files = sorted((ROOT / "sample_data").rglob("patterns.toml"))
    assert files
    desc = load_patterns(files[0])
    assert desc.sensor.knows_noise and desc.thresholds.unwrap_sigma_margin == 4.0
