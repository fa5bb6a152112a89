"""The calibration table: a nonparametric map from (u, v, x_p) to X, Y, Z, and its file.

The table is a regular grid over raw sensor coordinates (u, v) and the phase relative
to a smooth shear, s = x_p - x_shear(u, v) [projector px] (:mod:`scanqa.calibration.shear`);
its nodes hold X, Y, Z [mm], the slope dQ/dx_p and the table's own std. It is built by
:func:`scanqa.calibration.build.build_table` and applied by :mod:`scanqa.calibration.lookup`
(bilinear in (u, v), cubic Hermite in s; phases outside a node's calibrated range are
flagged, never silently extrapolated). :mod:`scanqa.io.table` is its file format.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanqa.calibration import lookup
from scanqa.calibration.lookup import TableLookup
from scanqa.calibration.shear import N_TERMS as SHEAR_TERMS
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import ConfigError, InputError
from scanqa.io import table as table_file
from scanqa.model.config import ScannerConfig, config_from_dict


@dataclass(frozen=True)
class CalibrationTable:
    """A built table. Arrays: nodes (n_v, n_u), s-grid (n_s,), values (n_v, n_u, n_s, 3)."""

    node_u: np.ndarray
    node_v: np.ndarray
    x_ref: np.ndarray
    s_nodes: np.ndarray
    xyz: np.ndarray
    dxyz: np.ndarray
    sigma_node: np.ndarray
    s_lo: np.ndarray
    s_hi: np.ndarray
    shear: np.ndarray
    width_px: int
    height_px: int
    weights: str
    config: dict
    provenance: dict

    @functools.cached_property
    def packed(self) -> lookup.Packed:
        """The table rearranged for fast lookups, computed once
        (:mod:`scanqa.calibration.lookup`)."""
        return lookup.pack(self)

    @functools.cached_property
    def image_grid(self) -> lookup.ImageGrid:
        """Per-row and per-column constants of whole-image lookups (computed once)."""
        return lookup.image_grid(self)

    @property
    def cell_px(self) -> float:
        """Node spacing in u and v [camera px]."""
        return float(self.node_u[1] - self.node_u[0]) if self.node_u.size > 1 else 1.0

    @property
    def z_range_mm(self) -> tuple[float, float]:
        """Calibrated stage range [mm]."""
        zs = [p["z_mm"] for p in self.provenance.get("positions", [])]
        return (min(zs), max(zs)) if zs else (float("nan"), float("nan"))

    @property
    def reference_node(self) -> int:
        """Index of the phase node nearest the shear (s = 0), where the maps are shown."""
        return int(np.argmin(np.abs(self.s_nodes)))

    def node_summary(self) -> dict:
        """Coverage and the table's own std over its nodes.

        Returns
        -------
        dict
            ``covered_node_fraction`` [-] (nodes with a calibrated phase range) and the
            median and 95th percentile of the std at :attr:`reference_node`,
            ``table_sigma_um_median`` and ``table_sigma_um_p95`` [um] (None when no node
            has one).
        """
        sig = self.sigma_node[..., self.reference_node] * 1e3
        known = bool(np.isfinite(sig).any())
        return {"covered_node_fraction": float(np.isfinite(self.s_lo).mean()),
                "table_sigma_um_median": float(np.nanmedian(sig)) if known else None,
                "table_sigma_um_p95": float(np.nanpercentile(sig, 95)) if known else None}

    def scanner_config(self) -> ScannerConfig:
        """The config the table was built with."""
        return config_from_dict(self.config, source="calibration table")

    def save(self, path: str | os.PathLike) -> Path:
        """Write the table to one ``.npz`` file (no pickle), atomically."""
        return save_table(path, self)

    def apply(self, u: np.ndarray, v: np.ndarray, xp: np.ndarray,
              extrapolate: bool = False) -> TableLookup:
        """Map pixel coordinates and phase to metric points.

        Parameters
        ----------
        u, v : array_like
            Pixel coordinates (column, row) [camera px].
        xp : array_like
            Unwrapped projector coordinate [projector px].
        extrapolate : bool
            Return points for phases outside a pixel's calibrated range (still flagged);
            by default they are NaN.

        Returns
        -------
        TableLookup
            X, Y, Z [mm], slope dQ/dx_p, the table's sigma and the in-volume flag.
        """
        u, v, xp = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float),
                                       np.asarray(xp, float))
        return lookup.apply_points(self, u, v, xp, extrapolate)

    def apply_image(self, xp: np.ndarray, extrapolate: bool = False) -> TableLookup:
        """Apply the table to a whole (H, W) phase map of the calibrated camera.

        Parameters
        ----------
        xp : (H, W) array_like
            Unwrapped projector coordinate, NaN where not decoded [projector px].
        extrapolate : bool
            As in :meth:`apply`.

        Returns
        -------
        TableLookup
            Arrays shaped (H, W, 3) and (H, W).
        """
        xp = np.asarray(xp, dtype=float)
        self._check_rows(xp, 0, whole=True)
        return lookup.apply_image(self, xp, extrapolate)

    def apply_rows(self, xp_rows: np.ndarray, row0: int = 0, select: np.ndarray | None = None,
                   extrapolate: bool = False) -> TableLookup:
        """Apply the table to a band of rows of a phase map (for chunked pipelines).

        Parameters
        ----------
        xp_rows : (n, W) float ndarray
            Rows row0 .. row0 + n - 1 of a phase map [projector px].
        row0 : int
            Image row of the first [camera px].
        select : (k,) int ndarray, optional
            Flat indices into ``xp_rows`` of the pixels to look up; default all.
        extrapolate : bool
            As in :meth:`apply`.

        Returns
        -------
        TableLookup
            Arrays shaped (n, W, ...) or, with ``select``, (k, ...).
        """
        xp_rows = np.asarray(xp_rows, dtype=float)
        self._check_rows(xp_rows, row0)
        return lookup.apply_rows(self, xp_rows, row0, select, extrapolate)

    def in_volume_rows(self, xp_rows: np.ndarray, row0: int = 0) -> np.ndarray:
        """Whether each phase of a band of rows (as in :meth:`apply_rows`) lies inside its
        pixel's calibrated range: (n, W) bool, False for NaN."""
        xp_rows = np.asarray(xp_rows, dtype=float)
        self._check_rows(xp_rows, row0)
        return lookup.in_volume_rows(self, xp_rows, row0)

    def check_scan(self, config: ScannerConfig, phase_map: PhaseMap,
                   source: str = "scan") -> None:
        """Raise unless the scan has the table's image size and the config matches the
        camera and projector settings the table was built with."""
        h, w = phase_map.xp.shape
        if (w, h) != (self.width_px, self.height_px):
            raise InputError(f"{source} is {w} x {h} px but the calibration table was built "
                             f"for a {self.width_px} x {self.height_px} px camera: use the "
                             "table of this scanner")
        for section in ("camera", "projector"):
            mine = config.to_dict()[section]
            for key, value in self.config.get(section, {}).items():
                if not np.allclose(np.asarray(mine.get(key), float), np.asarray(value, float)):
                    raise InputError(f"config {config.source} does not match the table's: "
                                     f"{section}.{key} is {mine.get(key)!r} here and {value!r} "
                                     "in the table; pass the config the table was built with")

    def _check_rows(self, xp: np.ndarray, row0: int, whole: bool = False) -> None:
        """Raise unless ``xp`` is rows row0.. (``whole``: all rows) of a phase map of the
        calibrated camera (:func:`scanqa.calibration.lookup.check_rows`)."""
        lookup.check_rows(xp, row0, self.width_px, self.height_px, whole, "the table's camera",
                          "the table was built for")


