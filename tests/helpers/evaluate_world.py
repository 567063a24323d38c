"""The stand-in world of the evaluation tests: the real coarse T-shirt on a shrunk-garment body, random
poses, smooth offsets, and cheap untrained run dirs (test_evaluate, predictor, view, pretrained, bench)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from pbc.core.runs import RunRecord, monitor
from pbc.data.dataset import ClothDataset
from pbc.geometry.shrinkwrap import Embedding

ROOT = Path(__file__).resolve().parents[2]


IMAGE = OmegaConf.load(ROOT / "conf/image/default.yaml")


N = 10


GARMENT_HASH = "fakegarment"


def _rotations(n: int, j: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.3, 0.3, (n, j))
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((n, j, 3, 3), np.float32)
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1
    return R


def fake_dataset(d: Path) -> ClothDataset:
    """Coarse T-shirt + cage, a shrunk-garment body, N random poses, smooth pose-dependent offsets."""
    from pbc.core.config import load_garment_config
    from pbc.geometry.body.base import Body
    from pbc.geometry.body.skeleton import skeleton_from_config
    from pbc.geometry.garment.tshirt import make_tshirt
    from pbc.pixels.reconstruct import Skinner

    garment, cage = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt_coarse.yaml"))
    skel = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
    V, J = garment.vertices.shape[0], len(skel.names)
    w = torch.zeros(V, J + 1)
    w[:, 0], w[:, 1] = 0.7, 0.3
    body = Body(skel, garment.vertices * 0.9, garment.faces, w, torch.ones(3, V, dtype=torch.bool))
    first: dict[int, tuple[int, int]] = {}
    for f, tri in enumerate(garment.faces.numpy()):
        for k, v in enumerate(tri):
            first.setdefault(int(v), (f, k))
    emb = Embedding(face=torch.tensor([first[v][0] for v in range(V)]),
                    bary=torch.eye(3)[[first[v][1] for v in range(V)]], part=torch.zeros(V, dtype=torch.long))
    poses = _rotations(N, J)
    anchors, frames = Skinner(body, garment, emb)(torch.from_numpy(poses))
    # smooth offsets (a low-order field over the rest shape), so PCA and inpainting see cloth-like data
    rest = garment.vertices
    coef = torch.from_numpy(poses[:, :3].reshape(N, -1)[:, :8]).float()
    field = torch.einsum("nk,vk->nv", coef, torch.cat([rest, rest ** 2, rest[:, :1] * rest[:, 1:]], 1))
    verts = anchors + 0.02 * field[..., None] * torch.tensor([1.0, 0.5, -0.7])
    d.mkdir(parents=True, exist_ok=True)
    np.save(d / "poses.npy", poses)
    np.save(d / "verts.npy", verts.numpy().astype(np.float32))
    manifest = {"format_version": 1, "garment_hash": GARMENT_HASH, "counts": {"kept": N},
                "splits": {"train": list(range(7)), "val": [7], "test": [8, 9]}}
    (d / "manifest.json").write_text(json.dumps(manifest))
    return ClothDataset(d, manifest, np.load(d / "poses.npy", mmap_mode="r"),
                        np.load(d / "verts.npy", mmap_mode="r"), garment, cage, body, emb)


def save_run(run: Path, data_dir: Path, kind: str, patch_id: int | None, garment_hash: str = GARMENT_HASH,
             seed: int = 0, num_vertices: int | None = None) -> Path:
    """A run dir as `pbc.train` leaves it (metrics.json + checkpoints/epoch_000.ckpt), untrained weights.
    kind "fc": a fully connected PCA net of `num_vertices` vertices with a random orthonormal 8-component
    basis (as if fitted: outputs of about a centimetre)."""
    from pbc.models.module import ClothModule

    torch.manual_seed(seed)
    size, start, out = ((160, 160), (5, 5), 3) if kind == "patch" else ((256, 256), (8, 8), 6)
    net = {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 90, "out_channels": out,
           "output_size": list(size), "start_size": list(start), "start_channels": 32,
           "first_layer": "linear" if kind == "patch" else "conv_transpose"}
    if kind == "fc":
        net = {"_target_": "pbc.models.fc.FCNet", "in_features": 90, "num_vertices": int(num_vertices),
               "hidden": [32, 32], "mode": "pca", "num_components": 8}
    identity = {"garment_hash": garment_hash, "kind": kind, "patch_id": patch_id, "space": "local",
                "resolution": 512 if kind == "patch" else 256}
    m = ClothModule(net=net, kind=kind, space="local", loss={"norm": "l1", "normal_weight": 0.0,
                                                              "edge_weight": 0.0},
                    lr=1e-3, identity=identity, patch_id=patch_id).eval()
    with torch.no_grad():  # small outputs: untrained decoders give offsets of a few mm
        if kind == "fc":
            q, _ = torch.linalg.qr(torch.randn(3 * int(num_vertices), 8))
            m.net.set_pca(torch.zeros(3 * int(num_vertices)), q.T.contiguous(), torch.full((8,), 1.0))
        else:
            m.net.head.weight.mul_(0.01)
            m.net.head.bias.zero_()
    ck = run / "checkpoints" / "epoch_000.ckpt"
    ck.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"hyper_parameters": dict(m.hparams), "state_dict": m.state_dict()}, ck)
    config = {"data": {"dir": str(data_dir)}, "paths": {"data_dir": str(data_dir.parent)},
              "image": OmegaConf.to_container(IMAGE)}
    RunRecord(kind=kind, optimized_metric=monitor(kind), best_checkpoint=str(ck), identity=identity,
              config=config).write(run)
    return run


def _stitch_cfg(method="pca"):
    # every seam method shares average.yaml's keys and only sets `method`
    return OmegaConf.merge(OmegaConf.load(ROOT / "conf/stitch/average.yaml"), {"method": method})
