"""The display fields of a scanqa PLY: grey intensity and colours derived from the
fringe offset (:mod:`scanqa.io.ply`).

A cloud with an ``offset_dn`` attribute carries, after its attributes, a ``float
intensity`` (the 16-bit grey level the LAS export stores as intensity [-]) and a grey
``uchar red, green, blue`` (its top 8 bits) with ``alpha`` 255, so that viewers colour it
by the scene's brightness. A producer that writes a cloud in chunks fills each chunk's
display fields as it goes (:func:`display_scale` before, :func:`fill_display` per chunk).
"""

from __future__ import annotations

import numpy as np

from scanqa.io.las import INTENSITY_SOURCE, grey_scale, scaled_grey

#: Display fields written after the attributes of a cloud with an ``offset_dn``
#: attribute: 8 bytes, so that records stay whole 4-byte words.
DISPLAY_FIELDS = (("intensity", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                  ("alpha", "u1"))
#: Header comment that marks the display fields as derived from ``scalar_offset_dn``.
DISPLAY_COMMENT = "comment scanqa-display intensity red green blue alpha"
#: The PLY property the display fields derive from (``scalar_`` + the LAS intensity source).
LEVEL_FIELD = "scalar_" + INTENSITY_SOURCE


#: Records whose display fields are filled per pass of :func:`fill_display`.
_DISPLAY_CHUNK = 1 << 16


def fill_display_records(records: np.ndarray) -> None:
    """Fill the display fields of records from their own ``offset_dn`` field, chunk by
    chunk: the grey levels of :func:`scanqa.io.las.grey_levels` (the same scale and
    rounding, element by element in float64) without its five full-size temporaries."""
    fill_display(records, grey_scale(records[LEVEL_FIELD]))


def display_scale(levels: np.ndarray) -> float:
    """The grey scale of the display fields of records whose ``offset_dn`` will be
    ``levels`` [DN], known before the records are written (:func:`fill_display`).

    Parameters
    ----------
    levels : (n,) float ndarray
        The ``offset_dn`` of every record, in any order [DN]; rounded to float32 here,
        as the records hold them.

    Returns
    -------
    float
        The factor :func:`write_ply` scales the levels by [1/DN]
        (:func:`scanqa.io.las.grey_scale`): the same order statistics of the same
        float32 values.
    """
    return grey_scale(np.asarray(levels, dtype=np.float32))


def fill_display(records: np.ndarray, scale: float) -> None:
    """Fill the display fields of records (:func:`vertex_dtype` with ``offset_dn``) from
    their own ``offset_dn`` field, chunk by chunk.

    Parameters
    ----------
    records : (n,) ndarray
        Records in the layout of :func:`vertex_dtype`, ``offset_dn`` written.
    scale : float
        The grey scale of the whole cloud (:func:`display_scale`) [1/DN].

    Notes
    -----
    The grey levels of :func:`scanqa.io.las.grey_levels` (the same scale and rounding,
    element by element in float64) without its five full-size temporaries; a producer
    that writes a cloud in chunks can fill each chunk's display fields as it goes.
    """
    level = records[LEVEL_FIELD]
    for a in range(0, records.size, _DISPLAY_CHUNK):
        v = np.nan_to_num(level[a:a + _DISPLAY_CHUNK].astype(float), nan=0.0, copy=False)
        fill_display_grey(records[a:a + _DISPLAY_CHUNK], scaled_grey(v, scale))


def fill_display_grey(records: np.ndarray, grey: np.ndarray) -> None:
    """Write the display fields of records (:data:`DISPLAY_FIELDS`, the last 8 bytes)
    from 16-bit grey levels: intensity, and red = green = blue = the top 8 bits, alpha
    255, as one little-endian word per record."""
    words = records.view(np.uint32).reshape(records.size, records.itemsize // 4)
    words[:, -2] = grey.astype(np.float32).view(np.uint32)
    rgba = grey.astype(np.uint32)
    rgba >>= 8
    rgba *= 0x010101
    rgba += 0xFF000000
    words[:, -1] = rgba
