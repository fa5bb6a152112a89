"""Sum a SCANQA_TEST_CPU_LOG file (tests/conftest.py) per test file and per test.

    SCANQA_TEST_CPU_LOG=/tmp/cpu.tsv pytest -n0 tests/...
    python tools/test_cpu_times.py /tmp/cpu.tsv [N]

Prints the CPU seconds per file, largest first, then the N slowest tests (default 20).
"""

from __future__ import annotations

import sys
from collections import defaultdict


def main(argv: list[str]) -> int:
    rows = []
    with open(argv[0], encoding="utf-8") as fh:
        for line in fh:
            seconds, nodeid = line.rstrip("\n").split("\t", 1)
            rows.append((float(seconds), nodeid))
    per_file: dict[str, float] = defaultdict(float)
    count: dict[str, int] = defaultdict(int)
    for seconds, nodeid in rows:
        per_file[nodeid.split("::")[0]] += seconds
        count[nodeid.split("::")[0]] += 1
    total = sum(per_file.values())
    print(f"{total:8.1f} s CPU in {len(rows)} tests, {len(per_file)} files")
    for name, seconds in sorted(per_file.items(), key=lambda kv: -kv[1]):
        print(f"{seconds:8.1f} s  {count[name]:4d} tests  {name}")
    n = int(argv[1]) if len(argv) > 1 else 20
    print(f"slowest {n} tests:")
    for seconds, nodeid in sorted(rows, reverse=True)[:n]:
        print(f"{seconds:8.1f} s  {nodeid}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
