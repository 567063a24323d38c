"""Helpers shared by tests/unit/test_any_cage.py and tests/integration/test_any_cage_jobs.py."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]


SHIRT_PATCHES = 28


SMALL_IMAGES = ["image.whole_resolution=64", "image.patch_resolution=128"]


def _stitch_cfg(method: str = "average"):
    from pbc.inference.predictor import stitch_config

    return stitch_config(method)


def _smooth_field(rest: torch.Tensor, b: int = 2) -> torch.Tensor:
    """A smooth per-vertex offset field over rest positions (V, 3) -> (b, V, 3), different per sample."""
    basis = torch.cat([rest, rest ** 2], 1)  # (V, 6)
    coef = torch.linspace(-0.05, 0.05, b * 6 * 3).view(b, 6, 3)
    return torch.einsum("vk,bkc->bvc", basis, coef)


def _train(root: Path, overrides: list[str], data_dir: Path, name: str, *extra: str):
    """`python -m pbc.train <extra>` on the tube top's data with trainer=smoke, into <root>/any_cage/<name>
    -> (run dir, the finished process)."""
    run = root / "any_cage" / name
    # the garment overrides the data was made with: training refuses a dataset its config does not describe
    r = subprocess.run([sys.executable, "-m", "pbc.train", *overrides, "trainer=smoke", *SMALL_IMAGES,
                        f"data.dir={data_dir}", *extra, f"hydra.run.dir={run}"],
                       cwd=ROOT, env=dict(os.environ, PBC_ROOT=str(root)), capture_output=True, text=True,
                       timeout=600)
    return run, r


def _trained(root: Path, overrides: list[str], data_dir: Path, experiment: str) -> Path:
    run, r = _train(root, overrides, data_dir, experiment, f"+experiment={experiment}")
    assert r.returncode == 0, r.stderr[-3000:]
    return run
