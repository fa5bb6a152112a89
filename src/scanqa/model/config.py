"""Scanner configs: TOML files in ``calib/`` loaded into validated frozen dataclasses.

A config describes one camera-projector pair in the scanner frame (the camera frame:
origin at the camera lens, +Z along the optical axis, +X right, +Y down), the fringe
periods, the parameters of the defocus model and, optionally, simulator-only settings.
Units are in the key names (``focal_mm``, ``pixel_um``, ``wavelength_nm``).

Profiles (``[profiles.NAME]`` tables) override keys of the base file, so that variants
of one scanner (the paper's f/11 and f/16 settings) need no edited copy::

    [profiles.f11]
    camera.f_number = 11.0
    model.gamma = 5.0

Every invalid value raises one :class:`~scanqa.errors.ConfigError` naming the key, the
value, the expected range and the file.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from scanqa.errors import ConfigError
from scanqa.io.fitted_model import absolute_evidence, check_characterised_by
from scanqa.io.schema import Check, Field, Schema, at_least, count, greater, one_of, within
from scanqa.io.tomlfile import read_toml

#: The values of ``model.filter_floor``: Eq. 17's readings (docs/model.rst, reading (i)).
FILTER_FLOORS = ("none", "one", "smooth")
#: The values of ``model.filter_form``: how F is formed (docs/noise_model.rst).
FILTER_FORMS = ("product", "sum")
#: The values of ``model.noise_reading`` (docs/model.rst, reading (ii); the paper's first).
NOISE_READINGS = ("power", "amplitude", "mixed", "two_source")
#: Largest sensor or panel side a config may declare [px] (bounds every image allocation).
MAX_SIDE_PX = 100_000
#: Range of the magnitude of any non-zero number in a config, in its unit: beyond it a
#: value is a typo, and the model's products of powers would overflow.
MIN_MAGNITUDE, MAX_MAGNITUDE = 1e-9, 1e9


def _spec(type_: str, unit: str = "", check: Check | None = None, doc: str = "",
          default: Any = MISSING) -> Any:
    """A key of a section: a dataclass field whose metadata holds its declaration, an
    :class:`~scanqa.io.schema.Field` (named by :data:`SCHEMA` after the attribute)."""
    declared = Field("", type_, unit, default is MISSING, None if default is MISSING
                     else default, check, doc)
    return field(default=default, metadata={"field": declared})


def _expected(f: Field) -> str:
    """The field's limit as messages say it, e.g. '>= 0.5 mm and <= 5000 mm'."""
    unit = f" {f.unit}" if f.unit not in ("", "-") else ""
    c = f.check or Check()
    parts = [f"{op} {b:g}{unit}" for op, b in ((">", c.gt), (">=", c.ge), ("<=", c.le))
             if b is not None]
    return " and ".join(parts) or c.text or f.expected()


