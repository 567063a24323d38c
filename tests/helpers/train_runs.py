"""Helpers of the training tests (tests/unit/test_train*.py, test_faults.py, test_reliability.py and
tests/integration/test_train_jobs.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import lightning as L
import torch
from conftest import TINY_SAMPLES

import pbc.jobs.train as pbc_train
from helpers.synthetic import FakeSkinner, two_chart_garment
from pbc.models.module import ClothModule
from pbc.pixels.operators import ImageOperators
from pbc.pixels.target import WholeTarget

ROOT = Path(__file__).resolve().parents[2]


CONF = ROOT / "conf"


def whole_module(norm="l1", normal_weight=0.01, res=32):
    g = two_chart_garment()
    ops = ImageOperators.for_garment(g, res, pad=2)
    net = {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 90, "out_channels": 6,
           "output_size": [res, res], "start_size": [8, 8], "start_channels": 64}
    ident = {"garment_hash": "g", "num_vertices": len(g.vertices), "kind": "whole", "resolution": res,
             "patch_id": None, "space": "local"}
    m = ClothModule(net, "whole", "local", {"norm": norm, "normal_weight": normal_weight, "edge_weight": 0.1},
                    1e-3, ident)
    return m.attach(WholeTarget(FakeSkinner(g.vertices), g.faces, ops, "local")), g


def _group_options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


TINY = ["data=tshirt_tiny", f"data.num_samples={TINY_SAMPLES}", "trainer=smoke", "image.whole_resolution=64",
        "image.patch_resolution=128",
        "callbacks.image_panel.every_n_epochs=1"]


def _train(root: Path, data_dir: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PBC_ROOT=str(root))
    return subprocess.run([sys.executable, "-m", "pbc.train", *TINY, f"data.dir={data_dir}", *args], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=300)


class ReachedTheData(Exception):
    """Raised where pbc.jobs.train.train would open the dataset: every door check before it ran."""


def stop_training_at_data(monkeypatch) -> None:
    """Make train() stop with ReachedTheData where it would build the DataModule (the doors' tests)."""
    def datamodule(cfg):
        raise ReachedTheData

    monkeypatch.setattr(pbc_train, "datamodule", datamodule)


class ScriptedModule(L.LightningModule):
    """A linear model fitted on `4 * batches` fixed random points (batches of 4) whose monitored
    val/vertex_error_cm is scripted per epoch: `val[epoch]`, or 10 - epoch when `val` is None, so the best epoch
    is known. The fault and checkpoint tests' stand-in for a ClothModule: a real Lightning fit in a second."""

    def __init__(self, val: Sequence[float] | None = None, batches: int = 2):
        super().__init__()
        self.lin = torch.nn.Linear(2, 1)
        self.val, self.batches = (None if val is None else list(val)), int(batches)

    def training_step(self, batch, _):
        x, y = batch
        return torch.nn.functional.mse_loss(self.lin(x), y)

    def validation_step(self, batch, _):
        self.log("val/vertex_error_cm", float(10 - self.current_epoch if self.val is None
                                              else self.val[self.current_epoch]))

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.01)

    def train_dataloader(self):
        x = torch.randn(4 * self.batches, 2, generator=torch.Generator().manual_seed(0))
        return torch.utils.data.DataLoader(torch.utils.data.TensorDataset(x, x.sum(1, keepdim=True)), batch_size=4)

    def val_dataloader(self):
        return self.train_dataloader()
