"""Per-point uncertainty of a scan: the optics model through the calibration table.

For every decoded pixel the calibration - a nonparametric table or a parametric
camera-projector model (:class:`scanqa.calibration.base.Calibration`) - gives X, Y, Z and
the slope dQ/dx_p; the model gives s_O at that point (Eqs. 12-19) and
sigma = s_T s_O sigma_p (Eq. 18) with s_T = |dQ/dx_p| from the calibration
(docs/model.rst). With the two-source model (docs/noise_model.rst) sigma is the
quadrature sum of a scene-side part, filtered by the camera blur, and a sensor part,
which is not; both are attributes. Alongside: the decoder's own sigma (s_T sigma_xp), the
calibration's, the random and total sigma, and with repeats the measured per-point std.

Attribute names (PLY ``scalar_<name>``, LAS extra bytes, CSV columns), all float32:

====================  =====  ==================================================================
name                  unit   meaning
====================  =====  ==================================================================
sigma_model_um        um     model sigma along the line of sight; NaN where the model is not
                             valid (a blur ratio > 1/2)
sx_um, sy_um,         um     the X, Y, Z components of sigma_random along dQ/dx_p (CloudCompare
sz_um                        M3C2 precision maps pick fields containing "sx", "sy", "sz")
sigma_scene_um        um     the model sigma's scene-side part (filtered by the camera blur;
                             the whole model sigma for the paper's readings)
sigma_sensor_um       um     the model sigma's sensor part (two-source model; 0 otherwise)
sigma_phase_um        um     s_T x decoder sigma_xp (intensity noise and measured modulation)
sigma_calibration_um  um     the calibration's term (parametric covariance or the table's):
                             the calibration's own std at that point along the line of
                             sight - a parametric calibration's from its parameter
                             covariance or a stated std, a table's cell std; 0 when it
                             carries none, and the cloud's ``sigma_source.calibration``
                             then says "none". Its old name ``sigma_table_um`` (clouds
                             written before the rename) is mapped to it on reading
sigma_random_um       um     the per-point random sigma along the line of sight, from the
                             source the cloud's ``sigma_source`` names: the model where a
                             characterisation pinned it, a board's noise law applied to the
                             pixel's own A and B, else the decoder's image estimate
                             (sigma_phase_um)
sigma_total_um        um     sqrt(sigma_random^2 + sigma_calibration^2 + systematic^2),
                             systematic the config's [model] systematic_sigma_mm
att_camera            -      camera attenuation A_c
att_projector         -      projector attenuation A_p
filter_factor         -      F_gamma (Eq. 17)
s_o                   -      optical scale s_O (Eq. 19)
s_t_um_px             um/px  triangulation scale |dQ/dx_p|
modulation_dn         DN     fringe modulation B
offset_dn             DN     fringe offset A (the mean level; A / B is the inverse contrast)
in_volume             0/1    phase inside the pixel's calibrated range
model_valid           0/1    both blur ratios <= 1/2
pixel_u, pixel_v      px     camera pixel (column, row)
table_corr_mm         mm     distance over which the table's errors are correlated here
                             (NaN for a parametric calibration)
sigma_meas_um         um     with repeats: std over the repeats along the line of sight
n_repeats             -      with repeats: number of scans valid at that pixel
nx, ny, nz            -      the surface normal, estimated from the pixel grid and turned
                             towards the camera (:mod:`scanqa.model.normals`; (0, 0, 0) where
                             it cannot be); PLY ``float nx, ny, nz``, which viewers load as
                             normals. Left out with ``normals=False``
====================  =====  ==================================================================
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scanqa._version import __version__
from scanqa.annotation import kernels
from scanqa.calibration import scan_checks
from scanqa.calibration.base import Calibration
from scanqa.calibration.build import SMOOTH_HALF_WIDTH
from scanqa.calibration.lookup import TableLookup
from scanqa.calibration.parametric_checks import with_calibrated_geometry
from scanqa.calibration.table import CalibrationTable
from scanqa.characterization.checks import evidence_check
from scanqa.chunks import row_bands, run_bands
from scanqa.compiled import HAVE_NUMBA
from scanqa.decoding.imagenoise import phase_sigma_px, working_steps
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io import ply
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.model import optics
from scanqa.model.config import ScannerConfig
from scanqa.model.normals import GRID_METHOD, grid_normals, pixel_index
from scanqa.numeric import json_ready

#: Attribute names in export order (repeat fields only when repeats are given).
#: ``sigma_total_um`` first: viewers (CloudCompare) select a cloud's first scalar field.
ATTRIBUTES = ("sigma_total_um", "sx_um", "sy_um", "sz_um", "sigma_scene_um",
              "sigma_sensor_um", "sigma_phase_um", "sigma_calibration_um",
              "sigma_random_um", "sigma_model_um",
              "att_camera", "att_projector", "filter_factor", "s_o", "s_t_um_px",
              "modulation_dn", "offset_dn", "in_volume", "model_valid", "pixel_u", "pixel_v",
              "table_corr_mm")
REPEAT_ATTRIBUTES = ("sigma_meas_um", "n_repeats")
#: The normals, last (``float nx, ny, nz`` in PLY): :mod:`scanqa.model.normals`.
NORMAL_ATTRIBUTES = ply.NORMALS

log = logging.getLogger(__name__)


def check_compatible(table: Calibration, config: ScannerConfig, phase_map: PhaseMap,
                     source: str = "scan") -> None:
    """Raise unless calibration, config and scan describe the same scanner and camera
    (each calibration knows what to check: :meth:`Calibration.check_scan`)."""
    table.check_scan(config, phase_map, source)


def annotate(phase_map: PhaseMap, table: Calibration, config: ScannerConfig,
             repeats: Sequence[PhaseMap] = (), keep_invalid: bool = False,
             source: str = "scan", out: str | os.PathLike | None = None,
             normals: bool = True) -> AnnotatedCloud:
    """Annotate a decoded scan with per-point sigmas.

    Parameters
    ----------
    phase_map : PhaseMap
        The decoded scan.
    table : Calibration
        The scanner's calibration: a nonparametric table
        (:class:`~scanqa.calibration.table.CalibrationTable`) or a parametric one
        (:class:`~scanqa.calibration.parametric.ParametricCalibration`).
    config : ScannerConfig
        The config the table was built with, or that describes the parametrically
        calibrated scanner (its ``[model]`` gives sigma_p, gamma and
        the readings; they may differ from the table's). A parametric calibration
        supplies the projector's pose itself (:func:`~scanqa.calibration.parametric_checks.
        with_calibrated_geometry`; a large change is a warning); the config the rest.
    repeats : sequence of PhaseMap
        Further scans of the same static scene for the measured per-point std.
    keep_invalid : bool
        Keep points outside the calibrated volume (extrapolated, flagged).
    source : str
        Name of the scan for messages.
    out : str or PathLike, optional
        A binary PLY (``.ply``) to write the cloud to while it is computed: the records
        are filled inside the output file's mapping (:func:`scanqa.io.ply.vertex_file`),
        the same bytes as :meth:`AnnotatedCloud.write` without a second copy of the
        cloud; published atomically.
    normals : bool
        Estimate each point's surface normal from its neighbouring pixels
        (:func:`scanqa.model.normals.grid_normals`; attributes ``nx, ny, nz``, and the
        metadata's ``normals`` says how).

    Returns
    -------
    AnnotatedCloud
        Points in row-major pixel order. ``xyz`` and the attributes are views of one
        record array in the binary PLY layout (:func:`scanqa.io.ply.vertex_views`);
        read-only views of the written file with ``out``.

    Raises
    ------
    InputError
        No valid phase at all; with ``out``, a suffix other than ``.ply``, or no point
        to write (nothing is written then).

    Notes
    -----
    Two passes over bands of image rows on every core: the first finds the points to keep
    (decoded, and inside the calibrated volume unless ``keep_invalid``), the second looks
    them up in the table, evaluates the model and writes every attribute straight into
    the cloud; no full-size intermediate array is made.
    """
    config = with_calibrated_geometry(table, config)  # a parametric one's pose wins
    check_compatible(table, config, phase_map, source)
    warnings = [scan_checks.sensitivity_warning(table, config, source),  # may refuse
                scan_checks.units_warning(table, config, source)]
    if out is not None and Path(out).suffix.lower() != ".ply":
        raise InputError(f"annotate writes a binary PLY while it computes (out={out}): give "
                         "a .ply name, or write other formats with AnnotatedCloud.write")
    xp = np.asarray(phase_map.xp, dtype=float)
    bands = row_bands(*xp.shape)
    keep, kept, counts = _select(table, xp, bands, keep_invalid)
    if counts["decoder_masked"] == xp.size:
        raise InputError(f"{source} has no valid phase at all (every pixel is NaN): check the "
                         "decoding mask or the pattern images")
    if out is not None and not counts["written"]:
        raise InputError(f"{source}: no point lies inside the calibrated volume; nothing "
                         f"written to {out} (keep_invalid extrapolates)")
    warnings.append(scan_checks.volume_warning(counts, xp.size, source, table))
    names = (ATTRIBUTES + (REPEAT_ATTRIBUTES if repeats else ())
             + (NORMAL_ATTRIBUTES if normals else ()))
    extra = {"sigma_xp": phase_map.sigma_xp, "modulation": phase_map.modulation,
             "offset": phase_map.offset}
    origin = sigma_source(config, phase_map)
    meta = cloud_metadata(config, table, source)
    meta["sigma_source"] = {k: v for k, v in origin.items() if k != "law"}
    meta["sigma_source"].update(calibration_source(table))
    if normals:
        meta["normals"] = GRID_METHOD
    if repeats:
        extra["std"], extra["count"] = measured_std(table, [phase_map, *repeats])
    starts = np.cumsum([0, *kept])
    index = {band: i for i, band in enumerate(bands)}
    grey = None
    compiled = _compiled(table, config, origin)

    def fill(records: np.ndarray) -> None:
        records = records.view(np.ndarray)  # a memmap's slices run Python hooks per view

        def band(r0: int, r1: int) -> int:
            i = index[(r0, r1)]
            return _annotate_band(table, config, xp, extra, keep[i], (r0, r1),
                                  keep_invalid, records[starts[i]:starts[i + 1]], origin,
                                  grey, compiled)

        counts["model_invalid"] = int(sum(run_bands(band, bands)))
        if normals:  # a second pass: a band's normals need the rows beside it
            pixels = pixel_index(np.concatenate(keep))
            xyz = ply.vertex_views(records)[0]
            focal = config.camera.principal_distance_px

            def normal_band(r0: int, r1: int) -> None:
                i = index[(r0, r1)]
                part = records[starts[i]:starts[i + 1]]
                found = grid_normals(xyz, pixels, focal, (r0, r1))
                part["nx"], part["ny"], part["nz"] = found.T

            run_bands(normal_band, bands)

    if out is None:
        records = np.empty(counts["written"], dtype=ply.vertex_dtype(names))
        fill(records)
    else:  # each band fills its display fields too, while its records are in cache
        grey = ply.display_scale(np.asarray(phase_map.offset)[np.concatenate(keep)])
        with ply.vertex_file(out, names, counts["written"], meta, display=False) as records:
            fill(records)
    counts["kept_invalid"] = keep_invalid
    xyz, attributes = ply.vertex_views(records)
    warnings.append(scan_checks.depth_warning(xyz[:, 2], config, source))
    for text in filter(None, warnings):  # the geometry checks (scan_checks)
        log.warning(text)
    evidence = evidence_check(origin, attributes)
    meta["sigma_source"].update(evidence)
    cloud = AnnotatedCloud(xyz, attributes, counts, meta)
    if out is not None and evidence:  # its header was written before the check: again
        cloud.write(out)
    return cloud


def cloud_metadata(config: ScannerConfig, table: Calibration, source: str) -> dict:
    """What a cloud carries into its file: the model variant and parameters that gave its
    sigmas, the whole scanner config, the table's build and the software version."""
    model = config.model
    return {"format": "scanqa-cloud/1", "software": {"name": "scanqa", "version": __version__},
            "source": source,
            "model": {"filter_floor": model.filter_floor, "noise_reading": model.noise_reading,
                      "filter_form": model.filter_form, "sigma_p_px": model.sigma_p_px,
                      "sensor_sigma_p_px": model.sensor_sigma_p_px, "gamma": model.gamma,
                      "wavelength_nm": model.wavelength_nm,
                      "working_period_px": config.fringes.working_period_px},
            "config": config.to_dict(),
            "config_source": config.source + (f"#{config.profile}" if config.profile else ""),
            "table": {"kind": table.provenance.get("kind", "table"), "weights": table.weights,
                      "z_range_mm": [json_ready(float(z)) for z in table.z_range_mm],
                      "cell_px": json_ready(float(table.cell_px)),
                      "n_planes": len(table.provenance.get("positions", [])) or None,
                      "sweep": table.provenance.get("sweep", ""),
                      "calibration": table.provenance.get("calibration", "")}}


def calibration_source(table: Calibration) -> dict:
    """Where a cloud's calibration term (``sigma_calibration_um``) comes from, for its
    ``sigma_source``: ``calibration`` ("table": a table's cell std; "covariance",
    "stated" or "none" for a parametric calibration,
    :attr:`~scanqa.calibration.parametric.ParametricCalibration.calibration_term`),
    ``calibration_detail`` and, with no term, ``calibration_warning``."""
    term = getattr(table, "calibration_term", None)
    if term is None:
        return {"calibration": "table", "calibration_detail": "the calibration table's own "
                "cell std (sigma_calibration_um)", "calibration_warning": ""}
    return {"calibration": term["kind"], "calibration_detail": term["detail"],
            "calibration_warning": term["detail"] if term["kind"] == "none" else ""}


def sigma_source(config: ScannerConfig, phase_map: PhaseMap) -> dict:
    """Where a scan's per-point random sigma comes from, and what it assumes.

    Returns
    -------
    dict
        ``kind``: "characterised" (a characterisation pinned the noise: a board's noise
        law, or the model's sigma_p), "images" (the decoder's estimate from the scan's
        own images: the config's sigma_p is assumed) or "assumed" (neither: the decoder
        fell back to a default camera model); ``random``: "law", "model" or "images";
        ``detail``: the characterisation or the images' noise source, in words;
        ``warning``: what the user must know, or ""; ``law``: (a, b, period, steps) for
        the "law" source.
    """
    model = config.model
    if model.has_noise_law:
        law = (model.noise_read_var_dn2, model.noise_shot_dn, phase_map.period_px,
               working_steps(phase_map))
        return {"kind": "characterised", "random": "law", "detail": model.characterised_by
                or "a board noise law of unstated origin", "warning": "", "law": law}
    if model.characterised_by:
        return {"kind": "characterised", "random": "model",
                "detail": model.characterised_by, "warning": ""}
    noise = phase_map.provenance.get("decode", {}).get("noise", {}).get("source", "")
    where = f"{config.source}#{config.profile}" if config.profile else config.source
    assumed = (f"sigma_p_px = {model.sigma_p_px:g} px in {where or 'the config'} is assumed "
               "(its [model] has no characterised_by)")
    if noise.startswith("default model"):
        return {"kind": "assumed", "random": "images", "detail": noise,
                "warning": f"{assumed}, and the decoder found no noise in the images "
                           "(default camera model): every sigma is assumed; characterise "
                           "the scanner (scanqa characterize board) or give [sensor] gain"}
    return {"kind": "images", "random": "images",
            "detail": noise or "the phase map's sigma_xp (its noise source not recorded)",
            "warning": f"{assumed}: sigma_random/sigma_total come from the scan's own "
                       "images instead; sigma_model_um is only the assumed model "
                       "(characterise the scanner: scanqa characterize board)"}


def _random_sigma(inputs: dict, sigma_model: np.ndarray, s_t: np.ndarray) -> np.ndarray:
    """The per-point random sigma along the line of sight from the scan's sigma source
    [mm] (:func:`sigma_source`)."""
    source = inputs["source"]
    if source["random"] == "model":
        return sigma_model
    if source["random"] == "law":
        a, b, period, steps = source["law"]
        return s_t * phase_sigma_px(inputs["modulation"], inputs["offset"], a, b, period,
                                    steps)
    return s_t * inputs["sigma_xp"]


def _annotate_band(table: Calibration, config: ScannerConfig, xp: np.ndarray,
                   extra: dict, keep: np.ndarray, rows: tuple[int, int], keep_invalid: bool,
                   out: np.ndarray, source: dict, grey: float | None = None,
                   compiled: tuple | None = None) -> int:
    """Look up, model and write the kept points of image rows ``rows`` into the records
    ``out`` (and their display fields with the grey scale ``grey`` [1/DN], if given);
    returns the number outside the model's validity. With ``compiled``
    (:func:`_compiled`), in one compiled pass (:func:`kernels.annotate_band`)."""
    r0, r1 = rows
    select = None if out.size == keep.size else np.flatnonzero(keep)
    if compiled is not None:
        return _compiled_band(compiled, xp, extra, select, rows, keep_invalid, out, source,
                              grey)
    look = table.apply_rows(xp[r0:r1], r0, select, extrapolate=keep_invalid)
    pixels = _pixels(select, r0, r1, xp.shape[1])
    inputs = {k: _pick(v[r0:r1], select) for k, v in extra.items()}
    inputs["corr_px"] = table_correlation_px(table)
    inputs["source"] = source
    term = getattr(table, "calibration_term", {"kind": "table"})
    if term["kind"] in ("covariance", "stated"):  # a parametric calibration's own
        inputs["sigma_calibration"] = table.calibration_sigma_mm(*pixels, _pick(
            xp[r0:r1], select))
    invalid = _annotate_points(look, pixels, inputs, config, out)
    if grey is not None:
        ply.fill_display(out, grey)
    return invalid


def _compiled(table: Calibration, config: ScannerConfig, source: dict) -> tuple | None:
    """The constants of the compiled pass (:mod:`scanqa.annotation.kernels`) for a
    nonparametric table, made once per scan; None for other calibrations or without numba
    (:mod:`scanqa.compiled`): the numpy path."""
    if not HAVE_NUMBA or not isinstance(table, CalibrationTable):
        return None
    model, run = kernels.model_parameters(config, source["random"],
                                               table_correlation_px(table))
    grid, packed = kernels.table_arrays(table)
    g = table.image_grid
    return grid, packed, model, run, g.shear_u, g.shear_c


def _compiled_band(compiled: tuple, xp: np.ndarray, extra: dict, select: np.ndarray | None,
                   rows: tuple[int, int], keep_invalid: bool, out: np.ndarray,
                   source: dict, grey: float | None) -> int:
    """One band through :func:`kernels.annotate_band`: its per-point inputs picked,
    the random source's phase sigma [px], a band of plain records filled (the display
    fields too with the grey scale ``grey`` [1/DN], if given) and copied into ``out``."""
    grid, packed, model, run, shear_u, shear_c = compiled
    r0, r1 = rows
    inputs = {k: np.asarray(_pick(v[r0:r1], select), dtype=float) for k, v in extra.items()}
    empty = np.empty(0)
    if source["random"] == "law":
        a, b, period, steps = source["law"]
        phase = phase_sigma_px(inputs["modulation"], inputs["offset"], a, b, period, steps)
    else:
        phase = inputs["sigma_xp"] if source["random"] == "images" else empty
    per_point = tuple(np.ascontiguousarray(a, dtype=float) for a in (
        inputs["modulation"], inputs["offset"], inputs["sigma_xp"], phase,
        inputs.get("std", empty), inputs.get("count", empty)))
    band = (*grid, kernels.shear_rows(shear_u, shear_c, range(r0, r1), grid[4].size),
            shear_u)
    chosen = np.empty(0, dtype=np.intp) if select is None else select
    phases = np.ascontiguousarray(xp[r0:r1]).view()
    phases.flags.writeable = False  # one compiled signature for every phase map
    # the loop fills plain records, then one copy into ``out`` (a mapping at any offset)
    records, points = np.empty(out.size, dtype=out.dtype), np.empty((out.size, 3))
    words = records.view(np.uint32).reshape(out.size, out.itemsize // 4)
    invalid = kernels.annotate_band(phases, chosen, r0, band, packed, bool(keep_invalid),
                                         per_point, model, run, points, words,
                                         words.view(np.float32),
                                         -1.0 if grey is None else float(grey))
    np.ndarray((out.size, 3), dtype="<f8", buffer=records,
               strides=(out.itemsize, 8))[...] = points
    out.view(np.uint8)[...] = records.view(np.uint8)  # bytes: a record copy is per field
    return invalid


def table_correlation_px(table: Calibration) -> float:
    """Distance over which the table's errors are correlated [camera px]: the window of
    the cell smoothing, (2 h + 1) cells (:func:`scanqa.calibration.build.smooth_cells`);
    NaN for a parametric calibration, which has no cells and no errors of its own."""
    return (2 * SMOOTH_HALF_WIDTH + 1) * table.cell_px


def _select(table: Calibration, xp: np.ndarray, bands: list, keep_invalid: bool
            ) -> tuple[list[np.ndarray], list[int], dict]:
    """Pixels to keep per band ((rows, W) bool each), how many, and the counts by fate."""
    def band(r0: int, r1: int) -> tuple[np.ndarray, int, int, int]:
        decoded = np.isfinite(xp[r0:r1])
        inside = table.in_volume_rows(xp[r0:r1], r0)  # False where not decoded
        keep = decoded if keep_invalid else inside
        return keep, int(keep.sum()), int(decoded.sum()), int(inside.sum())

    table.image_grid  # noqa: B018 - computed once, before the threads share it
    keep, kept, decoded, inside = zip(*run_bands(band, bands), strict=True)
    counts = {"written": sum(kept), "decoder_masked": xp.size - sum(decoded),
              "out_of_volume": sum(decoded) - sum(inside)}
    return list(keep), list(kept), counts


def _pick(values: np.ndarray, select: np.ndarray | None) -> np.ndarray:
    """Per-pixel values of a band's kept pixels (all, or the flat indices ``select``)."""
    return values.ravel() if select is None else np.take(values, select)


def _pixels(select: np.ndarray | None, r0: int, r1: int, width: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel column and row of a band's kept pixels [camera px]."""
    if select is None:  # no integer division per pixel
        return np.tile(np.arange(width), r1 - r0), np.repeat(np.arange(r0, r1), width)
    rows, cols = np.divmod(select, width)
    return cols, rows + r0


def _annotate_points(look: TableLookup, pixels: tuple, inputs: dict, config: ScannerConfig,
                     out: np.ndarray) -> int:
    """Model and attributes of one band's points, written into ``out``, records in the
    layout of :func:`scanqa.io.ply.vertex_dtype`; returns the number of points outside
    the model's validity.

    Every attribute is computed in float64 as ever and rounded once into its float32
    row of one block (``out=``: no float64 copy per attribute), which is then written
    record by record in one pass.
    """
    points = look.xyz.reshape(-1, 3)
    slope = look.slope.reshape(-1, 3)
    s_t = np.sqrt(slope[:, 0] ** 2 + slope[:, 1] ** 2 + slope[:, 2] ** 2)  # |dQ/dx_p|
    pred = optics.predict(points, config, s_t=s_t)
    invalid = ~pred.valid
    n_invalid = int(invalid.sum())
    sigma = np.where(invalid, np.nan, pred.sigma) if n_invalid else pred.sigma
    sig_tab = inputs.get("sigma_calibration", look.sigma_table.ravel())
    random = _random_sigma(inputs, sigma, s_t)
    ply.vertex_views(out)[0][...] = points
    names = [n for n in ply.attribute_names(out.dtype) if n not in ply.NORMALS]
    block = np.empty((len(names), out.size), dtype=np.float32)
    row = dict(zip(names, block, strict=True))
    um = 1e3 * s_t
    random_um = 1e3 * random
    for name, values in (("sigma_model_um", pred.sigma), ("sigma_scene_um", pred.sigma_scene),
                         ("sigma_sensor_um", pred.sigma_sensor),
                         ("sigma_calibration_um", sig_tab)):
        np.multiply(values, 1e3, out=row[name], casting="same_kind")
    if n_invalid:  # NaN where the model is not valid
        for name in ("sigma_model_um", "sigma_scene_um", "sigma_sensor_um"):
            row[name][invalid] = np.nan
    np.multiply(um, inputs["sigma_xp"], out=row["sigma_phase_um"], casting="same_kind")
    row["sigma_random_um"][...] = random_um
    total = random**2
    total += sig_tab**2
    total += config.model.systematic_sigma_mm**2
    np.sqrt(total, out=total)
    np.multiply(total, 1e3, out=row["sigma_total_um"], casting="same_kind")
    for i, name in enumerate(("sx_um", "sy_um", "sz_um")):
        part = np.abs(slope[:, i] / s_t)
        np.multiply(random_um, part, out=row[name], casting="same_kind")
    corr = inputs["corr_px"] * points[:, 2]
    np.divide(corr, config.camera.principal_distance_px, out=row["table_corr_mm"],
              casting="same_kind")
    for name, values in (("att_camera", pred.attenuation_camera),
                         ("att_projector", pred.attenuation_projector),
                         ("filter_factor", pred.filter_factor), ("s_o", pred.s_o),
                         ("s_t_um_px", um), ("modulation_dn", inputs["modulation"]),
                         ("offset_dn", inputs["offset"]), ("in_volume", look.in_volume.ravel()),
                         ("model_valid", pred.valid), ("pixel_u", pixels[0]),
                         ("pixel_v", pixels[1])):
        row[name][...] = values
    if "std" in inputs:
        np.multiply(inputs["std"], 1e3, out=row["sigma_meas_um"], casting="same_kind")
        row["n_repeats"][...] = inputs["count"]
    ply.attribute_block(out)[...] = block.T
    return n_invalid


def measured_std(table: Calibration, scans: Sequence[PhaseMap]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel std over repeated scans, along the line of sight.

    Parameters
    ----------
    table : Calibration
        Calibration table or parametric calibration.
    scans : sequence of PhaseMap
        Two or more scans of one static scene.

    Returns
    -------
    std : (H, W) float
        Sample std (ddof = 1) of the range along the camera ray [mm]; NaN where fewer
        than two scans are valid.
    count : (H, W) int
        Number of valid scans per pixel.

    Notes
    -----
    Bands of rows on every core; each band goes through all scans before the next.
    """
    shape = (table.height_px, table.width_px)
    for k, scan in enumerate(scans):
        if scan.xp.shape != shape:
            raise InputError(f"repeat {k} is {scan.xp.shape[1]} x {scan.xp.shape[0]} px, the "
                             f"table's camera {shape[1]} x {shape[0]} px")
    check_one_scene(scans)
    std = np.empty(shape)
    count = np.empty(shape, dtype=int)

    def band(r0: int, r1: int) -> None:
        std[r0:r1], count[r0:r1] = _band_std(table, [s.xp[r0:r1] for s in scans], r0)

    table.image_grid  # noqa: B018 - computed once, before the threads share it
    run_bands(band, row_bands(*shape))
    return std, count


#: Median |x_p difference| of a repeat from the first scan, in units of their combined
#: predicted sigma, above which the "repeat" shows another scene [-] (repeats of one
#: static scene differ by noise: about 0.7 of the combined sigma as the median).
REPEAT_LIMIT_SIGMA = 20.0


def check_one_scene(scans: Sequence[PhaseMap]) -> None:
    """Refuse repeats that show another scene than the first scan: a std over different
    scenes is no measured noise.

    Raises
    ------
    InputError
        Naming the repeat, its median difference and the fix.
    """
    first = scans[0]
    for k, scan in enumerate(scans[1:], start=1):
        both = first.valid & scan.valid
        if both.sum() < 10:
            continue
        diff = np.abs(scan.xp[both] - first.xp[both])
        sigma = np.hypot(first.sigma_xp[both], scan.sigma_xp[both])
        ratio = float(np.nanmedian(diff / sigma))
        if ratio > REPEAT_LIMIT_SIGMA:
            raise InputError(f"repeat {k} differs from the scan by a median "
                             f"{float(np.median(diff)):.3g} projector px, {ratio:.0f} times "
                             "their predicted sigma: it shows another scene (or the scene "
                             "moved); give repeats of one static scene")


def _band_std(table: Calibration, rows: list[np.ndarray], r0: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Std of the range over scans [mm] and the valid count, for one band of rows."""
    shape = rows[0].shape
    total = np.zeros(shape)
    total_sq = np.zeros(shape)
    count = np.zeros(shape, dtype=int)
    ref = np.zeros(shape)
    for xp in rows:
        rng = np.linalg.norm(table.apply_rows(xp, r0).xyz, axis=-1)
        ok = np.isfinite(rng)
        # centre on the first valid value per pixel to keep the sums well conditioned
        ref = np.where(ok & (count == 0), rng, ref)
        d = np.where(ok, rng - ref, 0.0)
        total += d
        total_sq += d * d
        count += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (total_sq - total**2 / count) / (count - 1)
    return np.where(count >= 2, np.sqrt(np.maximum(var, 0.0)), np.nan), count
