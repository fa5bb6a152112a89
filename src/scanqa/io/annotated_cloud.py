"""Annotated point clouds: metric points with per-point attributes and their provenance.

An :class:`AnnotatedCloud` is what :func:`scanqa.annotation.points.annotate` returns and what
the QA reads. Its ``metadata`` travels with it into every file format (a PLY header
comment, a LAS variable-length record, a CSV comment line, Parquet key-value metadata),
so that a cloud read back still says which model variant and parameters gave its
sigmas, with which scanner config, table and software version.

Lengths are millimetres; attribute units are in their names (``_um``, ``_dn``, ...;
docs/formats.rst lists every attribute).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from scanqa.io import cloud as cloud_file

#: Per-point random sigma attributes, most specific first: the one the cloud's
#: ``sigma_source`` chose (clouds from this version), else the model's (older clouds).
RANDOM_SIGMA_NAMES = ("sigma_random_um", "sigma_model_um")


def random_sigma_name(attributes: dict) -> str | None:
    """Name of the per-point random sigma attribute a cloud carries [um], or None."""
    return next((n for n in RANDOM_SIGMA_NAMES if n in attributes), None)


@dataclass(frozen=True, eq=False)
class AnnotatedCloud:
    """Points [mm] with per-point attributes, provenance, and counts of what was left out.

    Attributes
    ----------
    xyz : (n, 3) float64
        Points in the scanner frame [mm].
    attributes : dict of str to (n,) array
        Per-point values, units in the names (``sigma_model_um`` [um], ...).
    counts : dict
        From :func:`~scanqa.annotation.points.annotate`: pixels written and left out, by reason.
    metadata : dict
        Plain JSON: ``model`` (the variant and parameters that gave ``sigma_model_um``),
        ``config`` (the scanner config, as :meth:`ScannerConfig.to_dict`), ``table``,
        ``source``, ``software``. Empty for a cloud from elsewhere.

    Notes
    -----
    From :func:`~scanqa.annotation.points.annotate`, ``xyz`` and the float32 attributes are views
    of one record array in the binary PLY layout, which :meth:`write` writes as it is.
    """

    xyz: np.ndarray
    attributes: dict
    counts: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = np.shape(self.xyz)[0] if np.ndim(self.xyz) == 2 else -1
        if np.ndim(self.xyz) != 2 or np.shape(self.xyz)[1] != 3:
            raise ValueError(f"xyz must be an (n, 3) array, got shape {np.shape(self.xyz)}")
        for name, values in self.attributes.items():
            if np.shape(values) != (n,):
                raise ValueError(f"attribute {name!r} has shape {np.shape(values)}, "
                                 f"expected ({n},)")

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def model(self) -> dict:
        """The model variant and parameters that gave the sigmas (empty when unknown)."""
        return dict(self.metadata.get("model", {}))

    @property
    def sigma_source(self) -> dict:
        """Where the per-point random sigma comes from: ``kind`` ("characterised",
        "images", "assumed"), ``random`` ("law", "model", "images"), ``detail`` and
        ``warning`` (:func:`scanqa.annotation.points.sigma_source`); ``{"kind": "unknown"}`` for
        a cloud that does not say."""
        return dict(self.metadata.get("sigma_source") or {"kind": "unknown"})

    @property
    def sigma_warning(self) -> str:
        """What the user must know about where the sigmas come from ("" when they were
        characterised; :func:`scanqa.annotation.points.sigma_source`), and that the
        calibration carries no term of its own when it does not
        (:func:`scanqa.annotation.points.calibration_source`)."""
        source = self.sigma_source
        return "; ".join(t for t in (str(source.get("warning", "")),
                                     str(source.get("calibration_warning", ""))) if t)

    def summary(self) -> str:
        """One line: points written, and how many pixels were left out and why."""
        c = self.counts
        if not c:
            return f"{len(self)} points"
        parts = [f"{c.get('written', 0)} points written",
                 f"{c.get('decoder_masked', 0)} pixels masked by the decoder",
                 f"{c.get('out_of_volume', 0)} outside the calibrated volume"
                 + (" (kept, flagged)" if c.get("kept_invalid") else " (left out)"),
                 f"{c.get('model_invalid', 0)} outside the model's validity (kept, flagged)"]
        return "; ".join(parts)

    def write(self, path: str | os.PathLike) -> Path:
        """Write the cloud in the format its suffix names (``.ply``, ``.las``, ``.e57``,
        ``.csv``, ``.parquet``), metadata included; atomically."""
        return cloud_file.write_cloud(path, self.xyz, self.attributes, self.metadata)

    def with_attributes(self, **extra: np.ndarray) -> AnnotatedCloud:
        """A copy with further per-point attributes (e.g. the QA's residuals)."""
        return AnnotatedCloud(self.xyz, {**self.attributes, **extra}, dict(self.counts),
                              dict(self.metadata))

    def to_dataframe(self) -> Any:
        """A pandas DataFrame: columns ``x_mm``, ``y_mm``, ``z_mm`` and every attribute;
        ``frame.attrs["scanqa"]`` holds the metadata."""
        import pandas as pd

        frame = pd.DataFrame({"x_mm": self.xyz[:, 0], "y_mm": self.xyz[:, 1],
                              "z_mm": self.xyz[:, 2], **self.attributes})
        frame.attrs["scanqa"] = dict(self.metadata)
        return frame

    def to_open3d(self) -> Any:
        """An Open3D tensor point cloud (``open3d.t.geometry.PointCloud``).

        ``positions`` are float64 [mm] (Open3D has no units: they stay millimetres);
        every attribute is an (n, 1) float32 tensor under its own name, as Open3D's
        tensor PLY reader would load it, except the normals ``nx, ny, nz``, which are
        its ``normals`` (n, 3).
        """
        import open3d as o3d

        pcd = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(self.xyz,
                                                                             np.float64)))
        normals = ("nx", "ny", "nz")
        for name, values in self.attributes.items():
            if name in normals and set(normals) <= set(self.attributes):
                continue
            col = np.ascontiguousarray(np.asarray(values, np.float32).reshape(-1, 1))
            pcd.point[name] = o3d.core.Tensor(col)
        if set(normals) <= set(self.attributes):
            stack = np.stack([self.attributes[n] for n in normals], -1).astype(np.float32)
            pcd.point["normals"] = o3d.core.Tensor(np.ascontiguousarray(stack))
        return pcd


def read_cloud(path: str | os.PathLike) -> AnnotatedCloud:
    """Read a cloud file (``.ply``, ``.las``, ``.e57``, ``.csv``, ``.parquet``) with its metadata.

    Parameters
    ----------
    path : str or PathLike
        The file; a cloud written by scanqa carries its model and config, any other
        cloud gives empty metadata.

    Returns
    -------
    AnnotatedCloud
        Points [mm] and attributes (``scalar_`` prefixes removed).
    """
    xyz, attributes, metadata = cloud_file.read_cloud(path)
    return AnnotatedCloud(xyz, attributes, {}, metadata)


def write_cloud(path: str | os.PathLike, cloud: AnnotatedCloud) -> Path:
    """Write ``cloud`` to ``path`` (:meth:`AnnotatedCloud.write`)."""
    return cloud.write(path)