def save_table(path: str | os.PathLike, table: CalibrationTable) -> Path:
    """Write a table as one npz file (no pickle), atomically (:mod:`scanqa.io.table`)."""
    meta = {"width_px": table.width_px, "height_px": table.height_px,
            "weights": table.weights, "config": table.config, "provenance": table.provenance}
    return table_file.write_table_file(path, {k: getattr(table, k) for k in table_file.ARRAYS},
                                       meta)


def load_table(path: str | os.PathLike) -> CalibrationTable:
    """Read a table written by :func:`save_table`, checking its format version."""
    arrays, meta = table_file.read_table_file(path)
    try:  # the metadata's config is checked as any config: field by field
        config_from_dict(meta["config"], source=f"{path}, table metadata config")
    except ConfigError as err:
        raise InputError(f"{err}; the table is damaged: rebuild it") from None
    if arrays["shear"].shape != (SHEAR_TERMS,):
        raise InputError(f"{path}: table array shear has shape {arrays['shear'].shape}, "
                         f"expected ({SHEAR_TERMS},) (damaged); rebuild it")
    return CalibrationTable(**arrays, width_px=int(meta["width_px"]),
                            height_px=int(meta["height_px"]), weights=meta["weights"],
                            config=meta["config"], provenance=meta["provenance"])
