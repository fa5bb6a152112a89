"""Calibration: the nonparametric (Bumbaca-Blais style) table from a plane sweep.

- :mod:`~scanqa.calibration.table`: :class:`CalibrationTable`, its file;
- :mod:`~scanqa.calibration.build`: building it with noise-aware weights;
- :mod:`~scanqa.calibration.lookup`: applying it (constant time per point);
- :mod:`~scanqa.calibration.shear`: the smooth shear of its phase axis;
- :mod:`~scanqa.calibration.sweep`: the observations of a sweep manifest.
"""