def _check_number(key: str, value: Any, f: Field) -> float:
    """Validate one scalar against its declaration and return it as float or int."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key} must be a number ({_expected(f)}), got {value!r}")
    if f.type == "integer" and (not float(value).is_integer()):
        raise ConfigError(f"{key} must be a whole number ({_expected(f)}), got {value!r}")
    v = float(value)
    if math.isfinite(v) and v != 0 and not MIN_MAGNITUDE <= abs(v) <= MAX_MAGNITUDE:
        raise ConfigError(f"{key} must be {_expected(f)}, between {MIN_MAGNITUDE:g} and "
                          f"{MAX_MAGNITUDE:g} in magnitude (or 0 where allowed), got {value!r}")
    if not math.isfinite(v) or (f.check is not None and not f.check.test(v)):
        raise ConfigError(f"{key} must be {_expected(f)}, got {value!r}")
    return int(v) if f.type == "integer" else v


#: Value ``scanqa init`` writes where the user must measure or look up a number.
PLACEHOLDER = "MEASURE"


def _check_value(key: str, value: Any, f: Field) -> Any:
    """Validate a key of any declared type (number, integer, string, numbers)."""
    if isinstance(value, str) and value.startswith(PLACEHOLDER):
        raise ConfigError(f"{key} is still the placeholder {value!r} that 'scanqa init' wrote: "
                          f"replace it with the measured value ({_expected(f)}; the "
                          "comment above it says what to measure)")
    if f.type == "string" and f.check is None and not (
            isinstance(value, str) and len(value) <= 2000 and value.isprintable()):
        raise ConfigError(f"{key} must be one line of text (at most 2000 characters), "
                          f"got {value!r:.80}")
    if f.type == "string" and f.check is not None and value not in f.check.choices:
        raise ConfigError(f"{key} must be {_expected(f)}, got {value!r}")
    if f.type == "string":
        return value
    if f.type == "numbers":
        n = f.check.n if f.check else None
        if not isinstance(value, (list, tuple)) or not value or n not in (None, len(value)):
            what = f"a list of {n} numbers" if n else "a non-empty list of numbers"
            raise ConfigError(f"{key} must be {what} [{f.unit}], got {value!r}")
        item = replace(f, type="number", check=f.check and replace(f.check, n=None))
        return tuple(_check_number(f"{key}[{i}]", v, item) for i, v in enumerate(value))
    return _check_number(key, value, f)


class _Section:
    """Mixin: validates every field of a frozen dataclass in ``__post_init__``."""

    section: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for f in fields(self):  # type: ignore[arg-type]
            key, declared = f"{self.section}.{f.name}", f.metadata["field"]
            object.__setattr__(self, f.name, _check_value(key, getattr(self, f.name), declared))
        self._check_cross()

    def _check_cross(self) -> None:
        """Checks that involve several fields (overridden where needed)."""


_SIDE = within(1, MAX_SIDE_PX)


@dataclass(frozen=True)
class CameraConfig(_Section):
    """Camera lens and sensor; its frame is the scanner frame."""

    section: ClassVar[str] = "camera"
    focal_mm: float = _spec("number", "mm", within(0.5, 5000), "focal length of the lens")
    f_number: float = _spec("number", "-", within(0.5, 256), "f-number N the lens is set to")
    pixel_um: float = _spec("number", "um", within(0.1, 1000), "pixel size of the sensor")
    width_px: int = _spec("integer", "px", _SIDE, "image width")
    height_px: int = _spec("integer", "px", _SIDE, "image height")
    focus_mm: float = _spec("number", "mm", greater(0), "distance the camera is focused "
                            "at along its axis, beyond focal_mm")
    def _check_cross(self) -> None:
        if self.focus_mm <= self.focal_mm:
            raise ConfigError(
                f"camera.focus_mm must be > camera.focal_mm = {self.focal_mm:g} mm "
                f"(a lens cannot focus closer than its focal length), got {self.focus_mm!r}")

    @property
    def aperture_mm(self) -> float:
        """Aperture diameter Phi_c = f / N [mm] (Eq. 2)."""
        return self.focal_mm / self.f_number

    @property
    def principal_distance_px(self) -> float:
        """Pinhole principal distance: the thin-lens image distance at focus [px]."""
        v = self.focal_mm * self.focus_mm / (self.focus_mm - self.focal_mm)
        return v / (self.pixel_um * 1e-3)

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """Principal point (u0, v0) at the sensor centre [px]."""
        return ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0)


@dataclass(frozen=True)
class ProjectorConfig(_Section):
    """Projector lens, panel and pose in the scanner frame.

    Fringes vary along the projector's x axis (panel columns), so the decoded phase is
    the projector column coordinate x_p [projector px].
    """

    section: ClassVar[str] = "projector"
    focal_mm: float = _spec("number", "mm", within(0.5, 5000), "focal length of the lens")
    aperture_mm: float = _spec("number", "mm", within(0.01, 1000),
                               "aperture diameter of the lens (focal length / f-number)")
    pitch_um: float = _spec("number", "um", within(0.1, 1000), "pixel pitch of the panel "
                            "along x (active width / width_px)")
    width_px: int = _spec("integer", "px", _SIDE, "panel width")
    height_px: int = _spec("integer", "px", _SIDE, "panel height")
    focus_mm: float = _spec("number", "mm", greater(0), "distance the projector is "
                            "focused at along its axis, at least 4 x focal_mm")
    position_mm: tuple = _spec("numbers", "mm", count(3), "the projector's centre in the "
                               "scanner frame")
    look_at_mm: tuple = _spec("numbers", "mm", count(3), "a point on the projector's axis")

    def _check_cross(self) -> None:
        if self.focus_mm < 4.0 * self.focal_mm:
            raise ConfigError(
                f"projector.focus_mm must be >= 4 x projector.focal_mm = "
                f"{4.0 * self.focal_mm:g} mm (the projector's magnification, Eq. 3, holds "
                f"from four focal lengths on), got {self.focus_mm!r}")
        if np.allclose(self.position_mm, self.look_at_mm):
            raise ConfigError("projector.look_at_mm must differ from projector.position_mm, "
                              f"got both {list(self.position_mm)}")

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation from scanner to projector frame: Q_p = R (Q - position)."""
        z = np.subtract(self.look_at_mm, self.position_mm)
        z = z / np.linalg.norm(z)
        x = np.cross([0.0, 1.0, 0.0], z)
        if np.linalg.norm(x) < 1e-9:
            raise ConfigError("projector optical axis must not be parallel to the scanner Y axis")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        return np.vstack([x, y, z])

    @property
    def principal_distance_px(self) -> float:
        """Pinhole principal distance, consistent with Eq. 3 at focus [px].

        The projector's pinhole magnification at its focus distance equals the paper's
        m_p(Z_p') (Eq. 3), so that the fringe period on an object at focus is the model's
        omega_o(Z_p') exactly; the pitch was inferred through Eq. 3 (``calib/*.toml``).
        Away from focus the pinhole period grows as Z_p, Eq. 4 as 1 / m_p(Z_p).
        """
        z = self.focus_mm
        m_focus = 2.0 * self.focal_mm / (z - 2.0 * self.focal_mm
                                         + math.sqrt(z * (z - 4.0 * self.focal_mm)))
        return m_focus * z / (self.pitch_um * 1e-3)

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """Principal point (x0, y0) at the panel centre [px]."""
        return ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0)


