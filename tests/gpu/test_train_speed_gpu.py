"""The fast training path on a synthetic two-chart garment (no dataset, no body): the target cache serves
exactly what per-batch rendering gives (float16 images within their rounding), the DataModule builds and
uses it (and falls back when it would not fit), the cheaper vertex normals equal the reference formula
(values and gradients), a patch's normals need only its neighbourhood's faces, the step's losses are the
same with cached targets, bf16-mixed keeps the 3D path in float32, and the schedule presets compose."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers.run_if import run_if
from helpers.synthetic import FakeSkinner, batch_for, two_chart_garment
from helpers.train_speed_world import N, datamodule, targets


@pytest.fixture
def world(tmp_path):
    g = two_chart_garment(8)
    patch = SimpleNamespace(id=0, side=0, box_512=(51, 51, 170, 170),
                            vertices=np.array([8 * i + j for i in range(3) for j in range(3)]))
    b = batch_for(g, b=N, seed=1)
    ds = SimpleNamespace(garment=g, cage=SimpleNamespace(patches=[patch]), dir=tmp_path,
                         manifest={"garment_hash": "h"}, poses=b["pose"].reshape(N, -1).numpy(),
                         verts=b["verts"].numpy())
    return ds, FakeSkinner(g.vertices), b


@run_if(cuda=True)
def test_cache_on_cuda_equals_cpu_render(world):
    ds, sk, b = world
    for t in targets(ds, sk):
        dm = datamodule(ds, t)
        batch = next(iter(dm.train_dataloader()))
        got = dm.on_after_batch_transfer({k: v.cuda() for k, v in batch.items()}, 0)
        assert t.cache.device.type == "cuda"
        want = t.render(dict(batch))
        for k, v in want.items():
            torch.testing.assert_close(got[k].cpu(), v, rtol=1e-5, atol=1e-6)


@run_if(cuda=True)
@pytest.mark.parametrize("trainer", ["gpu", "ddp", "gpu_bf16"])
def test_gpu_trainers_run_end_to_end(tiny_dataset, tmp_path, trainer):
    """`trainer=gpu`, `trainer=ddp` (one device here: the DDP strategy and synced BatchNorm) and bf16-mixed
    train, test and write metrics on the session's tiny dataset, with the target cache on the GPU."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from conftest import tiny_overrides

    over = {"gpu": ["trainer=gpu"], "ddp": ["trainer=ddp", "trainer.devices=1"],
            "gpu_bf16": ["trainer=gpu", "trainer.precision=bf16-mixed"]}[trainer]
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "pbc.train", *tiny_overrides(tiny_dataset.parent), "+experiment=whole",
                        "+scale=smoke", *over, "trainer.max_epochs=2", f"hydra.run.dir={run}"],
                       cwd=Path(__file__).resolve().parents[2], env=dict(os.environ, PBC_ROOT=str(tmp_path)),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["status"] == "ok" and np.isfinite(metrics["test"]["vertex_error_cm"])
    assert "target cache" in r.stdout + r.stderr and "on cuda" in r.stdout + r.stderr
