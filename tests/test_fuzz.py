"""The fuzz test: seeded mutations of the nine input formats through the command line.

A slice of 40 cases per format, and 12 of each physical-value kind
(tests/fuzz_physical.py), runs here; ``make fuzz`` runs 560 of each (``python -m
tests.fuzz 560``). SCANQA_FUZZ_CASES and SCANQA_FUZZ_SEED change the size and the seed of
this slice. Besides tracebacks and broken promises, an input invalid for certain that is
accepted (exit 0) fails the slice.
"""

from __future__ import annotations

import os

import pytest

from .fuzz import FORMATS, KNOWN_DECODER_CRASHES, fuzz_format
from .fuzz_physical import KINDS, fuzz_physical

CASES = int(os.environ.get("SCANQA_FUZZ_CASES", "40"))
#: Cases of each physical-value kind in this slice (``make fuzz`` runs hundreds).
PHYSICAL_CASES = int(os.environ.get("SCANQA_FUZZ_PHYSICAL_CASES", "12"))
SEED = int(os.environ.get("SCANQA_FUZZ_SEED", "0"))


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.parametrize("kind", FORMATS)
def test_mutated_inputs_give_one_line_or_a_result(kind, work):
    result = fuzz_format(kind, CASES, SEED, work)
    assert result.cases == CASES
    known = KNOWN_DECODER_CRASHES if kind == "patterns" else {}
    unexpected = [(case, sig, text) for case, sig, text in result.tracebacks
                  if sig not in known]
    assert not unexpected, f"{len(unexpected)} tracebacks, first:\n{unexpected[0][2]}"
    assert result.broken_promises == []
    assert result.silent == [], f"invalid inputs accepted: cases {result.silent}"
    assert result.exits[2] > 0  # the mutations do reach the error paths


@pytest.mark.parametrize("kind", KINDS)
def test_physically_wrong_values_are_refused_or_warned(kind, work):
    """Values off by orders of magnitude, zeroed/swapped/foreign frames, coordinates in
    other units: exit 2, or a warning, or a result its oracle accepts (tests/fuzz_physical)."""
    result = fuzz_physical(kind, PHYSICAL_CASES, SEED, work)
    assert result.cases == PHYSICAL_CASES
    assert not result.tracebacks, result.tracebacks[0][2]
    assert result.broken_promises == []
    assert result.silent == [], f"silent-wrong results: {result.silent}"
