"""The fuzz test: seeded mutations of the nine input formats through the command line.

A slice of 40 cases per format runs here; ``make fuzz`` runs 560 per format (``python -m
tests.fuzz 560``). SCANQA_FUZZ_CASES and SCANQA_FUZZ_SEED change the size and the seed of
this slice. Besides tracebacks and broken promises, an input invalid for certain that is
accepted (exit 0) fails the slice.
"""

from __future__ import annotations

import os

import pytest

from .fuzz import FORMATS, KNOWN_DECODER_CRASHES, fuzz_format

CASES = int(os.environ.get("SCANQA_FUZZ_CASES", "40"))
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
