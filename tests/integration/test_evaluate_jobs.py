"""Evaluation, the predictor and patch-run selection, on a stand-in dataset and 29 cheap checkpoints.

The stand-in dataset is the real coarse T-shirt and its cage with a "body" that is the garment shrunk
10% (no draping, seconds to build). The checkpoints are untrained narrow decoders saved in the
checkpoint layout `pbc.train` writes (hparams + `net.*` state dict) with a run dir's metrics.json,
so 28 patch runs cost nothing to make.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

import pbc.data.dataset as dsmod
from pbc.data.dataset import ClothDataset
from pbc.runs import RunRecord, monitor

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
    from pbc.geometry.body import Body
    from pbc.geometry.garment import load_garment_config, make_tshirt
    from pbc.geometry.skeleton import skeleton_from_config
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
    emb = type("Emb", (), {})()
    emb.face = torch.tensor([first[v][0] for v in range(V)])
    emb.bary = torch.eye(3)[[first[v][1] for v in range(V)]]
    emb.part = torch.zeros(V, dtype=torch.long)
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
             seed: int = 0) -> Path:
    """A run dir as `pbc.train` leaves it (metrics.json + checkpoints/epoch_000.ckpt), untrained weights."""
    from pbc.models.module import ClothModule

    torch.manual_seed(seed)
    size, start, out = ((160, 160), (5, 5), 3) if kind == "patch" else ((256, 256), (8, 8), 6)
    net = {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 90, "out_channels": out,
           "output_size": list(size), "start_size": list(start), "start_channels": 32,
           "first_layer": "linear" if kind == "patch" else "conv_transpose"}
    identity = {"garment_hash": garment_hash, "kind": kind, "patch_id": patch_id, "space": "local",
                "resolution": 512 if kind == "patch" else 256}
    m = ClothModule(net=net, kind=kind, space="local", loss={"norm": "l1", "normal_weight": 0.0,
                                                              "edge_weight": 0.0},
                    lr=1e-3, identity=identity, patch_id=patch_id).eval()
    with torch.no_grad():  # small outputs: untrained decoders give offsets of a few mm
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


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    ds = fake_dataset(root / "data" / "fake")
    whole = save_run(root / "runs" / "whole", ds.dir, "whole", None)
    for k in range(28):
        save_run(root / "runs" / "patches" / f"{k}_patch_{k:02d}", ds.dir, "patch", k, seed=k)
    return root, ds, whole


@pytest.fixture
def patched_load(world, monkeypatch):
    _, ds, _ = world
    monkeypatch.setattr(dsmod, "load_dataset", lambda d: ds)
    return ds


def _stitch_cfg(method="pca"):
    # every seam method shares average.yaml's keys and only sets `method`
    return OmegaConf.merge(OmegaConf.load(ROOT / "conf/stitch/average.yaml"), {"method": method})




def test_stacked_patch_net_matches_loop(world, patched_load):
    from pbc.predict import ClothPredictor, LoopPatchNet

    root, ds, whole = world
    pred = ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("average"))
    pose = torch.from_numpy(ds.poses[:3]).float()
    ref = LoopPatchNet(pred.patch_nets).eval()
    with torch.inference_mode():
        assert torch.allclose(pred.patch_crops(pose), ref(pose.reshape(3, -1)), atol=1e-5)
        x1 = pred(pose[0])
        xb = pred(pose)
    assert x1.shape == (ds.verts.shape[1], 3) and torch.allclose(x1, xb[0], atol=1e-5)
    # untrained heads give mm-size offsets: the garment sits on its skinned cloth pixels
    assert (xb - pred(pose, model="whole")).norm(dim=-1).max() < 0.05




def test_evaluate_writes_all_outputs(world, patched_load, tmp_path):
    from pbc.evaluate import evaluate

    root, ds, whole = world
    cfg = OmegaConf.create({"whole_run": str(whole), "patch_runs": str(root / "runs" / "patches"),
                            "methods": ["average", "pca", "inpaint", "hierarchy", "hierarchy_detail"], "split": "test",
                            "max_samples": None, "batch_size": 8, "num_previews": 2, "pca_path": None,
                            "pca_fit_max": 100, "stitch": _stitch_cfg("pca")})
    m = evaluate(cfg, tmp_path)
    for f in ("metrics.json", "metrics.md", "error_maps.png", "preview_0.png", "preview_1.png", "pca.pt"):
        assert (tmp_path / f).is_file(), f
    assert len(list((tmp_path / "meshes").glob("*.obj"))) == 6
    e = m["entries"]
    for name in ("whole", "train_mean", "floor_256", "floor_512", "patches_average", "patches_pca", "patches_inpaint",
                 "patches_hierarchy", "gt_crops_average", "gt_crops_inpaint"):
        assert np.isfinite(e[name]["vertex_error_cm"]), name
    # ground-truth crops through every seam method land on the representation floor
    floor = e["floor_512"]["vertex_error_cm"]
    assert e["train_mean"]["vertex_error_cm"] > floor + 0.1  # the no-model baseline is a real error
    for meth in ("average", "pca", "hierarchy", "hierarchy_detail"):
        assert e[f"gt_crops_{meth}"]["vertex_error_cm"] <= floor + 1e-3, meth
    assert e["gt_crops_inpaint"]["vertex_error_cm"] <= floor + 0.05
    assert m["patch_disagreement_before_blend_cm"] > 0
    # a basis from another dataset is refused
    torch.save({**torch.load(tmp_path / "pca.pt"), "dataset_hash": "x"}, tmp_path / "bad_pca.pt")
    cfg.pca_path = str(tmp_path / "bad_pca.pt")
    with pytest.raises(ValueError, match="fitted on dataset"):
        evaluate(cfg, tmp_path / "again")










@pytest.fixture(scope="module")
def predictor(world):
    """One predictor for the door tests (building one costs seconds)."""
    from pbc.predict import ClothPredictor

    root, ds, whole = world
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dsmod, "load_dataset", lambda d: ds)
        return ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("average"))




