"""Calibration: the nonparametric (Bumbaca-Blais style) table from a plane sweep, and
parametric camera-projector calibrations (OpenCV's) behind the same interface.

- :mod:`~scanqa.calibration.base`: the interface annotation needs (:class:`Calibration`)
  and loading either kind by file suffix;
- :mod:`~scanqa.calibration.parametric`: pinholes with lens distortion, triangulated;
- :mod:`~scanqa.calibration.table`: :class:`CalibrationTable`, its file;
- :mod:`~scanqa.calibration.build`: building it with noise-aware weights;
- :mod:`~scanqa.calibration.lookup`: applying it (constant time per point);
- :mod:`~scanqa.calibration.shear`: the smooth shear of its phase axis;
- :mod:`~scanqa.calibration.sweep`: the observations of a sweep manifest.
"""
