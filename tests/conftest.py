"""Shared fixtures: the paper's scanner config."""

from __future__ import annotations

from pathlib import Path

import pytest

from scanqa.model.config import ScannerConfig, load_config

ROOT = Path(__file__).resolve().parents[1]
PAPER_CONFIG = ROOT / "calib" / "paper_scanner.toml"


@pytest.fixture(scope="session")
def paper_config() -> ScannerConfig:
    """calib/paper_scanner.toml at f/8 (the set-up of Tables 1 and 2)."""
    return load_config(PAPER_CONFIG)


def paper_config_text() -> str:
    """calib/paper_scanner.toml's text for a copy written elsewhere: the characterisation
    file its characterised_by names given by absolute path (a copy's folder lacks it)."""
    evidence = ROOT / "calib" / "paper_scanner_fig3.json"
    return PAPER_CONFIG.read_text().replace('characterised_by = "paper_scanner_fig3.json',
                                            f'characterised_by = "{evidence}')
