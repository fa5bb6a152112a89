"""The fuzzer's physical-value class: inputs of the right type and shape whose values are
physically wrong, each with an oracle that does not ask the code under test.

Every case changes one valid input (tests/smallcases.py) and runs the command that reads
it through ``scanqa.cli.main``, like :mod:`tests.fuzz`; a case is *silent* when the run
exits 0 with a result its oracle calls wrong. The mutations:

- ``config``: a number of the config's [fringes] or [model] scaled by 10^k
  (|k| in 3, 6, 9) or set to 0; the oracle reads the written cloud: the median
  sigma_total_um of its points must be finite and within 1e-3 .. 1e5 um (the paper's
  scanner predicts ~10 um; a result 4 orders of magnitude away is no prediction);
- ``phase``: the phase map's sigma_xp scaled by 10^k or set to 0 (a decoder never knows a
  phase exactly: 0 must fail), with the same oracle;
- ``cloud``: a per-point value set to one no scan can hold (a sigma < 0 or 1e30, a flag
  of -4 or 7, a coordinate of 1e30, inf): must fail; or the coordinates written in
  another unit (m, um, inch): qa must not pass blocks it cannot see (exit 0 is silent
  unless every step is "not evaluated");
- ``repeats``: annotate with a repeat that is the scan plus its noise, or the scan of
  another scene (the plane 1-20 mm away): another scene accepted is silent;
- ``frames``: a phase-set frame zeroed, two frames of one set swapped, or a frame of
  another scene (the frame mirrored and shifted by a quarter of its width): decode may
  exit 2, or exit 0 with a warning; exit 0 without a warning is silent when x_p differs
  from the untouched scan's by more than 3 times its own stated sigma_xp.
"""

from __future__ import annotations

import json
import random
import shutil
import time
import traceback
from pathlib import Path

import numpy as np

from scanqa.io.tomlfile import dumps_toml, tomllib

from .fuzz import QUIET, SLOW_S, Outcome, _fast_reports, _promise_kept, run_case, signature
from .smallcases import command, write_inputs

KINDS = ("config", "phase", "cloud", "frames", "repeats")
#: Values no per-point column can hold, by column (the oracle's own physics).
IMPOSSIBLE = {"sigma_model_um": (-1.0, 1e30, float("inf")), "sigma_calibration_um": (-5.0, 1e30),
              "in_volume": (-4.0, 7.0), "model_valid": (-1.0, 2.0), "x_mm": (1e30, -1e30),
              "z_mm": (float("inf"), 1e25)}
#: Coordinate units of other conventions: scale from mm.
UNITS = {"m": 1e-3, "um": 1e3, "inch": 1 / 25.4, "cm": 0.1}


def _scaled(value: float, rng: random.Random) -> float:
    if rng.random() < 0.15:
        return 0.0
    return value * 10.0 ** (rng.choice((-1, 1)) * rng.choice((3, 6, 9)))


def _sigma_ok(cloud: Path) -> str:
    """'' when the written cloud's sigma is plausible, else why not (the oracle)."""
    from scanqa.io.ply import read_ply

    _, attrs, _ = read_ply(cloud)
    sig = np.asarray(attrs.get("sigma_total_um", []), float)
    sig = sig[np.isfinite(sig)]
    if sig.size == 0:
        return "no point has a finite sigma_total_um"
    med = float(np.median(sig))
    return "" if 1e-3 <= med <= 1e5 else f"median sigma_total_um {med:.3g} um"


def _phase_error(path: Path, reference: Path) -> str:
    """'' unless the decoded x_p differs from the untouched scan's by more than 3 times
    its own stated sigma_xp (median over the pixels valid in both) - the oracle of a
    decode: an error its uncertainty does not cover."""
    from scanqa.decoding.phasemap import load_phase_map

    got, ref = load_phase_map(path), load_phase_map(reference)
    both = got.valid & ref.valid
    if not both.any():
        return ""
    error = float(np.median(np.abs(got.xp[both] - ref.xp[both])))
    stated = float(np.median(got.sigma_xp[both]))
    return f"x_p off {error:.3g} px, stated sigma {stated:.3g} px, no warning" \
        if error > max(3.0 * stated, 1e-3) else ""


