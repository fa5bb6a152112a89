"""scanqa batch and scanqa campaign: the same bytes serially and on Dask, a killed worker
loses and duplicates nothing, resuming skips complete scans, a bad scan fails alone.

The expected values come from other code paths: the per-scan QA files are compared with
what ``scanqa qa`` writes for the same scan, a campaign's run folder with what ``scanqa
simulate --seed`` writes, and the results table with the per-scan blocks.csv.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import logging
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from scanqa import cluster
from scanqa.annotation.points import annotate
from scanqa.calibration.base import load_calibration
from scanqa.cli import main
from scanqa.decoding.decoder import decode
from scanqa.io.atomic import STAGE_PREFIX
from scanqa.io.ply import read_ply, write_ply
from scanqa.model.config import load_config

from .conftest import ROOT
from .shared_runs import sample_table

SAMPLE = ROOT / "sample_data"
CONFIG = f"{SAMPLE / 'sample_scanner.toml'}#sample"
ROI64 = f"{SAMPLE / 'sample_scanner.toml'}#sample_roi64"
LAYOUT = SAMPLE / "gauge_blocks" / "layout.toml"
SCANS = str(SAMPLE / "gauge_blocks" / "p000_r*")

needs_dask = pytest.mark.skipif(not cluster.dask_available(),
                                reason="Dask distributed is not installed (pip install "
                                       "'scanqa[cluster]'; make test installs it)")


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def table(tmp_path_factory) -> Path:
    # `scanqa calibrate sample_data/calibration_sweep/sweep.toml --config CONFIG`, run once
    # per make test (tests/shared_runs.py)
    return sample_table(tmp_path_factory.mktemp("table"))


#: What ``--workers 2 --dashboard :0`` asks of scanqa.cluster.open_client.
TWO_WORKERS = cluster.EngineOptions(workers=2, dashboard=":0")


@pytest.fixture(scope="module")
def local_cluster():
    """The LocalCluster of 2 worker processes that ``--workers 2`` starts (scanqa's own
    :func:`scanqa.cluster.open_client`), started once for the file: (its address, for
    --scheduler; a client). Each cluster's start costs ~8 s of CPU (two nannies and two
    workers importing scanqa)."""
    if not cluster.dask_available():
        pytest.skip("Dask distributed is not installed (pip install 'scanqa[cluster]')")
    with cluster.open_client(TWO_WORKERS) as (client, report):
        assert report.engine == "local cluster (2 worker processes)"
        yield client.scheduler.address, client


def batch(table: Path, out: Path, *extra: str, scans: str = SCANS) -> int:
    return main(["batch", scans, "--calibration", str(table), "--config", CONFIG,
                 "--out", str(out), "-q", *extra])


@pytest.mark.slow
@needs_dask
def test_serial_and_two_workers_write_the_same_bytes(table, tmp_path, capsys, local_cluster,
                                                    monkeypatch):
    """Every file, byte for byte, and each scan's QA files are those of 'scanqa qa'. The
    cluster ``--workers 2`` asks for is the file's (the same open_client call, made once by
    the fixture): the command's request is checked, then its tasks run there."""
    asked, open_client = [], cluster.open_client

    @contextlib.contextmanager
    def the_files_cluster(options):
        asked.append(options)
        with open_client(cluster.EngineOptions(scheduler=local_cluster[0])) as opened:
            yield opened

    monkeypatch.setattr(cluster, "open_client", the_files_cluster)
    assert batch(table, tmp_path / "serial", "--layout", str(LAYOUT), "--serial") == 0
    assert batch(table, tmp_path / "dask", "--layout", str(LAYOUT), "--workers", "2",
                 "--dashboard", ":0") == 0
    assert asked == [TWO_WORKERS]
    serial, dask = tree(tmp_path / "serial"), tree(tmp_path / "dask")
    assert len(serial) == 1 + 3 * 7  # results.csv; 6 QA files and done.json per scan
    assert serial.keys() == dask.keys()
    assert [k for k in serial if serial[k] != dask[k]] == []
    # the same scan through 'scanqa qa': same tables, summary and cloud
    scan = SAMPLE / "gauge_blocks" / "p000_r1"
    assert main(["qa", str(scan), "--calibration", str(table), "--config", CONFIG,
                 "--layout", str(LAYOUT), "--out", str(tmp_path / "qa"), "-q"]) == 0
    for name in ("blocks.csv", "steps.csv", "budget.csv", "summary.json", "cloud_qa.ply"):
        assert serial[f"scans/p000_r1/{name}"] == (tmp_path / "qa" / name).read_bytes(), name
    # the results table repeats each scan's blocks.csv
    table_rows = {r["scan"]: r for r in rows(tmp_path / "serial" / "results.csv")}
    assert list(table_rows) == ["p000_r0", "p000_r1", "p000_r2"]
    for block in rows(tmp_path / "qa" / "blocks.csv"):
        got = table_rows["p000_r1"][f"block{block['block_id']}_measured_std_um"]
        assert float(got) == pytest.approx(float(block["measured_std_um"]), rel=1e-5)
        assert table_rows["p000_r1"][f"block{block['block_id']}_n_points"] == block["n_points"]


