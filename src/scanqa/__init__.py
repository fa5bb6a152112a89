"""scanqa: calibration-aware uncertainty toolkit for phase-shift (fringe projection) scanners.

Lengths are millimetres, phase is the unwrapped projector coordinate x_p in projector
pixels, and standard deviations in reports are micrometres.

The three jobs, from Python
---------------------------
1. Weighted calibration run - a flat target at known stage positions to a table::

       config = scanqa.load_config("sample_data/sample_scanner.toml", profile="sample")
       table, build = scanqa.calibrate("sample_data/calibration_sweep/sweep.toml", config)
       table.save("table.npz")

2. Annotated point cloud - a scan and a calibration (the table, or an OpenCV camera-projector
   calibration: ``scanqa.load_calibration("calibration.xml", config)``) to points with
   predicted sigmas::

       scan = scanqa.decode("sample_data/gauge_blocks/p000_r0")   # or a phase.npz
       cloud = scanqa.annotate(scan, table, config)
       cloud.write("cloud.ply")          # .ply .las .e57 .csv .parquet; the model goes along
       cloud.to_open3d(), cloud.to_dataframe()

3. QA report - gauge blocks: plane fits, measured vs predicted std, steps with U::

       qa = scanqa.run_qa(scanqa.read_cloud("cloud.ply"), scanqa.load_layout("layout.toml"))
       scanqa.write_report(qa, "qa/")   # report.html, blocks.csv, steps.csv, summary.json

A real scanner, from its frames to a comparison (:mod:`scanqa.api`; the commands'
arguments)::

       scanqa.describe("capture/")                       # -> capture/patterns.toml
       result = scanqa.calibrate_board(poses, ("columns.toml", "rows.toml"), square_mm=10,
                                       out="calibration.xml")
       law = scanqa.characterize_board(poses, "calibration.xml", "scanner.toml",
                                       out="board_noise")
       config = scanqa.apply_characterization("scanner.toml", "board_noise/summary.json")
       cloud = scanqa.annotate(scanqa.decode("part/"),
                               scanqa.load_calibration("calibration.xml", config), config)
       cmp = scanqa.compare(cloud, "part.stl", align=True, out="cmp")

Characterise a scanner (fit sigma_p, gamma and the model's reading to a sweep) with
:func:`characterize` and apply the result with ``result.apply_to(config)``; predict the
std of any point with :func:`predict`. Every error a user can cause is a
:class:`ScanQAError`. Progress and notes go to the ``scanqa`` logger (shown after
``logging.basicConfig(level=logging.INFO)``; :mod:`scanqa.progress`).
"""

from __future__ import annotations

from scanqa._version import __version__

#: Public name -> (module, attribute): imported on first use (PEP 562), so that
#: ``import scanqa.cli`` stays light and Ctrl-C during the command line's start-up is
#: caught by :func:`scanqa.cli.main` instead of printing a traceback.
_EXPORTS = {
    "annotate": ("scanqa.annotation.points", "annotate"),
    "Calibration": ("scanqa.calibration.base", "Calibration"),
    "load_calibration": ("scanqa.calibration.base", "load_calibration"),
    "BuildReport": ("scanqa.calibration.build", "BuildReport"),
    "build_table": ("scanqa.calibration.build", "build_table"),
    "ParametricCalibration": ("scanqa.calibration.parametric", "ParametricCalibration"),
    "load_opencv_calibration": ("scanqa.calibration.parametric", "load_opencv_calibration"),
    "calibrate": ("scanqa.calibration.sweep", "calibrate"),
    "load_sweep": ("scanqa.calibration.sweep", "load_sweep"),
    "CalibrationTable": ("scanqa.calibration.table", "CalibrationTable"),
    "load_table": ("scanqa.calibration.table", "load_table"),
    "save_table": ("scanqa.calibration.table", "save_table"),
    "characterize": ("scanqa.characterization.sweep", "characterize_sweeps"),
    "AnnotatedCloud": ("scanqa.io.annotated_cloud", "AnnotatedCloud"),
    "read_cloud": ("scanqa.io.annotated_cloud", "read_cloud"),
    "write_cloud": ("scanqa.io.annotated_cloud", "write_cloud"),
    "ScannerConfig": ("scanqa.model.config", "ScannerConfig"),
    "load_config": ("scanqa.model.config", "load_config"),
    "PatternDescription": ("scanqa.decoding.coding", "PatternDescription"),
    "decode": ("scanqa.decoding.decoder", "decode"),
    "decode_images": ("scanqa.decoding.decoder", "decode_images"),
    "load_patterns": ("scanqa.decoding.parsing", "load_patterns"),
    "PhaseMap": ("scanqa.decoding.phasemap", "PhaseMap"),
    "load_phase_map": ("scanqa.decoding.phasemap", "load_phase_map"),
    "save_phase_map": ("scanqa.decoding.phasemap", "save_phase_map"),
    "ConfigError": ("scanqa.errors", "ConfigError"),
    "InputError": ("scanqa.errors", "InputError"),
    "OutputError": ("scanqa.errors", "OutputError"),
    "RangeError": ("scanqa.errors", "RangeError"),
    "ScanQAError": ("scanqa.errors", "ScanQAError"),
    "predict": ("scanqa.model.optics", "predict"),
    "QAResult": ("scanqa.qa.blocks", "QAResult"),
    "run_qa": ("scanqa.qa.blocks", "run_qa"),
    "detect_blocks": ("scanqa.qa.detect", "detect_blocks"),
    "Layout": ("scanqa.qa.layout", "Layout"),
    "load_layout": ("scanqa.qa.layout", "load_layout"),
    "write_report": ("scanqa.report.qa", "write_outputs"),
    "describe": ("scanqa.api", "describe"),
    "calibrate_board": ("scanqa.api", "calibrate_board"),
    "characterize_board": ("scanqa.api", "characterize_board"),
    "apply_characterization": ("scanqa.api", "apply_characterization"),
    "compare": ("scanqa.api", "compare"),
    "sample_data_path": ("scanqa.runs.demo", "sample_data_path"),
}


__all__ = [
    "AnnotatedCloud",
    "BuildReport",
    "Calibration",
    "CalibrationTable",
    "ConfigError",
    "InputError",
    "Layout",
    "OutputError",
    "ParametricCalibration",
    "PatternDescription",
    "PhaseMap",
    "QAResult",
    "RangeError",
    "ScanQAError",
    "ScannerConfig",
    "__version__",
    "annotate",
    "apply_characterization",
    "build_table",
    "calibrate",
    "calibrate_board",
    "characterize",
    "characterize_board",
    "compare",
    "decode",
    "decode_images",
    "describe",
    "detect_blocks",
    "load_calibration",
    "load_config",
    "load_layout",
    "load_opencv_calibration",
    "load_patterns",
    "load_phase_map",
    "load_sweep",
    "load_table",
    "predict",
    "read_cloud",
    "run_qa",
    "sample_data_path",
    "save_phase_map",
    "save_table",
    "write_cloud",
    "write_report",
]


def __getattr__(name: str):
    """The public API, imported on first use."""
    import importlib

    try:
        module, attribute = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'scanqa' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
