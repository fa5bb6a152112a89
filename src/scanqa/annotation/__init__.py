"""Annotation: the per-point uncertainty of a decoded scan through its calibration, and
the range-dependent filter that flattens it (Sect. 5.2 of the paper)."""
