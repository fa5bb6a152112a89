"""What a signed report states about where its numbers come from: the header block.

Date, scanqa version, the scanner config (name and a hash of its content, so that two
reports can be seen to rest on the same config), the calibration table (file and a hash
of its bytes, or what the cloud's metadata records of it), the artefact certificate
(the spec file and its hash), the data and the operator's name and notes from the
command line. Hashes are the first 12 hex digits of SHA-256.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from scanqa._version import __version__
from scanqa.errors import InputError

#: Hex digits of SHA-256 a header shows [-].
HASH_DIGITS = 12


@dataclass(frozen=True)
class ReportHeader:
    """The header block of a report (every field a display string)."""

    date: str
    version: str
    config: str
    config_hash: str
    table: str
    table_hash: str
    certificate: str
    data: str
    operator: str
    notes: str

    @property
    def report_id(self) -> str:
        """``SQA-`` and a hash of every field: the same inputs, date and operator give the
        same id, and any change gives another."""
        fields = {k: getattr(self, k) for k in self.__dataclass_fields__}
        return f"SQA-{content_hash(fields)}"

    def items(self) -> list[tuple[str, str]]:
        """(label, value) pairs in display order."""
        return [("Report id", self.report_id), ("Date", self.date),
                ("scanqa version", self.version),
                ("Scanner config", f"{self.config} (sha256 {self.config_hash})"
                 if self.config_hash else self.config),
                ("Calibration", f"{self.table} (sha256 {self.table_hash})"
                 if self.table_hash else self.table),
                ("Artefact certificate", self.certificate), ("Data", self.data),
                ("Operator", self.operator), ("Notes", self.notes)]

    def row(self) -> dict:
        return {label: value for label, value in self.items()}


def file_hash(path: str | os.PathLike) -> str:
    """First :data:`HASH_DIGITS` hex digits of the SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    except OSError as err:
        raise InputError(f"cannot read {path} to record its hash: {err.strerror}") from None
    return digest.hexdigest()[:HASH_DIGITS]


def content_hash(data: dict) -> str:
    """Hash of a plain dict's canonical JSON (keys sorted): the same config gives the
    same hash whichever file or cloud it came from."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:HASH_DIGITS]


def _config_text(config: dict | None, source: str) -> tuple[str, str]:
    if not config:
        return "not recorded (a cloud without scanqa metadata and no --config)", ""
    name = str(config.get("name", "")) or "unnamed"
    return (f"{name} ({source})" if source else name), content_hash(config)


def _table_text(table_path: str | None, cloud_table: dict | None) -> tuple[str, str]:
    if table_path:
        return str(table_path), file_hash(table_path)
    if cloud_table:
        parts = [f"{k} {v}" for k, v in cloud_table.items() if v not in ("", None)]
        return "as recorded in the cloud: " + ", ".join(parts), ""
    return "not recorded", ""


def report_time() -> datetime.datetime:
    """The date of a report: ``SOURCE_DATE_EPOCH`` (seconds since 1970, UTC) when set,
    for reproducible reports (https://reproducible-builds.org/specs/source-date-epoch/),
    else now in local time with its offset."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if epoch.isdigit() and int(epoch) < 253402300800:  # before the year 10000
        return datetime.datetime.fromtimestamp(int(epoch), datetime.timezone.utc)
    return datetime.datetime.now().astimezone()


def build_header(config: dict | None = None, config_source: str = "",
                 table_path: str | None = None, cloud_table: dict | None = None,
                 certificate: str = "", spec_path: str | None = None,
                 data: str = "", operator: str | None = None, notes: str | None = None,
                 when: datetime.datetime | None = None) -> ReportHeader:
    """The header block of a report.

    Parameters
    ----------
    config : dict, optional
        The scanner config as a plain dict (``ScannerConfig.to_dict()`` or a cloud's
        ``metadata["config"]``).
    config_source : str
        Where it was read from (file and profile).
    table_path : str, optional
        The calibration table file given on the command line (hashed).
    cloud_table : dict, optional
        What the cloud's metadata records of its table, when no file was given.
    certificate : str
        The artefact certificate in words (spec name, certified values).
    spec_path : str, optional
        The spec file (hashed).
    data : str
        The scans or clouds evaluated.
    operator, notes : str, optional
        From the command line.
    when : datetime, optional
        Date and time of the report (default now, local time with its offset).
    """
    when = when or report_time()
    cfg, cfg_hash = _config_text(config, config_source)
    table, table_hash = _table_text(table_path, cloud_table)
    cert = certificate or "none given"
    if spec_path:
        cert = f"{cert} ({spec_path}, sha256 {file_hash(spec_path)})"
    return ReportHeader(when.strftime("%Y-%m-%d %H:%M %z").strip(), __version__, cfg, cfg_hash,
                        table, table_hash, cert, data or "not recorded",
                        operator or "not given (--operator)", notes or "none")


def describe_paths(paths) -> str:
    """Short text naming the inputs (the first three and a count)."""
    names = [Path(p).name or str(p) for p in paths]
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def certificate_text(spec) -> str:
    """The certified values of a spec (:class:`scanqa.io.spec.Spec`) in words."""
    if spec is None:
        return ""
    parts = []
    if spec.sphere is not None:
        c = spec.sphere
        parts.append(f"sphere D = {c.diameter_mm:.4f} mm, U = {c.diameter_uncertainty_um:g} um "
                     f"(k = {c.k:g})" + (f", form {c.form_um:g} um" if c.form_um is not None
                                          else ""))
    if spec.ball_bar is not None:
        c = spec.ball_bar
        parts.append(f"ball bar L = {c.distance_mm:.4f} mm, U = "
                     f"{c.distance_uncertainty_um:g} um (k = {c.k:g})")
    if spec.flat is not None:
        parts.append(f"flat, flatness {spec.flat.flatness_um:g} um")
    return f"{spec.name}: " + ("; ".join(parts) if parts else "no certificate")