@dataclass(frozen=True)
class FringeConfig(_Section):
    """The projected fringe periods; the smallest is the working period."""

    section: ClassVar[str] = "fringes"
    periods_px: tuple = _spec("numbers", "px", within(2, MAX_SIDE_PX * 100), "the "
                              "projected periods [projector px]; the smallest is the working one")

    @property
    def working_period_px(self) -> float:
        """The period whose phase noise sets the point noise [px]: the smallest one."""
        return float(min(self.periods_px))


@dataclass(frozen=True)
class ModelConfig(_Section):
    """Parameters and readings of the defocus model (paper Sect. 3; docs/noise_model.rst).

    The readings' defaults are the model the simulated camera and projector sweeps select
    on held-out positions; the paper's config sets the paper's reading explicitly.
    """

    section: ClassVar[str] = "model"
    wavelength_nm: float = _spec("number", "nm", within(100, 20000),
                                 "wavelength of the projected light")
    gamma: float = _spec("number", "-", within(1, 1000),
                         "camera noise-filtering factor of Eq. 17")
    sigma_p_px: float = _spec("number", "px", within(0, 100, open_low=True), "phase noise at "
                              "focus before the optical scale [projector px]")
    filter_floor: str = _spec("string", "", one_of(*FILTER_FLOORS), '"none" applies Eq. 17 '
                              'as printed (F < 1 amplifies noise); "one" clamps F >= 1 as the '
                              "paper's bound 1 <= gamma <= sqrt(b_c b_d) implies; \"smooth\" "
                              "takes F^2 + 1, the variance share gamma^2 / (gamma^2 + N) kept "
                              "under a kernel of noise-equivalent area N", "one")
    noise_reading: str = _spec("string", "", one_of(*NOISE_READINGS), "how attenuation "
                               'enters s_O: "power" divides it by A (Eq. 19 as printed), '
                               '"amplitude" by sqrt(A), "mixed" by A_c sqrt(A_p); '
                               '"two_source" adds scene-side noise (sigma_p, filtered by F) '
                               "and sensor noise (sensor_sigma_p_px, not filtered), each "
                               "divided by sqrt(A_c A_p)", "two_source")
    filter_form: str = _spec("string", "", one_of(*FILTER_FORMS), '"product" is Eq. 17 as '
                             'printed, F = sqrt(b_c b_d) / gamma; "sum" takes F^2 as the '
                             "noise-equivalent area of pixel, defocus disc and Airy disc "
                             "together, (1 + b_disc + b_d) / gamma^2", "sum")
    sensor_sigma_p_px: float = _spec("number", "px", within(0, 100), "phase noise of the "
                                     "sensor at focus (A_c = A_p = 1) [projector px]; "
                                     "two_source only", 0.0)
    characterised_by: str = _spec("string", "", None, "where sigma_p comes from: a "
                                  "characterisation file and the start of its sha256, "
                                  "'summary.json sha256 HEX'; empty: assumed, and the "
                                  "images' own noise sets each point's sigma", "")
    noise_read_var_dn2: float = _spec("number", "DN^2", at_least(0), "per-pixel noise law "
                                      "fitted to a board ('scanqa characterize board'): "
                                      "intensity variance a + b A per frame at offset A; "
                                      "this is a (0 and 0: no law)", 0.0)
    noise_shot_dn: float = _spec("number", "DN", at_least(0), "b of that law", 0.0)
    systematic_sigma_mm: float = _spec("number", "mm", at_least(0), "systematic error per "
                                       "point a characterisation measured (board flatness "
                                       "and calibration), added in quadrature", 0.0)

    @property
    def has_noise_law(self) -> bool:
        """True when a board characterisation gave a per-pixel noise law."""
        return self.noise_read_var_dn2 > 0 or self.noise_shot_dn > 0


