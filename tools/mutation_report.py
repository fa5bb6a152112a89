"""Summarise a mutmut run (`make mutate`): kill rate per module and every surviving mutant.

Reads the per-file results mutmut leaves in ``mutants/`` and prints, per mutated module,
killed / total (a timeout counts as killed: the mutant changed behaviour enough to hang a
test; "no tests" counts as surviving), then each survivor with its diff. Exits 1 when a
module's kill rate is below the threshold (85 %; 90 % for what decides pass or fail,
:data:`DECIDING`; docs/mutation.rst).

Usage: ``python tools/mutation_report.py [--threshold 0.85] [--no-diff]``
"""

from __future__ import annotations

import argparse
import ast
import difflib
import functools
import json
import sys
from collections import Counter
from pathlib import Path

from mutmut.stats import status_by_exit_code

DETECTED = {"killed", "timeout", "caught by type check", "segfault"}
#: The modules that decide pass or fail, held to a higher kill rate (issue 28).
DECIDING = {"scanqa/qa/vdi2634.py": 0.90, "scanqa/qa/verdict.py": 0.90,
            "scanqa/qa/budget.py": 0.90}


def load(root: Path) -> dict[str, dict[str, str]]:
    """Status of every mutant, per source file (path relative to ``src``)."""
    out = {}
    for meta in sorted(root.glob("src/**/*.py.meta")):
        codes = json.loads(meta.read_text())["exit_code_by_key"]
        name = meta.relative_to(root / "src").as_posix().removesuffix(".meta")
        out[name] = {key: status_by_exit_code[code] for key, code in codes.items()}
    return out


@functools.cache
def _functions(path: Path) -> dict[str, tuple[int, list[str]]]:
    """First line and source lines of every function (methods too) in a file, by name."""
    text = path.read_text()
    lines = text.splitlines()
    out = {}
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            out[node.name] = (node.lineno, lines[node.lineno - 1:node.end_lineno])
    return out


def describe(root: Path, key: str) -> str:
    """Where a mutant is (file:line of the original source) and what it changes."""
    module, _, mangled = key.rpartition(".")
    func, _, number = mangled.rpartition("__mutmut_")
    rel = Path(*module.split(".")).with_suffix(".py")
    mutants = _functions(root / "src" / rel)
    name = func.split("ǁ")[-1].removeprefix("x_")
    orig = mutants[f"{func}__mutmut_orig"][1]
    new = mutants[f"{func}__mutmut_{number}"][1]
    orig = [orig[0].replace(f"{func}__mutmut_orig", name), *orig[1:]]
    new = [new[0].replace(f"{func}__mutmut_{number}", name), *new[1:]]
    start = _functions(Path("src") / rel)[name][0]
    lines = []
    for group in difflib.SequenceMatcher(a=orig[1:], b=new[1:]).get_grouped_opcodes(0):
        for tag, i1, i2, j1, j2 in group:
            if tag != "equal":
                line = start + 1 + i1
                lines += [f"  {rel}:{line}"]
                lines += [f"  - {t.strip()}" for t in orig[1 + i1:1 + i2]]
                lines += [f"  + {t.strip()}" for t in new[1 + j1:1 + j2]]
    if orig[0] != new[0]:  # the signature (a default value)
        lines += [f"  {rel}:{start}", f"  - {orig[0].strip()}", f"  + {new[0].strip()}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threshold", type=float, default=0.85)
    parser.add_argument("--no-diff", action="store_true", help="list survivors without diffs")
    parser.add_argument("--mutants", type=Path, default=Path("mutants"))
    args = parser.parse_args(argv)
    results = load(args.mutants)
    if not results:
        print(f"no mutmut results under {args.mutants}/ (run `make mutate`)", file=sys.stderr)
        return 2
    low = []
    print(f"{'module':36s} {'killed':>7s} {'total':>6s} {'rate':>7s}  other")
    for name, status in results.items():
        counts = Counter(status.values())
        killed = sum(n for s, n in counts.items() if s in DETECTED)
        rate = killed / len(status) if status else 1.0
        other = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()) if s not in DETECTED)
        print(f"{name:36s} {killed:7d} {len(status):6d} {rate:7.1%}  {other}")
        if rate < max(args.threshold, DECIDING.get(name, 0.0)):
            low.append(name)
    for status in results.values():
        for key, st in status.items():
            if st in DETECTED:
                continue
            print(f"{st}: {key}")
            if not args.no_diff and st != "not checked":
                print(describe(args.mutants, key))
    if low:
        print(f"\nkill rate below {args.threshold:.0%} (90 % for {', '.join(DECIDING)}): "
              f"{', '.join(low)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
