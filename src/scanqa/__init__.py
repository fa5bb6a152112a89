"""scanqa: calibration-aware uncertainty toolkit for phase-shift 3D scanners.

Lengths are in millimetres, phase is the unwrapped projector coordinate x_p in
projector pixels, and standard deviations in reports are in micrometres.
"""

from __future__ import annotations

__version__ = "0.1.0"

from scanqa.errors import ConfigError, InputError, ScanQAError

__all__ = ["ConfigError", "InputError", "ScanQAError", "__version__"]