def _case(kind: str, base: Path, case_dir: Path, rng: random.Random
          ) -> tuple[list[str], object, str]:
    """(argv, oracle, what) of one case; the oracle maps (code, stderr) to '' or why the
    result is wrong."""
    case_dir.mkdir(parents=True)
    names = {"ply": "cloud.ply", "layout": "layout.toml", "config": "config.toml",
             "table": "table.npz", "phase": "phase.npz", "patterns": "patterns",
             "stack": "stack", "csv": "cloud.csv"}
    paths = {k: base / v for k, v in names.items()}
    out = case_dir / "out"
    if kind == "config":
        data = tomllib.loads((base / "config.toml").read_text())
        section = rng.choice(("fringes", "model"))
        keys = [k for k, v in data[section].items()
                if isinstance(v, (int, float, list)) and not isinstance(v, bool)]
        key = rng.choice(keys)
        value = data[section][key]
        data[section][key] = [_scaled(float(v), rng) for v in value] \
            if isinstance(value, list) else _scaled(float(value), rng)
        paths["config"] = case_dir / "config.toml"
        paths["config"].write_text(dumps_toml(data))
        what = f"{section}.{key} = {data[section][key]!r}"
        out.mkdir()
        return (command("config", paths, out), lambda c, e: _sigma_ok(out / "cloud.ply")
                if c == 0 else "", what)
    if kind == "phase":
        with np.load(base / "phase.npz") as npz:
            arrays = {k: npz[k] for k in npz.files}
        factor = _scaled(1.0, rng)
        arrays["sigma_xp"] = (arrays["sigma_xp"] * factor).astype(arrays["sigma_xp"].dtype)
        paths["phase"] = case_dir / "phase.npz"
        np.savez(paths["phase"], **arrays)
        out.mkdir()

        def oracle(code, err):
            if code != 0:
                return ""
            return "sigma_xp = 0 accepted" if factor == 0 else _sigma_ok(out / "cloud.ply")
        return command("phase", paths, out), oracle, f"sigma_xp x {factor:g}"
    if kind == "cloud":
        from scanqa.io.ply import read_ply, write_ply

        xyz, attrs, meta = read_ply(base / "cloud.ply")
        if rng.random() < 0.6:
            column = rng.choice(sorted(IMPOSSIBLE))
            value = rng.choice(IMPOSSIBLE[column])
            i = rng.randrange(len(xyz))
            if column.endswith("_mm"):
                xyz = xyz.copy()
                xyz[i, "xyz".index(column[0])] = value
            else:
                attrs = {**attrs, column: np.asarray(attrs.get(column, np.ones(len(xyz))),
                                                     float).copy()}
                attrs[column][i] = value
            what = f"{column}[{i}] = {value!r}"
            def oracle(code, err):
                return "an impossible value accepted" if code == 0 else ""
        else:
            unit = rng.choice(sorted(UNITS))
            xyz = xyz * UNITS[unit]
            what = f"coordinates in {unit}"

            def oracle(code, err, _out=out):
                if code != 0:
                    return ""
                summary = json.loads((_out / "summary.json").read_text())
                decided = [s for s in summary.get("steps", []) if s.get("evaluated")]
                return f"{len(decided)} steps decided on a cloud in {unit}" if decided else ""
        paths["ply"] = write_ply(case_dir / "cloud.ply", xyz, attrs, meta)
        return command("ply", paths, out), oracle, what
    if kind == "repeats":
        return _repeats_case(paths, case_dir, out, rng)
    # frames
    patterns = shutil.copytree(base / "patterns", case_dir / "patterns")
    paths["patterns"] = patterns
    sets = tomllib.loads((patterns / "patterns.toml").read_text())["set"]
    phase = [s for s in sets if s.get("kind") == "phase" and s.get("files")]
    pset = rng.choice(phase)
    files = list(pset["files"])
    op = rng.choice(("zero", "swap", "foreign"))
    k = rng.randrange(len(files))
    if op == "zero":
        from PIL import Image

        frame = np.asarray(Image.open(patterns / files[k]))
        Image.fromarray(np.zeros_like(frame)).save(patterns / files[k])
    elif op == "swap":
        j = (k + rng.randrange(1, len(files))) % len(files)
        a, b = (patterns / files[k]).read_bytes(), (patterns / files[j]).read_bytes()
        (patterns / files[k]).write_bytes(b)
        (patterns / files[j]).write_bytes(a)
    else:  # the frame of another scene: this one mirrored and shifted by a quarter
        from PIL import Image

        frame = np.asarray(Image.open(patterns / files[k]))
        Image.fromarray(np.roll(frame[:, ::-1], frame.shape[1] // 4, axis=1).copy()).save(
            patterns / files[k])
    out.mkdir()

    def frames_oracle(code, err, _out=out):
        if code != 0 or "scanqa: warning:" in err:
            return ""
        return _phase_error(_out / "phase.npz", base / "reference_phase.npz")
    return command("image", paths, out), frames_oracle, f"{op} {pset['name']} frame {k}"


def _repeats_case(paths: dict, case_dir: Path, out: Path, rng: random.Random):
    """annotate --repeats with a true repeat (the scan plus its noise) or the scan of
    another scene (the plane 1-20 mm away); another scene accepted is silent."""
    import dataclasses

    from scanqa.decoding.phasemap import load_phase_map, save_phase_map

    from .smallcases import phase_map, small_config

    scan = load_phase_map(paths["phase"])
    other = rng.random() < 0.5
    if other:
        dz = rng.choice((-1, 1)) * rng.uniform(1.0, 20.0)
        rep = phase_map(small_config(), 450.0 + dz)
        what = f"a repeat of the plane {dz:+.1f} mm away"
    else:
        noise = np.random.default_rng(rng.randrange(2**32)).normal(0, 1, scan.xp.shape)
        rep = dataclasses.replace(scan, xp=scan.xp + noise * np.nan_to_num(scan.sigma_xp))
        what = "a true repeat"
    save_phase_map(case_dir / "repeat.npz", rep)
    out.mkdir()
    argv = [*command("phase", paths, out), "--repeats", str(case_dir / "repeat.npz")]
    return argv, (lambda c, e: "another scene taken as a repeat" if other and c == 0
                  else ""), what


def fuzz_physical(kind: str, cases: int, seed: int, work: Path, render_every: int = 25
                  ) -> Outcome:
    """Run ``cases`` physical-value mutations of ``kind`` (:data:`KINDS`); a case whose
    oracle calls an exit-0 result wrong is listed in ``silent`` as (case, what, why)."""
    rng = random.Random(f"{seed}-physical-{kind}")
    base = work / "base"
    if not base.exists():
        write_inputs(base)
    if not (base / "reference_phase.npz").exists():  # the untouched scan, decoded
        code, err, exc = run_case(["decode", str(base / "patterns"), "--out",
                                   str(base / "reference_phase.npz"), *QUIET])
        assert code == 0 and exc is None, err
    result = Outcome()
    for i in range(cases):
        case_dir = work / f"physical-{kind}-{i}"
        argv, oracle, what = _case(kind, base, case_dir, rng)
        start = time.monotonic()
        with _fast_reports(i % render_every != 0):
            code, stderr, exc = run_case([*argv, *QUIET])
        took = time.monotonic() - start
        result.slowest_s = max(result.slowest_s, took)
        result.cases += 1
        result.exits[code] += 1
        if exc is not None:
            result.tracebacks.append((i, signature(exc),
                                      f"{what}\n" + "".join(traceback.format_exception(exc))))
        else:
            broken = _promise_kept(code, stderr, case_dir / "out", case_dir)
            if took > SLOW_S:
                broken = (f"{broken}; " if broken else "") + f"took {took:.0f} s (a hang)"
            if broken:
                result.broken_promises.append((i, f"{what}: {broken}"))
            why = oracle(code, stderr)
            if why:
                result.silent.append((i, what, why))
        shutil.rmtree(case_dir, ignore_errors=True)
    return result
