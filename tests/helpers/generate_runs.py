"""Helpers shared by tests/unit/test_generate.py and tests/integration/test_generate_jobs.py."""

from __future__ import annotations

from pathlib import Path

from conftest import tiny_overrides

from pbc.core.config import load_config

ROOT = Path(__file__).resolve().parents[2]


def tiny_cfg(data_dir: Path, *extra: str):
    return load_config(tiny_overrides(data_dir, *extra))
