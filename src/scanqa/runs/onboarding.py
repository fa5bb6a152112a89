"""Files a new user would otherwise write by hand: a commented scanner config.

:func:`scanner_config_text` writes the TOML that ``scanqa init`` saves: every key of
:mod:`scanqa.model.config` with its unit and meaning in a comment, filled where the inputs
allow and the placeholder ``"MEASURE"`` elsewhere (loading a config that still holds one
fails with a message naming the key).

From an OpenCV calibration (:class:`~scanqa.calibration.parametric.ParametricCalibration`)
come the image and panel sizes and the projector pose. The config's pose is a position
and a look-at point: the position is the projector's centre -Rp^T Tp, the look-at point
the point of the projector's axis Rp^T e_z closest to the camera's axis. The config has
no roll about that axis, and needs none: the model uses only the depth Z_p along the
axis, and the triangulation comes from the calibration. Focal lengths in mm need the
pixel pitch ([px] -> [mm]); with it, each focal length is the one whose thin-lens image
distance at the focus distance equals the calibrated f_x (the config's principal
distance, :attr:`~scanqa.model.config.CameraConfig.principal_distance_px`), so config and
calibration agree. Unless given, focus distances are ASSUMED to be where the two axes
cross, and say so.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from scanqa.calibration.parametric import ParametricCalibration
from scanqa.errors import InputError
from scanqa.io.schema import Field
from scanqa.model.config import PLACEHOLDER, SCHEMA, ProjectorConfig

#: Model parameters written when nothing better is known (``scanqa characterize`` fits
#: sigma_p and gamma; the wavelength is the projector's light).
MODEL_DEFAULTS = {"wavelength_nm": 550.0, "gamma": 1.0, "sigma_p_px": 0.05}


@dataclass(frozen=True)
class Geometry:
    """What an OpenCV calibration says about the config's geometry keys."""

    position_mm: np.ndarray      # projector centre -Rp^T Tp (3,) [mm]
    look_at_mm: np.ndarray       # point of the projector axis nearest the camera axis [mm]
    camera_focus_mm: float       # Z of the camera-axis point nearest the projector axis [mm]
    projector_focus_mm: float    # distance from the projector to look_at_mm [mm]
    crossing: bool               # False when the axes are (nearly) parallel


def calibration_geometry(cal: ParametricCalibration) -> Geometry:
    """Projector pose as position + look-at, and where the two optical axes cross.

    Parameters
    ----------
    cal : ParametricCalibration
        The calibration.

    Returns
    -------
    Geometry
        Points [mm]; with (nearly) parallel axes the look-at point is 500 mm along the
        projector's axis and ``crossing`` is False.
    """
    pos, axis = cal.projector_position_mm, cal.projector_axis
    b, d, e = axis[2], axis @ pos, pos[2]
    denom = 1.0 - b * b
    if denom < 1e-6:
        s = 500.0
        return Geometry(pos, pos + s * axis, float(pos[2] + s * b), s, False)
    s = (b * e - d) / denom      # along the projector axis
    t = (e - b * d) / denom      # along the camera axis
    return Geometry(pos, pos + s * axis, float(t), float(s), True)


def camera_focal_mm(fx_px: float, pixel_um: float, focus_mm: float) -> float:
    """Focal length [mm] whose thin-lens image distance at ``focus_mm`` [mm] is
    ``fx_px`` pixels of ``pixel_um`` [um]: 1/f = 1/v + 1/Z'."""
    v = fx_px * pixel_um * 1e-3
    return v * focus_mm / (v + focus_mm)


def projector_focal_mm(fx_px: float, pitch_um: float, focus_mm: float) -> float:
    """Focal length [mm] that gives the projector config a principal distance of
    ``fx_px`` [px] at ``focus_mm`` [mm] with pitch ``pitch_um`` [um]
    (:attr:`scanqa.model.config.ProjectorConfig.principal_distance_px`, Eq. 3)."""
    def excess(f: float) -> float:
        cfg = ProjectorConfig(f, 1.0, pitch_um, 1, 1, focus_mm, (0.0, 0.0, 0.0),
                              (0.0, 0.0, 1.0))
        return cfg.principal_distance_px - fx_px

    # search only the focal lengths a config accepts (its field range, and focus >= 4 f)
    limit = SCHEMA.field("projector").table.field("focal_mm").check
    lower, upper = limit.ge, min(limit.le, focus_mm / 4.0 * (1 - 1e-12))
    if not (lower < upper and excess(lower) < 0 < excess(upper)):
        raise InputError(f"the projector's f_x = {fx_px:g} px times the pitch {pitch_um:g} um "
                         f"is not a lens that can focus at {focus_mm:g} mm: check pitch_um")
    return float(brentq(excess, lower, upper, xtol=1e-12))


