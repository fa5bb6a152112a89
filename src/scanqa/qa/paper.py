"""The paper's Table 3 beside scanqa's per-block numbers (Sect. 4 of [1]_).

Table 3 of [1]_ gives, per gauge block, the predicted and the measured standard
deviation of the points about a plane fitted on the block [um]. This module holds the
values as printed and joins them to a gauge-block result; the report renders the rows
(:mod:`scanqa.report.qa`) and computes nothing.

Where the text departs from a clean table: block 1's prediction is printed as "Large
value" (the block lies outside the calibrated volume), and block 6's measured value is
missing from the text (seven numbers for eight blocks, the gap under block 6); both are
None here, never a guessed number.

References
----------
.. [1] M.-A. Drouin, F. Blais, G. Godin, "Characterizing the impact of optically induced
   blurring of a high-resolution phase-shift 3D scanner", Machine Vision and
   Applications 28, 2017.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from scanqa.qa.results import BlockResult

#: Table 3 of the paper: block -> (predicted, measured) std [um]; None where the text prints
#: "Large value" (block 1, predicted) or nothing legible (block 6, measured).
PAPER_TABLE3 = {1: (None, 22), 2: (13, 12), 3: (13, 14), 4: (15, 16), 5: (16, 16),
                6: (17, None), 7: (21, 18), 8: (22, 20)}
#: Table 3's block heights, block 1 first [mm].
PAPER_TABLE3_HEIGHTS_MM = {1: 50.80, 2: 25.40, 3: 12.70, 4: 7.62, 5: 6.35, 6: 5.08,
                           7: 3.18, 8: 2.54}
#: The columns :func:`table3_rows` adds to a block's row.
TABLE3_COLUMNS = ("paper_predicted_um", "paper_measured_um", "paper_ratio")


def paper_ratio(block_id: int) -> float:
    """The paper's measured over predicted std of one block, from Table 3 [-].

    Parameters
    ----------
    block_id : int
        Block number, 1 (tallest) to 8 [-].

    Returns
    -------
    float
        s_measured / s_predicted [-]; NaN for a block the table has no pair for
        (block 1, block 6, an unknown block).

    Notes
    -----
    The same ratio as :attr:`BlockResult.ratio`, s_meas / s_pred, on the printed values
    of Table 3 in Sect. 4.3 of the paper: a model that predicts the measured std has a ratio
    of 1, whatever the noise level.

    Examples
    --------
    >>> round(paper_ratio(7), 4)
    0.8571
    """
    predicted, measured = PAPER_TABLE3.get(block_id, (None, None))
    if predicted is None or measured is None:
        return math.nan
    return measured / predicted


def paper_series(block_ids: Iterable[int]) -> tuple[list[float], list[float]]:
    """Table 3's predicted and measured std for each block, NaN where it has none [um].

    Parameters
    ----------
    block_ids : iterable of int
        Block numbers [-].

    Returns
    -------
    predicted, measured : list of float
        One value per block [um].

    Notes
    -----
    The printed values of Table 3 in Sect. 4.3 of the paper, looked up, not computed.
    """
    pairs = [PAPER_TABLE3.get(i, (None, None)) for i in block_ids]
    return ([math.nan if p is None else float(p) for p, _ in pairs],
            [math.nan if m is None else float(m) for _, m in pairs])


def table3_rows(blocks: Iterable[BlockResult], paper: bool) -> list[dict]:
    """Every block's row, with Table 3's values beside scanqa's when ``paper`` is set.

    Parameters
    ----------
    blocks : iterable of BlockResult
        scanqa's per-block results.
    paper : bool
        Add :data:`TABLE3_COLUMNS` (the layout asks for the paper comparison).

    Returns
    -------
    list of dict
        :meth:`BlockResult.row` per block; with ``paper``, also the paper's predicted
        std ("large/-" for block 1's "Large value"), measured std ("-" where illegible)
        [um] and their ratio (NaN where a value is missing) [-].

    Notes
    -----
    Table 3 in Sect. 4.3 of the paper, joined by block number; the ratio as
    :func:`paper_ratio`.
    """
    rows = []
    for block in blocks:
        row = block.row()
        if paper:
            predicted, measured = PAPER_TABLE3.get(block.block_id, (None, None))
            row.update(paper_predicted_um=predicted if predicted is not None else "large/-",
                       paper_measured_um=measured if measured is not None else "-",
                       paper_ratio=paper_ratio(block.block_id))
        rows.append(row)
    return rows