def _manifest(tmp_path: Path, names: list[tuple[str, str]]) -> Path:
    lines = ['format = "scanqa-batch/1"']
    for name, path in names:
        lines += ["[[scan]]", f'name = "{name}"', f'path = "{path}"']
    (tmp_path / "scans.toml").write_text("\n".join(lines) + "\n")
    return tmp_path / "scans.toml"


@pytest.mark.slow
@needs_dask
def test_killed_worker_loses_and_duplicates_nothing(table, tmp_path, local_cluster):
    """One worker is killed (os._exit) while it runs a scan: its nanny restarts it, the
    scan runs again, and the table has every scan once, with the serial run's bytes."""
    address, client = local_cluster
    gauge = SAMPLE / "gauge_blocks"
    manifest = _manifest(tmp_path, [(f"{c}{r}", str(gauge / f"p000_r{r}"))
                                    for c in "abc" for r in range(3)])
    killed = []

    def killer():
        deadline = time.monotonic() + 120
        scans = tmp_path / "dask" / "scans"
        while time.monotonic() < deadline and not list(scans.glob("*/done.json")):
            time.sleep(0.05)
        busy = [w for w, keys in client.processing().items() if keys]
        if busy:
            killed.append(busy[0])
            try:  # the worker dies before it can answer
                client.run(os._exit, 1, workers=[busy[0]], wait=False)
            except Exception:
                pass

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    assert batch(table, tmp_path / "dask", "--scheduler", address, "--layout",
                 str(LAYOUT), "--no-report", scans=str(manifest)) == 0
    thread.join()
    assert killed, "no worker was busy when the first scan finished"
    got = rows(tmp_path / "dask" / "results.csv")
    assert [r["scan"] for r in got] == [f"{c}{r}" for c in "abc" for r in range(3)]
    assert {r["status"] for r in got} == {"ok"}
    assert not list((tmp_path / "dask").rglob(STAGE_PREFIX + "*"))
    assert batch(table, tmp_path / "serial", "--serial", "--layout", str(LAYOUT),
                 "--no-report", scans=str(manifest)) == 0
    assert tree(tmp_path / "dask") == tree(tmp_path / "serial")


def test_a_bad_scan_fails_alone_and_a_rerun_resumes(table, tmp_path, capsys):
    gauge = SAMPLE / "gauge_blocks"
    (tmp_path / "empty").mkdir()
    manifest = _manifest(tmp_path, [("good", str(gauge / "p000_r0")),
                                    ("bad", str(tmp_path / "empty")),
                                    ("again", str(gauge / "p000_r2"))])
    out = tmp_path / "out"
    assert batch(table, out, "--serial", scans=str(manifest)) == 1
    result = rows(out / "results.csv")
    assert [(r["scan"], r["status"]) for r in result] == [
        ("good", "ok"), ("bad", "failed"), ("again", "ok")]
    assert str(tmp_path / "empty") in result[1]["error"]
    assert not (out / "scans" / "bad").exists()
    assert int(result[0]["points"]) > 60000
    # written while annotated (issue 31): the cloud of an in-memory annotate of the scan,
    # written apart by write_ply's chunk packer, read back alike
    config = load_config(SAMPLE / "sample_scanner.toml", "sample")
    ref = annotate(decode(gauge / "p000_r0"), load_calibration(table, config), config)
    ref_file = write_ply(tmp_path / "ref.ply", np.array(ref.xyz),
                         {k: np.array(v) for k, v in ref.attributes.items()})
    got_xyz, got, _ = read_ply(out / "scans" / "good" / "cloud.ply")
    want_xyz, want, _ = read_ply(ref_file)
    np.testing.assert_array_equal(got_xyz, want_xyz)
    assert got.keys() == want.keys()
    for name in want:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)
    printed = capsys.readouterr().out
    assert "failed: bad:" in printed and "2 ok, 1 failed" in printed
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    text = (out / "results.csv").read_bytes()
    assert batch(table, out, "--serial", scans=str(manifest)) == 1
    assert "(2 complete already)" in capsys.readouterr().out
    assert (out / "results.csv").read_bytes() == text
    marker = out / "scans" / "good" / "done.json"
    assert marker.stat().st_mtime_ns == before[marker]  # skipped, not redone
    # other settings: the markers' fingerprint no longer matches, every scan is redone
    assert batch(table, out, "--serial", "--keep-invalid", scans=str(manifest)) == 1
    assert "complete already" not in capsys.readouterr().out
    assert marker.stat().st_mtime_ns != before[marker]