def scanner_config_text(cal: ParametricCalibration | None = None,
                        pixel_um: float | None = None, pitch_um: float | None = None,
                        camera_focus_mm: float | None = None,
                        projector_focus_mm: float | None = None,
                        periods_px: list[float] | None = None, name: str = "my_scanner"
                        ) -> str:
    """A commented scanner config TOML (module notes).

    Parameters
    ----------
    cal : ParametricCalibration, optional
        Fills sizes, projector pose and (with the pitches) focal lengths.
    pixel_um, pitch_um : float, optional
        Camera pixel size and projector pixel pitch [um].
    camera_focus_mm, projector_focus_mm : float, optional
        Focus distances [mm]; default (with ``cal``) where the axes cross, marked ASSUMED.
    periods_px : list of float, optional
        Fringe periods, finest first [projector px].
    name : str
        The config's ``name``.

    Returns
    -------
    str
        The TOML text; it loads with :func:`scanqa.model.config.load_config` once every
        ``"MEASURE"`` placeholder is replaced.
    """
    for key, value in (("pixel_um", pixel_um), ("pitch_um", pitch_um),
                       ("camera focus_mm", camera_focus_mm),
                       ("projector focus_mm", projector_focus_mm)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"{key} must be > 0, got {value!r}")
    geo = calibration_geometry(cal) if cal is not None else None
    sections = {"camera": _camera(cal, geo, pixel_um, camera_focus_mm),
                "projector": _projector(cal, geo, pitch_um, projector_focus_mm),
                "fringes": [("periods_px", periods_px, "")],
                "model": _model()}
    lines = _header(cal, name)
    for section, entries in sections.items():
        lines += [f"[{section}]", ""]
        for key, value, how in entries:
            lines += _key(SCHEMA.field(section).table.field(key), value, how)  # type: ignore
    return "\n".join(lines).rstrip("\n") + "\n"


def placeholders(text: str) -> list[str]:
    """Keys ("section.key") of a config text that still hold the placeholder."""
    section, keys = "", []
    for line in text.splitlines():
        if line.startswith("["):
            section = line.strip("[] ")
        elif line.endswith(f'= "{PLACEHOLDER}"'):
            keys.append(f"{section}.{line.split('=')[0].strip()}")
    return keys


def _value(value: object) -> str:
    """A TOML value: numbers with enough digits, lists, or the placeholder."""
    if value is None:
        return f'"{PLACEHOLDER}"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_value(float(v)) for v in value) + "]"
    if isinstance(value, bool) or isinstance(value, str):
        return f'"{value}"' if isinstance(value, str) else str(value).lower()
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    text = f"{float(value):.6f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def _key(declared: Field, value: object, how: str) -> list[str]:
    """``key = value`` under its comment: the declared meaning and unit, how to measure."""
    unit = f" [{declared.unit}]" if declared.unit and "[" not in declared.doc else ""
    comment = f"{declared.doc}{unit}{how}"
    lines = [line for part in comment.split("\n")
             for line in textwrap.wrap(part, 86, break_long_words=False, break_on_hyphens=False)]
    return [f"# {line}" for line in lines] + [f"{declared.name} = {_value(value)}", ""]


def _header(cal: ParametricCalibration | None, name: str) -> list[str]:
    src = f"filled from the OpenCV calibration {cal.source}" if cal is not None else \
        "not filled from a calibration"
    return [
        "# scanqa scanner config, written by 'scanqa init' (" + src + ").",
        "# Scanner frame = camera frame: origin at the camera lens, +Z along the camera's",
        "# optical axis, +X right, +Y down. Lengths in mm, units in the key names.",
        f'# Every "{PLACEHOLDER}" must be replaced by a measured or data-sheet value before',
        "# scanqa loads this file; values marked ASSUMED are guesses to check.",
        f'name = "{name}"', ""]


