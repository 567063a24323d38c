"""ClothDataModule: batch shapes for whole and patch targets, splits, per-batch rendering, clear errors.

Uses a stand-in dataset (the real coarse T-shirt and its cage, a "body" that is the garment shrunk
10%, random poses, verts = cloth pixels + small offsets) so it runs in seconds without draping.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

import pbc.data.datamodule as dmmod
from pbc.data.dataset import ClothDataset
from pbc.geometry.body import Body
from pbc.geometry.garment import make_tshirt
from pbc.geometry.skeleton import skeleton_from_config
from pbc.pixels.reconstruct import images_to_positions

ROOT = Path(__file__).resolve().parents[1]
IMAGE = OmegaConf.load(ROOT / "conf/image/default.yaml")
N = 10


def _rotations(n: int, j: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.3, 0.3, (n, j))
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((n, j, 3, 3), np.float32)
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1
    return R


@pytest.fixture(scope="module")
def fake_dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("ds")
    cfg = OmegaConf.create(
        {"garment": OmegaConf.load(ROOT / "conf/garment/tshirt_coarse.yaml"), "image": IMAGE}
    )
    garment, cage = make_tshirt(cfg.garment)
    skel = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
    V, J = garment.vertices.shape[0], len(skel.names)
    w = torch.zeros(V, J + 1)
    w[:, 0], w[:, 1] = 0.7, 0.3  # a gentle, smooth pose dependence
    body = Body(skel, garment.vertices * 0.9, garment.faces, w, torch.ones(3, V, dtype=torch.bool))
    faces = garment.faces.numpy()
    first = {}
    for f, tri in enumerate(faces):
        for k, v in enumerate(tri):
            first.setdefault(int(v), (f, k))
    face = torch.tensor([first[v][0] for v in range(V)])
    bary = torch.eye(3)[[first[v][1] for v in range(V)]]
    emb = type("Emb", (), {})()
    emb.face, emb.bary, emb.part = face, bary, torch.zeros(V, dtype=torch.long)
    poses = _rotations(N, J)
    from pbc.pixels.reconstruct import Skinner

    anchors, frames = Skinner(body, garment, emb)(torch.from_numpy(poses))
    verts = anchors + 0.01 * torch.randn(N, V, 3, generator=torch.Generator().manual_seed(0))
    np.save(d / "poses.npy", poses)
    np.save(d / "verts.npy", verts.numpy().astype(np.float32))
    manifest = {"garment_hash": "abc", "splits": {"train": list(range(8)), "val": [8], "test": [9]}}
    (d / "manifest.json").write_text("{}")  # prepare_data only looks for it
    data = ClothDataset(
        d,
        manifest,
        np.load(d / "poses.npy", mmap_mode="r"),
        np.load(d / "verts.npy", mmap_mode="r"),
        garment,
        cage,
        body,
        emb,
    )
    return data


@pytest.fixture
def dm_factory(fake_dataset, monkeypatch):
    monkeypatch.setattr(dmmod, "load_dataset", lambda d: fake_dataset)

    def make(**kw):
        kw.setdefault("batch_size", 4)
        return dmmod.ClothDataModule(str(fake_dataset.dir), IMAGE, **kw)

    return make


def test_whole_batch_shapes(dm_factory, fake_dataset):
    dm = dm_factory(target="whole")
    dm.prepare_data()
    dm.setup("fit")
    assert [len(dm.splits[s]) for s in ("train", "val", "test")] == [8, 1, 1]
    batch = next(iter(dm.train_dataloader()))
    V = fake_dataset.verts.shape[1]
    assert batch["pose"].shape == (4, 90) and batch["verts"].shape == (4, V, 3)
    out = dm.on_after_batch_transfer(batch, 0)
    assert out["image"].shape == (4, 6, 256, 256) and out["mask"].shape == (1, 6, 256, 256)
    assert out["anchors"].shape == (4, V, 3) and out["frames"].shape == (4, V, 3, 3)
    assert out["offsets"].shape == (4, V, 3)
    # the images decode back to the draped vertices (the representation floor, exact operators)
    pos = images_to_positions(out["image"], dm.ops, out["anchors"], out["frames"], "local")
    assert (pos - out["verts"]).abs().max() < 1e-5
    # images change with pose
    assert (out["image"][0] - out["image"][1]).abs().max() > 1e-4


def test_patch_batch_shapes(dm_factory):
    dm = dm_factory(target="patch", patch_id=7, space="root")
    dm.setup("fit")
    out = dm.on_after_batch_transfer(next(iter(dm.val_dataloader())), 0)
    assert out["image"].shape == (1, 3, 160, 160) and out["mask"].shape == (1, 3, 160, 160)
    assert out["mask"].sum() > 0
    vals = dm.ops.sample(out["image"])
    assert torch.allclose(vals, out["offsets"][:, out["vertices"]], atol=1e-6)


def test_clear_errors(dm_factory, fake_dataset, tmp_path):
    with pytest.raises(ValueError, match="unknown patch_id 28"):
        dm_factory(target="patch", patch_id=28).setup()
    with pytest.raises(ValueError, match="made for garment"):
        dm_factory(garment_hash="other").setup()
    with pytest.raises(ValueError, match="target"):
        dm_factory(target="vertices")
    with pytest.raises(FileNotFoundError, match="no dataset"):
        dmmod.ClothDataModule(str(tmp_path / "missing"), IMAGE).prepare_data()
    bad = np.array(fake_dataset.verts)
    bad[-1, 0, 0] = np.nan
    corrupt = ClothDataset(
        fake_dataset.dir,
        fake_dataset.manifest,
        fake_dataset.poses,
        bad,
        fake_dataset.garment,
        fake_dataset.cage,
        fake_dataset.body,
        fake_dataset.embedding,
    )
    dm = dm_factory()
    with pytest.raises(ValueError, match="corrupt"):
        dm._check(corrupt)
