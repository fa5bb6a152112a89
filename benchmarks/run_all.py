"""Run every ``benchmarks/bench_*.py`` and print one table of their results.

Each script runs in its own subprocess, one after another (so that they do not compete
for the cores), with its output captured. Its result lines are read from its standard
output: a line is a result when it states a time; from it the runner takes

- stage: the words before the first ``:`` (or before the first number), ``RESULT``
  dropped; for a JSON line, the script name and its ``size``;
- time: the total after ``=``, else the value after ``best``, else the first
  ``<number> s`` (JSON: ``seconds``);
- throughput: the first ``<number> <unit>/s`` (Mpx/s, Mpt/s, ...);
- peak memory: ``peak RSS <number> GB|MB`` (JSON: ``peak_rss_mb``);
- target: every ``target <= <number> s|GB|MB`` (or ``<``) in the line, and ``faster than
  NAME``, met when the line reports ``.../NAME time`` below 1. Scripts whose lines carry
  no target get the one their docstring states (:data:`DOCSTRING_TARGETS`).

Each script also gets a row of its own: wall time and the peak resident memory of its
whole process tree (``wait4``). A script that exits non-zero, times out or prints no
result line is shown as FAILED with the end of its stderr, and the runner exits 1.
Unmet targets are shown (``NO``) but do not change the exit code: timings depend on the
machine, and tests never assert them.

Usage::

    .venv/bin/python benchmarks/run_all.py [--only NAME ...] [--timeout S] [--verbose]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
#: Targets stated in a script's docstring, for scripts whose result lines print none.
DOCSTRING_TARGETS: dict = {}

_NUM = r"(\d+(?:\.\d+)?)"
_TIME = re.compile(_NUM + r"\s?(ms|s)\b")
_TOTAL = re.compile(r"(?<![<>≤])=\s*" + _NUM + r"\s?(ms|s)\b")
_BEST = re.compile(r"\bbest\s+" + _NUM + r"\s?(ms|s)\b")
_RATE = re.compile(_NUM + r"\s?([kMG]?(?:px|pt|pts|points|B|scans?)/s)")
_PEAK = re.compile(r"peak RSS\s*" + _NUM + r"\s?(GB|MB)", re.I)
_TARGET = re.compile(r"target\s*(<=|<|≤)\s*" + _NUM + r"\s?(ms|s|GB|MB)\b", re.I)
_FASTER = re.compile(r"faster than (\w+)")
_MB = {"MB": 1.0, "GB": 1024.0}
_SECONDS = {"s": 1.0, "ms": 1e-3}


@dataclass
class Row:
    """One result of a script (lengths of time in s, memory in MB)."""

    stage: str
    seconds: float | None = None
    rate: str = "-"
    peak_mb: float | None = None
    targets: list = field(default_factory=list)   # (op, value, unit)
    faster: list = field(default_factory=list)    # (name, ratio or None)
    status: str = ""

    @property
    def target_text(self) -> str:
        parts = [f"{op} {value:g} {unit}" for op, value, unit in self.targets]
        parts += [f"faster than {name}" for name, _ in self.faster]
        return ", ".join(parts) or "-"

    def met(self) -> str:
        """"yes", "NO", "?" (a target without a value to compare) or "-" (no target)."""
        if self.status:
            return self.status
        checks = [_check(op, value, unit, self.seconds if unit in _SECONDS else self.peak_mb)
                  for op, value, unit in self.targets]
        checks += [None if ratio is None else ratio < 1.0 for _, ratio in self.faster]
        if not checks:
            return "-"
        if any(c is False for c in checks):
            return "NO"
        return "yes" if all(checks) else "?"


def _check(op: str, limit: float, unit: str, value: float | None) -> bool | None:
    if value is None:
        return None
    limit *= _SECONDS.get(unit, 1.0) * _MB.get(unit, 1.0)
    return value < limit if op == "<" else value <= limit


def _stage(line: str, script: str) -> str:
    text = re.sub(r"^\s*RESULT\s+", "", line)
    colon, digit = text.find(":"), re.search(r"\d", text)
    end = min(i for i in (colon if colon >= 0 else len(text),
                          digit.start() if digit else len(text)))
    stage = re.sub(r"\s+best\s*$", "", text[:end].strip())
    return stage or script


def _targets(text: str) -> list:
    return [(op.replace("≤", "<="), float(v), u if u in _SECONDS else u.upper())
            for op, v, u in _TARGET.findall(text)]


def parse_line(line: str, script: str) -> Row | None:
    """A :class:`Row` from one output line, or None when it states no time."""
    text = line.strip()
    if text.startswith("{"):
        return _parse_json(text, script)
    bare = _TARGET.sub("", text)  # a target's number is not a measured one
    found = _TOTAL.search(bare) or _BEST.search(bare) or _TIME.search(bare)
    if not found:
        return None
    row = Row(_stage(text, script), float(found.group(1)) * _SECONDS[found.group(2)])
    rate = _RATE.search(bare)
    row.rate = f"{rate.group(1)} {rate.group(2)}" if rate else "-"
    peak = _PEAK.search(bare)
    row.peak_mb = float(peak.group(1)) * _MB[peak.group(2).upper()] if peak else None
    row.targets = _targets(text)
    for name in _FASTER.findall(text):
        ratio = re.search(rf"/{re.escape(name)} time\s*{_NUM}", text)
        row.faster.append((name, float(ratio.group(1)) if ratio else None))
    return row


def _parse_json(text: str, script: str) -> Row | None:
    try:
        data = json.loads(text)
    except ValueError:
        return None
    if not isinstance(data, dict) or "seconds" not in data:
        return None
    stage = f"{script.removeprefix('bench_')} {data['size']}" if "size" in data else script
    peak = data.get("peak_rss_mb")
    row = Row(stage, float(data["seconds"]), peak_mb=None if peak is None else float(peak))
    row.targets = _targets(str(data.get("target", "")))
    return row


@dataclass
class Run:
    """A finished script: exit code, output, wall time [s], process-tree peak [MB]."""

    script: str
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    peak_mb: float | None
    timed_out: bool = False


def run_script(path: Path, timeout: float) -> Run:
    """Run one script in its own process group; kill the group after ``timeout``."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, str(path)], stdout=out, stderr=err,
                                cwd=ROOT, text=True, start_new_session=True)
        expired = threading.Event()

        def kill() -> None:
            expired.set()
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

        timer = threading.Timer(timeout, kill)
        timer.start()
        try:
            if hasattr(os, "wait4"):  # rusage of this child and the children it waited for
                _, status, usage = os.wait4(proc.pid, 0)
                proc.returncode = os.waitstatus_to_exitcode(status)
                peak = usage.ru_maxrss / 1024.0
            else:  # pragma: no cover - not Linux
                proc.wait()
                peak = None
        finally:
            timer.cancel()
        seconds = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        return Run(path.stem, proc.returncode, out.read(), err.read(), seconds, peak,
                   expired.is_set())