def _camera(cal, geo, pixel_um, focus_mm) -> list[tuple]:
    """(key, value, comment) of the [camera] table."""
    focus, note = _focus(focus_mm, geo.camera_focus_mm if geo else None, geo)
    fx = None if cal is None else float(cal.camera.matrix[0, 0])
    focal = None if None in (fx, pixel_um, focus) else camera_focal_mm(fx, pixel_um, focus)
    how = (f"from Kc f_x = {fx:.2f} px x pixel_um at focus_mm (thin lens)" if focal else
           "the lens's focal length (data sheet), or give --pixel-um with --calibration")
    size = (cal.camera.width_px, cal.camera.height_px) if cal is not None else (None, None)
    return [("focal_mm", focal, f": {how}"), ("f_number", None, " (read the aperture "
             "ring; the blur circle scales as f / N)"), ("pixel_um", pixel_um, " (data sheet)"),
            ("width_px", size[0], _from(cal, "frameWidth")),
            ("height_px", size[1], _from(cal, "frameHeight")), ("focus_mm", focus, note)]


def _projector(cal, geo, pitch_um, focus_mm) -> list[tuple]:
    """(key, value, comment) of the [projector] table."""
    focus, note = _focus(focus_mm, geo.projector_focus_mm if geo else None, geo)
    fx = None if cal is None else float(cal.projector.matrix[0, 0])
    focal = None if None in (fx, pitch_um, focus) else projector_focal_mm(fx, pitch_um, focus)
    how = (f"from Kp f_x = {fx:.2f} px x pitch_um at focus_mm (Eq. 3 of the model)"
           if focal else
           "the lens's focal length (data sheet), or give --pitch-um with --calibration")
    size = (cal.projector.width_px, cal.projector.height_px) if cal is not None else \
        (None, None)
    measure = " (measure it, or use --calibration)"
    pose = ": -Rp^T Tp from the calibration" if cal is not None else measure
    axis = (": where the axis Rp^T e_z passes closest to the camera axis. The config has no "
            "roll about this axis and needs none: the model uses only the depth along it"
            if cal is not None else measure)
    return [("focal_mm", focal, f": {how}"), ("aperture_mm", None, ""),
            ("pitch_um", pitch_um, " (data sheet)"),
            ("width_px", size[0], _from(cal, "screenResX")),
            ("height_px", size[1], _from(cal, "screenResY")), ("focus_mm", focus, note),
            ("position_mm", None if geo is None else geo.position_mm, pose),
            ("look_at_mm", None if geo is None else geo.look_at_mm, axis)]


def _model() -> list[tuple]:
    """(key, value, comment) of the [model] table."""
    d = MODEL_DEFAULTS
    fitted = " (STARTING VALUE: 'scanqa characterize' fits it)"
    return [("wavelength_nm", d["wavelength_nm"], " (ASSUMED: white light; 460 for a blue "
             "LED)"), ("gamma", d["gamma"], fitted), ("sigma_p_px", d["sigma_p_px"], fitted),
            ("filter_floor", "none", ""), ("noise_reading", "power", ""),
            ("characterised_by", "", " (never free words: 'scanqa characterize board' or "
             "--model SUMMARY.json fill it; every command warns while it is empty)")]


def _from(cal: ParametricCalibration | None, key: str) -> str:
    return f" ({key} of the calibration)" if cal is not None else ""


def _focus(given: float | None, derived: float | None, geo: Geometry | None
           ) -> tuple[float | None, str]:
    """A focus distance and the note saying where it came from."""
    if given is not None:
        return given, " (given to 'scanqa init')"
    if derived is None or not (derived > 0):
        return None, ""
    where = "the two optical axes cross" if geo is not None and geo.crossing else \
        "500 mm along the projector axis (the axes are parallel)"
    return derived, (f" (ASSUMED: focused where {where}; measure it, e.g. the distance of "
                     "the sharpest image, and recompute focal_mm)")
