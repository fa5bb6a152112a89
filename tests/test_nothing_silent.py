"""Nothing silent, round 3 (issue 45): each case a second adversary got through, refused or
warned with one line naming the file, field or request and the fix.

Covers: a publication interrupted between any two of its file operations; outputs that
would overwrite an input; tracebacks of compare, the mesh reader and the table reader;
physical values off by orders of magnitude in configs, phase maps, clouds and CSV files;
a zeroed, black or swapped frame in a phase set.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from scanqa.io import atomic


def _publish_old_then_new(root: Path) -> None:
    out = root / "out"
    with atomic.staged_dir(out) as stage:
        for name in ("budget.csv", "steps.csv", "report.html"):
            (stage / name).write_text(f"old {name}")
    with atomic.staged_dir(out) as stage:
        for name in ("budget.csv", "steps.csv", "report.html", "new.json"):
            (stage / name).write_text(f"new {name}")
        (stage / "sub").mkdir()
        (stage / "sub" / "x.txt").write_text("new x")


@pytest.mark.parametrize("after", [False, True], ids=["before-call", "after-call"])
def test_publication_interrupted_between_any_two_lines_loses_nothing(tmp_path, monkeypatch,
                                                                     after):
    """An interrupt before or after every rename or link of the second publication leaves
    the folder exactly as the first one wrote it, or exactly as the second (issue 45: a
    KeyboardInterrupt between two lines of the old _apply deleted budget.csv)."""
    old = {"budget.csv": b"old budget.csv", "steps.csv": b"old steps.csv",
           "report.html": b"old report.html"}
    new = {"budget.csv": b"new budget.csv", "steps.csv": b"new steps.csv",
           "report.html": b"new report.html", "new.json": b"new new.json",
           "sub/x.txt": b"new x"}
    real = {"replace": os.replace, "link": os.link, "rename": os.rename}
    outcomes = set()
    for k in range(40):
        calls = [0]

        def hook(name, *args, _k=k, _calls=calls, **kw):
            _calls[0] += 1
            if not after and _calls[0] == _k + 1:
                raise KeyboardInterrupt
            result = real[name](*args, **kw)
            if after and _calls[0] == _k + 1:
                raise KeyboardInterrupt
            return result

        root = tmp_path / f"run{k}"
        root.mkdir()
        for name in real:
            monkeypatch.setattr(atomic.os, name,
                                lambda *a, _n=name, **kw: hook(_n, *a, **kw))
        calls[0] = -10**6  # the first publication runs untouched
        with atomic.staged_dir(root / "out") as stage:
            for name, text in old.items():
                (stage / name).write_bytes(text)
        calls[0] = 0
        try:
            with atomic.staged_dir(root / "out") as stage:
                for name, text in new.items():
                    (stage / name).parent.mkdir(exist_ok=True)
                    (stage / name).write_bytes(text)
            outcome = "new"
        except KeyboardInterrupt:
            outcome = "interrupted"
        monkeypatch.undo()
        got = {str(p.relative_to(root / "out")): p.read_bytes()
               for p in sorted((root / "out").rglob("*")) if p.is_file()}
        assert got in (old, new), (k, outcome, got)
        assert (got == new) == (outcome == "new"), (k, outcome)
        assert [p.name for p in root.iterdir()] == ["out"], k  # no stage left behind
        outcomes.add(outcome)
        if outcome == "new":
            break
    assert outcomes == {"interrupted", "new"}