def rows_of(run: Run) -> tuple[list[Row], bool]:
    """Result rows of a run (with its own summary row last) and whether it failed."""
    rows = [r for r in (parse_line(line, run.script) for line in run.stdout.splitlines())
            if r is not None]
    fallback = _targets(DOCSTRING_TARGETS.get(run.script, ""))
    for r in rows:
        if not r.targets and not r.faster:
            r.targets = list(fallback)
    failed = run.returncode != 0 or run.timed_out or not rows
    summary = Row(f"{run.script}.py (whole script)", run.seconds, peak_mb=run.peak_mb)
    if run.timed_out:
        summary.status = "FAILED (timeout)"
    elif run.returncode != 0:
        summary.status = f"FAILED (exit {run.returncode})"
    elif not rows:
        summary.status = "FAILED (no result line)"
    else:
        summary.status = "ok"
    return [*rows, summary], failed


def _fmt_time(s: float | None) -> str:
    if s is None:
        return "-"
    return f"{s * 1e3:.0f} ms" if s < 0.1 else f"{s:.2f} s" if s < 100 else f"{s:.0f} s"


def _fmt_mem(mb: float | None) -> str:
    if mb is None:
        return "-"
    return f"{mb / 1024:.2f} GB" if mb >= 1024 else f"{mb:.0f} MB"


def format_table(rows: list[Row]) -> str:
    """Aligned text table: stage, time, throughput, peak memory, target, met?."""
    head = ("stage", "time", "throughput", "peak memory", "target", "met?")
    cells = [(r.stage, _fmt_time(r.seconds), r.rate, _fmt_mem(r.peak_mb), r.target_text,
              r.met()) for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(head)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(cell, widths, strict=True))
              for cell in cells]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="+", metavar="NAME", default=None,
                    help="run only these scripts (e.g. bench_decode or decode)")
    ap.add_argument("--timeout", type=float, default=1800.0,
                    help="seconds per script before it is killed (default 1800)")
    ap.add_argument("--verbose", action="store_true", help="echo each script's output")
    args = ap.parse_args(argv)
    scripts = sorted(HERE.glob("bench_*.py"))
    if args.only:
        wanted = {n.removesuffix(".py").removeprefix("bench_") for n in args.only}
        scripts = [s for s in scripts if s.stem.removeprefix("bench_") in wanted]
    if not scripts:
        print("run_all: no benchmark script to run", file=sys.stderr)
        return 2
    rows, failures = [], []
    for path in scripts:
        print(f"run_all: {path.name} ...", file=sys.stderr, flush=True)
        run = run_script(path, args.timeout)
        script_rows, failed = rows_of(run)
        rows += script_rows
        print(f"run_all: {path.name} {script_rows[-1].status} in {run.seconds:.1f} s",
              file=sys.stderr, flush=True)
        if args.verbose:
            print(run.stdout.rstrip(), file=sys.stderr)
        if failed:
            failures.append(run)
    print(format_table(rows))
    for run in failures:
        tail = "\n    ".join(run.stderr.strip().splitlines()[-8:]) or "(no stderr)"
        print(f"\n{run.script}.py failed (exit {run.returncode}"
              f"{', timed out' if run.timed_out else ''}):\n    {tail}")
    unmet = sum(r.met() == "NO" for r in rows)
    print(f"\n{len(scripts) - len(failures)} of {len(scripts)} scripts ran"
          + (f"; {unmet} target(s) not met on this machine" if unmet else ""))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
