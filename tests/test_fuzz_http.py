"""The design page's HTTP surface under seeded requests (tests/fuzz_http.py).

A slice of 120 requests runs here (about a second of model time per valid view);
``make fuzz`` runs 1000. Every request is answered - no 500, no traceback on the server,
no hang - and every request the server must refuse is refused with its status.
"""

from __future__ import annotations

from .fuzz_http import fuzz_http


def test_design_page_http_fuzz_slice():
    res = fuzz_http(120, 3)
    assert res.cases == 120
    assert res.failures == [] and res.silent == []
    # the slice reached the refusals, not only the happy path
    assert {400, 403, 404}.issubset(res.statuses) and res.statuses[200] > 0