@dataclass(frozen=True)
class SimulatorConfig(_Section):
    """Simulator-only settings (ignored by the model), all optional (docs/simulator.rst).

    A white surface at normal incidence gives ``mean_signal_e``, ``1 - modulation_ratio``
    of it ambient; the realism settings (distortion, tilts, a printed target) are off."""

    section: ClassVar[str] = "simulator"
    seed: int = _spec("integer", "-", at_least(0), "seed of every random stream", 0)
    supersampling: int = _spec("integer", "-", within(1, 16), "s x s rays per pixel", 3)
    bit_depth: int = _spec("integer", "bit", within(8, 16), "image quantisation", 12)
    gain_e_per_dn: float = _spec("number", "e-/DN", greater(0), "sensor gain", 10.0)
    read_noise_e: float = _spec("number", "e-", at_least(0), "read noise", 10.0)
    full_well_e: float = _spec("number", "e-", greater(0), "saturation", 40000.0)
    scene_noise_rel: float = _spec("number", "-", at_least(0), "std of the scene-side noise "
                                   "relative to the local level, per pattern", 0.05)
    scene_noise_cell_mm: float = _spec("number", "mm", at_least(0), "size of its object "
                                       "cells; 0: white per supersample", 0.06)
    mean_signal_e: float = _spec("number", "e-", greater(0), "signal of a white surface at "
                                 "normal incidence", 20000.0)
    modulation_ratio: float = _spec("number", "-", within(0, 1, open_low=True), "fringe "
                                    "modulation B / A at focus", 0.8)
    projector_samples: int = _spec("integer", "-", within(16, 65536), "points of the "
                                   "projector's disc quadrature", 256)
    steps: int = _spec("integer", "-", within(3, 64), "frames per phase set", 4)
    unwrap_periods_px: tuple = _spec("numbers", "px", greater(0), "coarser periods (steps "
                                     "frames each) that unwrap the working one [projector px]",
                                     (80.0, 1280.0))
    roi_width_px: int = _spec("integer", "px", at_least(0), "width of a centred window of "
                              "the sensor to render, optics unchanged (0: the whole sensor)", 0)
    roi_height_px: int = _spec("integer", "px", at_least(0), "its height (0: the whole "
                               "sensor)", 0)
    projector_gamma: float = _spec("number", "-", within(0, 10, open_low=True), "projector "
                                   "response: it emits p**projector_gamma for a pattern "
                                   "value p in [0, 1] (1: linear)", 1.0)
    camera_k1: float = _spec("number", "-", within(-50, 50), "camera distortion, "
                             "Brown-Conrady (OpenCV) on normalised coordinates", 0.0)
    camera_k2: float = _spec("number", "-", within(-5000, 5000), "the same, k2", 0.0)
    camera_p1: float = _spec("number", "-", within(-1, 1), "the same, p1", 0.0)
    camera_p2: float = _spec("number", "-", within(-1, 1), "the same, p2", 0.0)
    camera_cx_offset_px: float = _spec("number", "px", within(-1000, 1000), "the camera's "
                                       "principal point off the sensor centre, along x (the "
                                       "config's principal_point_px stays the centre)", 0.0)
    camera_cy_offset_px: float = _spec("number", "px", within(-1000, 1000), "the same, "
                                       "along y", 0.0)
    projector_k1: float = _spec("number", "-", within(-50, 50), "projector distortion, the "
                                "camera's model", 0.0)
    projector_k2: float = _spec("number", "-", within(-5000, 5000), "the same, k2", 0.0)
    projector_p1: float = _spec("number", "-", within(-1, 1), "the same, p1", 0.0)
    projector_p2: float = _spec("number", "-", within(-1, 1), "the same, p2", 0.0)
    stage_tilt_deg: float = _spec("number", "deg", within(0, 20), "the calibration stage's "
                                  "axis tilted against the camera axis", 0.0)
    stage_tilt_azimuth_deg: float = _spec("number", "deg", within(-360, 360), "towards "
                                          "where (0: +X, 90: +Y)", 0.0)
    target_tilt_deg: float = _spec("number", "deg", within(-30, 30), "the calibration flat "
                                   "turned about the X axis", 0.0)
    target: str = _spec("string", "", one_of("none", "chessboard"), '"chessboard": print '
                        "the marked chessboard on the calibration flat and render a marker "
                        "frame per position", "none")
    target_square_mm: float = _spec("number", "mm", greater(0), "its square", 4.0)
    target_contrast: float = _spec("number", "-", within(0, 1), "albedo contrast of the "
                                   "print in the marker frame", 0.8)
    target_fringe_contrast: float = _spec("number", "-", within(0, 1), "the same under the "
                                          "fringe light", 0.0)


