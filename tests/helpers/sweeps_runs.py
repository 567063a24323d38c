"""Helpers shared by tests/unit/test_sweeps.py and tests/integration/test_sweeps_jobs.py."""

from __future__ import annotations

from pathlib import Path

from hydra import compose

import pbc.core.config  # noqa: F401  (registers the pbc.monitor resolver that conf/callbacks reads)

ROOT = Path(__file__).resolve().parents[2]


CONF = ROOT / "conf"


SCALES = sorted(p.stem for p in (CONF / "scale").glob("*.yaml"))


def _compose(overrides):
    return compose("config", overrides=overrides, return_hydra_config=True)
