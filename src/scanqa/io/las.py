"""LAS 1.4 point clouds with float extra-byte dimensions (read by CloudCompare and PDAL).

Coordinates are stored as scaled integers with a 0.1 um scale [mm]; every attribute is
an extra-bytes dimension of type float32 named as in the PLY export.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scanqa.errors import InputError
from scanqa.io.atomic import atomic_path

#: Coordinate resolution of the LAS export [mm].
LAS_SCALE_MM = 1e-4


def _laspy():
    try:
        import laspy
    except ImportError:  # pragma: no cover - laspy is a dependency
        raise InputError("LAS export needs the 'laspy' package (pip install laspy)") from None
    return laspy


def write_las(path: str | os.PathLike, xyz: np.ndarray, attributes: dict[str, np.ndarray]
              ) -> Path:
    """Write a LAS 1.4 file (point format 6) with float32 extra bytes, atomically.

    Parameters
    ----------
    path : str or PathLike
        Output file.
    xyz : (n, 3) float
        Coordinates [mm].
    attributes : dict of str to (n,) array
        Per-point values stored as float32 extra-byte dimensions.
    """
    laspy = _laspy()
    xyz = np.asarray(xyz, dtype=float)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, LAS_SCALE_MM)
    header.offsets = np.floor(np.nanmin(xyz, axis=0)) if len(xyz) else np.zeros(3)
    for name in attributes:
        if len(name) > 32:
            raise InputError(f"LAS extra-byte names are limited to 32 characters: {name!r}")
        header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=np.float32))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    for name, values in attributes.items():
        las[name] = np.asarray(values, dtype=np.float32)
    with atomic_path(path, suffix=".las") as tmp:
        las.write(str(tmp))
    return Path(path)


def read_las(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read coordinates and extra-byte dimensions of a LAS file."""
    laspy = _laspy()
    try:
        las = laspy.read(str(path))
    except (OSError, laspy.errors.LaspyException) as err:
        raise InputError(f"cannot read LAS file {path}: {err}") from None
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], -1)
    extra = {d: np.asarray(las[d]) for d in las.point_format.extra_dimension_names}
    return xyz, extra