_SECTIONS = {"camera": CameraConfig, "projector": ProjectorConfig, "fringes": FringeConfig,
             "model": ModelConfig, "simulator": SimulatorConfig}

#: The scanner config's tables and keys, declared once: each key's type, unit, limits,
#: default and meaning are its section's dataclass field (docs/formats.rst shows them).
SCHEMA = Schema("scanner config", (
    Field("name", "string", doc="the scanner's name (default: the file's stem)"),
    *(Field(name, "table", required=name != "simulator", doc=cls.__doc__.split("\n")[0],
            table=Schema(f"[{name}]", tuple(replace(f.metadata["field"], name=f.name)
                                             for f in fields(cls))))
      for name, cls in _SECTIONS.items()),
    Field("profiles", "table", doc="[profiles.NAME] tables of overrides of the keys above, "
          "e.g. camera.f_number = 11.0")))


@dataclass(frozen=True)
class ScannerConfig:
    """A whole scanner config, as loaded from a TOML file (and an optional profile)."""

    camera: CameraConfig
    projector: ProjectorConfig
    fringes: FringeConfig
    model: ModelConfig
    simulator: SimulatorConfig = field(default_factory=SimulatorConfig)
    name: str = ""
    source: str = ""
    profile: str = ""

    def to_dict(self) -> dict:
        """Plain dict of every section (for provenance in output files)."""
        out: dict = {name: {k: list(v) if isinstance(v, tuple) else v for k, v in
                            asdict(getattr(self, name)).items()} for name in _SECTIONS}
        return {**out, "name": self.name}

    @property
    def axes_crossing_mm(self) -> np.ndarray:
        """The point of the camera axis closest to the projector axis, (3,) [mm]: where
        both devices look, the centre of the camera and projector sweeps."""
        p = np.asarray(self.projector.position_mm, dtype=float)
        a = self.projector.rotation[2]
        b, d, f = a[2], -p[2], -(a @ p)
        denom = 1.0 - b * b
        t = (b * f - d) / denom if denom > 1e-12 else self.camera.focus_mm
        return np.array([0.0, 0.0, t])

    def replace_model(self, **changes: Any) -> ScannerConfig:
        """Copy with some model parameters changed (validated again)."""
        return replace(self, model=ModelConfig(**{**asdict(self.model), **changes}))

    def replace_simulator(self, **changes: Any) -> ScannerConfig:
        """Copy with some simulator settings changed (validated again)."""
        return replace(self, simulator=SimulatorConfig(**{**asdict(self.simulator),
                                                          **changes}))


def _merge(base: dict, over: dict) -> dict:
    """Deep-merge ``over`` into a copy of ``base``."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _build_section(name: str, table: Any) -> Any:
    """Build one section dataclass, rejecting unknown and missing keys."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{name}] must be a table, got {table!r}")
    declared = SCHEMA.field(name).table.fields  # type: ignore[union-attr]
    unknown = sorted(set(table) - {f.name for f in declared})
    if unknown:
        raise ConfigError(f"unknown key {name}.{unknown[0]} (known keys of [{name}]: "
                          f"{', '.join(sorted(f.name for f in declared))})")
    missing = [f for f in declared if f.required and f.name not in table]
    if missing:
        raise ConfigError(f"missing key {name}.{missing[0].name} (expected "
                          f"{_expected(missing[0])})")
    return _SECTIONS[name](**table)


