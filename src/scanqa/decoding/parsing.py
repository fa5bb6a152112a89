"""Validation of a parsed ``patterns.toml`` into a :class:`PatternDescription`.

Both format versions are read. Version 1 files keep the meaning of what they state:
their ``thresholds.gray_max_residual`` (cycles of the ordered period, whose Gray cells
were always half a period) becomes ``gray_edge_cells = 2 gray_max_residual - 1/2``, and
a ``[sensor]`` table with only one of gain and read noise gets version 1's 4 e-/DN or
8 e- for the other. What they leave out takes today's defaults, on purpose: without
sensor gain and read noise the noise is estimated from the images (the 4 e-/DN, 8 e-
guess masked real 8-bit cameras wholesale), and ``unwrap_sigma_margin`` is 2 (version
1's 4 asked a 12 sigma excursion for a fringe-order error). Every file the simulator
wrote states both, so it decodes as before.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

from scanqa.decoding.coding import (
    DecodeOptions,
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
    Thresholds,
    require_setting,
)
from scanqa.errors import ConfigError
from scanqa.io.patterns import FORMAT, READ_FORMATS, SCHEMA, read_patterns_file

_V1 = READ_FORMATS[0]
_STORAGE_KEYS = ("name", "files", "stack", "stack_key")
_SET_KEYS = {
    _V1: {"phase": ("kind", "period_px", "steps", "shifts_rad", "orientation",
                    *_STORAGE_KEYS),
          "gray": ("kind", "bits", "orders", "inverse", "orientation", *_STORAGE_KEYS)},
    FORMAT: {"phase": ("kind", "period_px", "steps", "shifts_rad", "orientation",
                       *_STORAGE_KEYS),
             "gray": ("kind", "bits", "cell_px", "orders", "inverse", "threshold",
                      "orientation", "code", *_STORAGE_KEYS),
             "reference": ("kind", "levels", *_STORAGE_KEYS)},
}
#: Top-level keys per version: the declared ones (:data:`scanqa.io.patterns.SCHEMA`),
#: version 1 without ``[decode]``.
_TOP_KEYS = {FORMAT: tuple(f.name for f in SCHEMA.fields)}
_TOP_KEYS[_V1] = tuple(k for k in _TOP_KEYS[FORMAT] if k != "decode")
_V1_THRESHOLDS = ("min_modulation_dn", "unwrap_max_residual", "unwrap_sigma_margin",
                  "gray_max_residual", "gray_min_contrast_sigma", "max_period_ratio")


def load_patterns(path: str | os.PathLike) -> PatternDescription:
    """Load and validate a ``patterns.toml`` (or the one inside a folder).

    Parameters
    ----------
    path : str or PathLike
        The patterns.toml file, or the pattern folder that contains it.

    Returns
    -------
    PatternDescription
        The validated description, with ``source`` set to the file path.

    Raises
    ------
    ConfigError
        On a missing/unreadable file, bad TOML, an unknown or missing key, a bad value,
        a wrong count of files, or a coding that cannot be decoded.
    """
    data, p = read_patterns_file(path)
    return patterns_from_dict(data, source=str(p))


def patterns_from_dict(data: dict, source: str = "<dict>") -> PatternDescription:
    """Validate a parsed patterns.toml given as nested dicts.

    Parameters
    ----------
    data : dict
        The parsed TOML.
    source : str
        File name used in error messages and to resolve relative image paths.
    """
    SCHEMA.validate(data, source, ConfigError)
    try:
        return _from_dict(data, source)
    except ConfigError as err:
        raise ConfigError(f"{err} (in {source})") from None
    except TypeError as err:
        raise ConfigError(f"bad value in pattern description: {err} (in {source})") from None


def _from_dict(data: dict, source: str) -> PatternDescription:
    fmt = data.get("format")
    require_setting(fmt in READ_FORMATS, "format", fmt,
             f"one of {', '.join(map(repr, READ_FORMATS))} (the versions this scanqa reads)")
    _reject_unknown("", data, _TOP_KEYS[fmt])
    require_setting("projector_width_px" in data, "projector_width_px", None,
             "given (the coded range along the fringe direction [projector px])")
    raw_sets = data.get("set", [])
    require_setting(isinstance(raw_sets, list) and len(raw_sets) > 0, "set", raw_sets,
             "one or more [[set]] tables")
    sets = tuple(_parse_set(fmt, i, t) for i, t in enumerate(raw_sets))
    return PatternDescription(
        projector_width_px=_integer("projector_width_px", data["projector_width_px"]),
        sets=sets, sensor=_sensor(fmt, data.get("sensor", {})),
        thresholds=_thresholds(fmt, data.get("thresholds", {})),
        description=str(data.get("description", "")), source=source,
        options=_options(data.get("decode", {})))


def _sensor(fmt: str, table: Any) -> SensorModel:
    """The [sensor] table; version 1 fills a lone gain or read noise with its default."""
    args = _table("sensor", table, list(SensorModel.__dataclass_fields__))
    if fmt == _V1 and ("gain_e_per_dn" in args) != ("read_noise_e" in args):
        args.setdefault("gain_e_per_dn", 4.0)
        args.setdefault("read_noise_e", 8.0)
    return SensorModel(**args)


def _thresholds(fmt: str, table: Any) -> Thresholds:
    """The [thresholds] table, version 1 translated to version 2's keys."""
    if fmt != _V1:
        return Thresholds(**_table("thresholds", table, list(Thresholds.__dataclass_fields__)))
    args = _table("thresholds", table, _V1_THRESHOLDS)
    gray = args.pop("gray_max_residual", 0.375)
    require_setting(0.25 < gray < 0.5, "thresholds.gray_max_residual", gray,
             "in (0.25, 0.5) [cycles]")
    return Thresholds(**args, gray_edge_cells=2.0 * gray - 0.5)


