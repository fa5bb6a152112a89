"""Phase map files: round trip, no pickle, version check, atomic writes."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from scanqa.decoding.phasemap import (
    MASK_LOW_MODULATION,
    MASK_SATURATED,
    MASK_VALID,
    PhaseMap,
    load_phase_map,
    save_phase_map,
)
from scanqa.errors import InputError
from scanqa.io.phasemap import FORMAT


def _phase_map() -> PhaseMap:
    rng = np.random.default_rng(0)
    xp = rng.uniform(0, 1280, (6, 7))
    mask = np.zeros((6, 7), np.uint8)
    mask[0, :3] = MASK_SATURATED
    mask[5, 4:] = MASK_LOW_MODULATION
    xp[mask != MASK_VALID] = np.nan
    sigma = np.where(mask == MASK_VALID, 0.02, np.nan)
    return PhaseMap(xp, rng.uniform(0, 900, (6, 7)), rng.uniform(0, 2000, (6, 7)), mask,
                    sigma, period_px=16.0, orientation="horizontal", projector_width_px=1280,
                    provenance={"software": "scanqa", "patterns": {"set": [{"period_px": 16}]}})


def test_round_trip_keeps_every_field(tmp_path):
    pm = _phase_map()
    path = save_phase_map(tmp_path / "phase.npz", pm)
    got = load_phase_map(path)
    for name in ("xp", "modulation", "offset", "mask", "sigma_xp"):
        np.testing.assert_array_equal(getattr(got, name), getattr(pm, name))
        assert getattr(got, name).dtype == getattr(pm, name).dtype
    assert got.xp.dtype == np.float64 and got.mask.dtype == np.uint8
    assert (got.period_px, got.orientation, got.projector_width_px) == (16.0, "horizontal", 1280)
    assert got.provenance == pm.provenance
    assert got.counts() == {"valid": 36, "saturated": 3, "low_modulation": 3,
                            "inconsistent": 0, "out_of_range": 0}


def test_file_is_plain_npz_without_pickle(tmp_path):
    save_phase_map(tmp_path / "p.npz", _phase_map())
    with np.load(tmp_path / "p.npz", allow_pickle=False) as npz:
        assert str(npz["format"]) == FORMAT == "scanqa-phasemap/1"
        assert npz["provenance"].dtype.kind == "U"
        assert json.loads(str(npz["provenance"]))["software"] == "scanqa"
        assert set(npz.files) == {"format", "xp", "modulation", "offset", "mask", "sigma_xp",
                                  "period_px", "orientation", "projector_width_px",
                                  "provenance"}


def test_arrays_are_read_only():
    pm = _phase_map()
    with pytest.raises(ValueError, match="read-only"):
        pm.xp[0, 0] = 1.0


def _rewrite(tmp_path, **changes):
    save_phase_map(tmp_path / "p.npz", _phase_map())
    with np.load(tmp_path / "p.npz", allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    data.update(changes)
    data = {k: v for k, v in data.items() if v is not None}
    np.savez(tmp_path / "bad.npz", **data)
    return tmp_path / "bad.npz"


def test_other_format_version_is_refused(tmp_path):
    path = _rewrite(tmp_path, format=np.str_("scanqa-phasemap/2"))
    with pytest.raises(InputError, match="has format 'scanqa-phasemap/2'; this scanqa reads "
                                         "'scanqa-phasemap/1'"):
        load_phase_map(path)


def test_missing_entry_and_bad_arrays(tmp_path):
    with pytest.raises(InputError, match="lacks sigma_xp"):
        load_phase_map(_rewrite(tmp_path, sigma_xp=None))
    with pytest.raises(InputError, match="mask holds unknown reason codes"):
        load_phase_map(_rewrite(tmp_path, mask=np.full((6, 7), 7, np.uint8)))
    with pytest.raises(InputError, match="must be a 2-D array of the shape of xp"):
        load_phase_map(_rewrite(tmp_path, offset=np.zeros((6, 8))))


def test_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_phase_map(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(InputError, match="cannot read phase map"):
        load_phase_map(tmp_path / "junk.npz")
    with zipfile.ZipFile(tmp_path / "empty.npz", "w"):
        pass
    with pytest.raises(InputError, match="has format '\\(none\\)'"):
        load_phase_map(tmp_path / "empty.npz")


def test_nothing_is_written_on_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        save_phase_map(tmp_path / "missing" / "phase.npz", _phase_map())
    pm = _phase_map()
    bad = PhaseMap(pm.xp, pm.modulation, pm.offset, pm.mask, pm.sigma_xp, 16.0,
                   provenance={"x": {1, 2}})
    with pytest.raises(InputError, match="provenance is not plain JSON"):
        save_phase_map(tmp_path / "phase.npz", bad)
    assert list(tmp_path.iterdir()) == []