def config_from_dict(data: dict, source: str = "<dict>", profile: str | None = None
                     ) -> ScannerConfig:
    """Validate a config given as nested dicts (the parsed TOML).

    Parameters
    ----------
    data : dict
        Parsed TOML: tables ``camera``, ``projector``, ``fringes``, ``model``, optional
        ``simulator`` and ``profiles``, and an optional top-level ``name``.
    source : str
        File name used in error messages.
    profile : str, optional
        Name of a ``[profiles.NAME]`` table to apply over the base values.
    """
    try:
        return _config_from_dict(data, source, profile)
    except ConfigError as err:
        raise ConfigError(f"{err} (in {source})") from None


def _config_from_dict(data: dict, source: str, profile: str | None) -> ScannerConfig:
    data = dict(data)
    profiles = data.pop("profiles", {})
    name = data.pop("name", Path(source).stem)
    if not isinstance(profiles, dict):
        raise ConfigError(f"profiles must be [profiles.NAME] tables, got {profiles!r}")
    for pname, ptable in profiles.items():  # every profile must be valid, used or not
        _check_profile_keys(pname, ptable)
    if profile:
        if profile not in profiles:
            avail = ", ".join(sorted(profiles)) or "none"
            raise ConfigError(f"unknown profile {profile!r} (profiles in this file: {avail})")
        data = _merge(data, profiles[profile])
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ConfigError(f"unknown table or key {unknown[0]!r} (known: "
                          f"{', '.join(_SECTIONS)}, name, profiles)")
    for sec in _SECTIONS:
        if sec not in data and SCHEMA.field(sec).required:
            raise ConfigError(f"missing table [{sec}]")
    built = {sec: _build_section(sec, data.get(sec, {})) for sec in _SECTIONS}
    return ScannerConfig(**built, name=str(name), source=source, profile=profile or "")


def _check_profile_keys(pname: str, ptable: Any) -> None:
    """Reject profile keys that do not exist in the schema."""
    if not isinstance(ptable, dict):
        raise ConfigError(f"[profiles.{pname}] must be a table of overrides such as "
                          f"camera.f_number = 11.0, got {ptable!r}")
    for sec, table in ptable.items():
        if sec not in _SECTIONS or not isinstance(table, dict):
            raise ConfigError(f"unknown table {sec!r} in [profiles.{pname}]")
        known = {f.name for f in fields(_SECTIONS[sec])}
        for key in table:
            if key not in known:
                raise ConfigError(f"unknown key {sec}.{key} in [profiles.{pname}]")


def load_config(path: str | os.PathLike, profile: str | None = None) -> ScannerConfig:
    """Load and validate a scanner config TOML file.

    Parameters
    ----------
    path : str or PathLike
        The TOML file. ``FILE#PROFILE`` selects a profile too.
    profile : str, optional
        Name of a ``[profiles.NAME]`` table to apply.

    Returns
    -------
    ScannerConfig
        The validated config.

    Raises
    ------
    ConfigError
        On an unreadable file, TOML syntax error, unknown or missing key, or bad value.
    """
    text_path = str(path)
    if "#" in text_path and profile is None:
        text_path, profile = text_path.rsplit("#", 1)
    p = Path(text_path)
    data = read_toml(p, "scanner config", ConfigError)
    config = config_from_dict(data, source=str(p), profile=profile)
    evidence = config.model.characterised_by
    check_characterised_by(evidence, p)  # evidence, not words
    # named by absolute path from here on: a config written elsewhere (an export, a test's
    # copy, a recorded config) still names the same file
    return config.replace_model(characterised_by=absolute_evidence(evidence, p)) \
        if evidence else config


def first_difference(config: ScannerConfig, recorded: dict,
                     sections: tuple[str, ...] = ("camera", "projector")
                     ) -> tuple[str, str, Any, Any] | None:
    """The first key where ``config`` differs from a recorded config (a manifest's
    ``config`` table, or ``to_dict()`` of another config), section by section in key
    order; numbers compare to a relative 1e-9. ``None`` when they agree.

    Returns
    -------
    (section, key, value in config, recorded value) or None
    """
    given = config.to_dict()
    for section in sections:
        for key, theirs in sorted((recorded.get(section) or {}).items()):
            mine = given[section].get(key)
            if not np.allclose(np.asarray(mine, float), np.asarray(theirs, float),
                               rtol=1e-9, atol=1e-12):
                return section, key, mine, theirs
    return None
