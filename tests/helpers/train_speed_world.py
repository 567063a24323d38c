"""Helpers shared by tests/unit/test_train_speed.py and tests/gpu/test_train_speed_gpu.py."""

from __future__ import annotations

import numpy as np
import torch

from pbc.data.datamodule import ClothDataModule
from pbc.models.module import ClothModule
from pbc.pixels.target import make_target

IMAGE = {"whole_resolution": 32, "patch_resolution": 64, "reference_resolution": 512, "crop_size": 256,
         "margin": 16, "pad": 16, "exact_sample": True, "method": "gather"}


N = 7  # samples; caches are built 3 at a time so chunks (and a ragged last one) are exercised


def targets(ds, sk):
    return [make_target(ds, IMAGE, k, patch_id=0, skinner=sk) for k in ("whole", "patch", "fc")]


def reference_normals(p, faces):
    """The textbook formula: area-weighted face normals (torch.cross) summed at their corners."""
    q = p[:, faces]
    n_f = torch.cross(q[:, :, 1] - q[:, :, 0], q[:, :, 2] - q[:, :, 0], dim=-1)
    n = p.new_zeros(p.shape).index_add(1, faces.reshape(-1), n_f[:, :, None].expand(-1, -1, 3, -1)
                                       .reshape(p.shape[0], -1, 3))
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def datamodule(ds, t, **kw) -> ClothDataModule:
    """A ClothDataModule over the synthetic dataset: setup's loading is replaced by the objects it makes."""
    dm = ClothDataModule(str(ds.dir), IMAGE, target=t.kind, patch_id=t.patch_id, batch_size=3, **kw)
    dm.data, dm.target = ds, t
    dm.splits = {"train": np.array([0, 2, 3, 5]), "val": np.array([1, 6]), "test": np.array([4])}
    return dm


def module(t, normal_weight=0.01):
    res = t.image_size[0]
    net = {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 90,
           "out_channels": 6 if t.kind == "whole" else 3, "output_size": [res, res], "start_size": [8, 8],
           "start_channels": 32}
    m = ClothModule(net, t.kind, "local", {"norm": "l1", "normal_weight": normal_weight, "edge_weight": 0.1},
                    1e-3, {}, patch_id=t.patch_id)
    m.log_dict = lambda *a, **k: None
    return m.attach(t)
