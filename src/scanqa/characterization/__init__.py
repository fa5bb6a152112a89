"""Characterization: the noise of a scanner measured and the model fitted to it, from sweeps
of a flat, from calibration-board poses or from repeated captures."""