def test_without_dask_runs_serially_and_says_so(table, tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(cluster, "dask_available", lambda: False)
    with caplog.at_level(logging.INFO, logger="scanqa"):
        assert main(["batch", str(SAMPLE / "gauge_blocks" / "p000_r0"), "--calibration",
                     str(table), "--config", CONFIG, "--out", str(tmp_path / "o")]) == 0
    notes = [r.getMessage() for r in caplog.records if "not installed" in r.getMessage()]
    assert len(notes) == 1 and "running serially" in notes[0]


def _one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("scanqa: "), err
    return lines[0]


def test_bad_input_gives_one_error_each(table, tmp_path, capsys, monkeypatch):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "scanqa-batch/1"\n[[scan]]\nname = "../x"\npath = "a"\n')
    assert "name must be" in _one_line_error(capsys, batch(table, tmp_path / "o",
                                                           scans=str(bad)))
    bad.write_text('format = "nope"\n')
    assert "format must be 'scanqa-batch/1'" in _one_line_error(
        capsys, batch(table, tmp_path / "o", scans=str(bad)))
    assert "no scans match" in _one_line_error(
        capsys, batch(table, tmp_path / "o", scans=str(tmp_path / "none*")))
    twice = _manifest(tmp_path, [("x", "a"), ("x", "b")])
    assert "two scans are named 'x'" in _one_line_error(
        capsys, batch(table, tmp_path / "o", scans=str(twice)))
    if cluster.dask_available():
        monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)
        msg = _one_line_error(capsys, batch(table, tmp_path / "o", "--scheduler",
                                            "tcp://127.0.0.1:9"))
        assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in msg
    assert not (tmp_path / "o" / "results.csv").exists()


def _campaign(tmp_path: Path, runs: list[str]) -> Path:
    blocks = {
        "sweep": ('experiment = "calibration-sweep"\npositions = [440.0, 452.0]\n'
                  "repeats = 2\n"),
        "cam": 'experiment = "camera-sweep"\npositions = [-10.0]\n'}
    text = 'format = "scanqa-campaign/1"\nseed = 11\n'
    for name in runs:
        text += f'\n[[run]]\nname = "{name}"\nconfig = "{ROI64}"\n{blocks[name]}'
    path = tmp_path / f"campaign_{'_'.join(runs)}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def serial_campaign(tmp_path_factory) -> tuple[Path, Path]:
    """(campaign file, its output folder) of the campaign of runs "sweep" and "cam" run
    serially: once for the two tests below."""
    tmp = tmp_path_factory.mktemp("campaign")
    campaign = _campaign(tmp, ["sweep", "cam"])
    assert main(["campaign", str(campaign), "--out", str(tmp / "serial"), "--serial",
                 "-q"]) == 0
    return campaign, tmp / "serial"


def test_campaign_run_is_what_simulate_writes_with_the_derived_seed(tmp_path,
                                                                    serial_campaign):
    """Each run's folder equals 'scanqa simulate' with the run's seed, and the seed is
    SHA-256 of 'campaign seed/run name' (computed here by hand): reordering the runs
    changes nothing."""
    seed = int.from_bytes(hashlib.sha256(b"11/sweep").digest()[:8], "big") % 10**9
    first = serial_campaign[1]
    assert main(["simulate", "calibration-sweep", "--config", ROI64, "--positions",
                 "440,452", "--repeats", "2", "--seed", str(seed), "--out",
                 str(tmp_path / "sim"), "-q"]) == 0
    assert tree(first / "sweep") == tree(tmp_path / "sim")
    assert {r["seed"] for r in rows(first / "results.csv")
            if r["run"] == "sweep"} == {str(seed)}
    assert main(["campaign", str(_campaign(tmp_path, ["cam", "sweep"])), "--out",
                 str(tmp_path / "b"), "--serial", "-q"]) == 0
    for run in ("sweep", "cam"):
        assert tree(first / run) == tree(tmp_path / "b" / run)


@pytest.mark.slow
@needs_dask
def test_campaign_is_the_same_on_two_workers(tmp_path, local_cluster, serial_campaign):
    campaign, serial_out = serial_campaign  # the serial run, shared with the test above
    assert main(["campaign", str(campaign), "--out", str(tmp_path / "dask"), "--scheduler",
                 local_cluster[0], "-q"]) == 0
    serial = tree(serial_out)
    assert len([k for k in serial if k.endswith("patterns.toml")]) == 5
    assert tree(tmp_path / "dask") == serial
    # an interrupted scan: its marker is missing, so a rerun redoes it (and only it)
    (tmp_path / "dask" / "done" / "sweep" / "p001_r1.json").unlink()
    shutil.rmtree(tmp_path / "dask" / "sweep" / "p001_r1")
    assert main(["campaign", str(campaign), "--out", str(tmp_path / "dask"), "--serial",
                 "-q"]) == 0
    assert tree(tmp_path / "dask") == serial
