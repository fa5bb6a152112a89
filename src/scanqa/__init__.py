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
       cloud.write("cloud.ply")          # .ply .las .csv .parquet; the model goes along
       cloud.to_open3d(), cloud.to_dataframe()

3. QA report - gauge blocks: plane fits, measured vs predicted std, steps with U::

       qa = scanqa.run_qa(scanqa.read_cloud("cloud.ply"), scanqa.load_layout("layout.toml"))
       scanqa.write_report(qa, "qa/")   # report.html, blocks.csv, steps.csv, summary.json

Characterise a scanner (fit sigma_p, gamma and the model's reading to a sweep) with
:func:`characterize` and apply the result with ``result.apply_to(config)``; predict the
std of any point with :func:`predict`. Every error a user can cause is a
:class:`ScanQAError`. Progress and notes go to the ``scanqa`` logger (shown after
``logging.basicConfig(level=logging.INFO)``; :mod:`scanqa.progress`).
"""

from __future__ import annotations

from scanqa._version import __version__
from scanqa.annotation import annotate
from scanqa.calibration.base import Calibration, load_calibration
from scanqa.calibration.build import BuildReport, build_table
from scanqa.calibration.parametric import ParametricCalibration, load_opencv_calibration
from scanqa.calibration.sweep import calibrate, load_sweep
from scanqa.calibration.table import CalibrationTable, load_table, save_table
from scanqa.characterization import characterize_sweeps as characterize
from scanqa.cloud import AnnotatedCloud, read_cloud, write_cloud
from scanqa.config import ScannerConfig, load_config
from scanqa.decoding.coding import PatternDescription
from scanqa.decoding.decoder import decode, decode_images
from scanqa.decoding.parsing import load_patterns
from scanqa.decoding.phasemap import PhaseMap, load_phase_map, save_phase_map
from scanqa.errors import ConfigError, InputError, OutputError, RangeError, ScanQAError
from scanqa.optics import predict
from scanqa.qa.blocks import QAResult, run_qa
from scanqa.qa.detect import detect_blocks
from scanqa.qa.layout import Layout, load_layout
from scanqa.report.qa import write_outputs as write_report

__all__ = [
    "AnnotatedCloud", "BuildReport", "Calibration", "CalibrationTable", "ConfigError",
    "InputError", "Layout", "OutputError", "ParametricCalibration", "PatternDescription",
    "PhaseMap", "QAResult", "RangeError", "ScanQAError", "ScannerConfig", "__version__",
    "annotate",
    "build_table", "calibrate", "characterize", "decode", "decode_images", "detect_blocks",
    "load_calibration", "load_config", "load_layout", "load_opencv_calibration",
    "load_patterns", "load_phase_map", "load_sweep", "load_table", "predict", "read_cloud",
    "run_qa", "save_phase_map", "save_table", "write_cloud", "write_report",
]