def _options(table: Any) -> DecodeOptions:
    require_setting(isinstance(table, dict), "[decode]", table, "a table")
    _reject_unknown("decode.", table, list(DecodeOptions.__dataclass_fields__))
    for key in ("noise", "channel", "response"):
        if key in table:
            require_setting(isinstance(table[key], str), f"decode.{key}", table[key], "a string")
    return DecodeOptions(**table)


def _reject_unknown(prefix: str, table: dict, known: Sequence[str]) -> None:
    for key in table:
        if key not in known:
            raise ConfigError(f"unknown key {prefix}{key} (known keys: {', '.join(known)})")


def _table(name: str, table: Any, known: Sequence[str]) -> dict:
    """Keys of an optional table of numbers, checked against the known keys."""
    require_setting(isinstance(table, dict), f"[{name}]", table, "a table")
    _reject_unknown(f"{name}.", table, known)
    out = {}
    for key, value in table.items():
        whole = key == "bit_depth"
        out[key] = _integer(f"{name}.{key}", value) if whole else _number(f"{name}.{key}",
                                                                          value)
    return out


def _number(key: str, value: Any) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    require_setting(ok and math.isfinite(value), key, value, "a finite number")
    return float(value)


def _integer(key: str, value: Any) -> int:
    ok = isinstance(value, int) and not isinstance(value, bool)
    require_setting(ok, key, value, "a whole number")
    return int(value)


def _list(key: str, value: Any) -> list:
    require_setting(isinstance(value, list), key, value, "a list")
    return value


def _parse_set(fmt: str, index: int, table: Any) -> PhaseSet | GrayCodeSet | ReferenceSet:
    """One ``[[set]]`` table, with its storage (files or stack) checked."""
    where = f"set[{index}]"
    require_setting(isinstance(table, dict), where, table, "a table")
    kinds = _SET_KEYS[fmt]
    kind = table.get("kind")
    require_setting(kind in kinds, f"{where}.kind", kind, " or ".join(map(repr, kinds)))
    _reject_unknown(f"{where}.", table, kinds[kind])
    args = {k: v for k, v in table.items() if k != "kind"}
    args.setdefault("name", f"{kind}{index}")
    for key in ("name", "orientation", "stack", "stack_key", "orders", "threshold"):
        if key in args:
            require_setting(isinstance(args[key], str), f"{where}.{key}", args[key], "a string")
    pset = {"phase": _phase_set, "gray": _gray_set, "reference": _reference_set}[kind](
        where, args)
    _check_storage(where, pset, table)
    return pset


def _phase_set(where: str, args: dict) -> PhaseSet:
    require_setting("period_px" in args and "steps" in args, where, sorted(args),
             "a table with period_px and steps")
    args["period_px"] = _number(f"{where}.period_px", args["period_px"])
    args["steps"] = _integer(f"{where}.steps", args["steps"])
    args["shifts_rad"] = tuple(_number(f"{where}.shifts_rad", v)
                               for v in _list(f"{where}.shifts_rad",
                                              args.get("shifts_rad", [])))
    return PhaseSet(**args)


def _gray_set(where: str, args: dict) -> GrayCodeSet:
    require_setting("bits" in args, where, sorted(args), "a table with bits")
    args["bits"] = _integer(f"{where}.bits", args["bits"])
    if "cell_px" in args:
        args["cell_px"] = _number(f"{where}.cell_px", args["cell_px"])
    inverse = args.get("inverse", "none")
    require_setting(isinstance(inverse, (bool, str)), f"{where}.inverse", inverse,
             "true, false, 'none', 'grouped' or 'interleaved'")
    return GrayCodeSet(**args)


def _reference_set(where: str, args: dict) -> ReferenceSet:
    levels = _list(f"{where}.levels", args.get("levels", ["white", "black"]))
    args["levels"] = tuple(levels)
    return ReferenceSet(**args)


def _check_storage(where: str, pset: Any, table: dict) -> None:
    """Exactly one of files (with the right count) and stack."""
    has_files, has_stack = "files" in table, "stack" in table
    require_setting(has_files != has_stack, where, sorted(table),
             "a table with either files = [...] or stack = '...' (not both)")
    if has_files:
        files = _list(f"{where}.files", table["files"])
        require_setting(all(isinstance(f, str) for f in files), f"{where}.files", files,
                 "a list of file names")
        if len(files) != pset.frames:
            raise ConfigError(f"wrong count of files in {where} ({pset.name!r}): got "
                              f"{len(files)}, need {pset.frames} ({_frames_why(pset)})")
    elif "stack_key" in table and not pset.stack.lower().endswith(".npz"):
        raise ConfigError(f"{where}.stack_key is only meaningful with a .npz stack")


def _frames_why(pset: Any) -> str:
    """Why a set has the frame count it has, for the file-count message."""
    if isinstance(pset, PhaseSet):
        return f"steps = {pset.steps}"
    if isinstance(pset, ReferenceSet):
        return f"one per entry of levels = {list(pset.levels)}"
    inverse = f" x 2 (inverse = {pset.inverse!r})" if pset.inverse != "none" else ""
    return f"bits = {pset.bits}{inverse}"
