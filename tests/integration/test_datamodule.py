"""ClothDataModule on the session's real tiny dataset: batch shapes for whole and patch targets, splits,
per-batch rendering that decodes back to the draped vertices, clear errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

import pbc.data.datamodule as dmmod
from pbc.data.dataset import ClothDataset, load_dataset
from pbc.pixels.reconstruct import images_to_positions

ROOT = Path(__file__).resolve().parents[2]
IMAGE = OmegaConf.load(ROOT / "conf/image/default.yaml")


@pytest.fixture(scope="module")
def dataset(tiny_dataset) -> ClothDataset:
    return load_dataset(tiny_dataset)


@pytest.fixture
def dm_factory(dataset):
    def make(**kw):
        kw.setdefault("batch_size", 2)
        return dmmod.ClothDataModule(str(dataset.dir), IMAGE, **kw)

    return make


def test_whole_batch_shapes(dm_factory, dataset):
    dm = dm_factory(target="whole")
    dm.prepare_data()
    dm.setup("fit")
    for split in ("train", "val", "test"):
        assert len(dm.splits[split]) == len(dataset.split(split))
    batch = next(iter(dm.train_dataloader()))
    V = dataset.verts.shape[1]
    assert batch["pose"].shape == (2, 90) and batch["verts"].shape == (2, V, 3)
    out = dm.on_after_batch_transfer(batch, 0)
    assert out["image"].shape == (2, 6, 256, 256) and out["mask"].shape == (1, 6, 256, 256)
    assert out["anchors"].shape == (2, V, 3) and out["frames"].shape == (2, V, 3, 3)
    assert out["offsets"].shape == (2, V, 3)
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


def test_clear_errors(dm_factory, dataset, tmp_path):
    with pytest.raises(ValueError, match="unknown patch_id 28"):
        dm_factory(target="patch", patch_id=28).setup()
    with pytest.raises(ValueError, match="made for garment"):
        dm_factory(garment_hash="other").setup()
    with pytest.raises(ValueError, match="target"):
        dm_factory(target="vertices")
    with pytest.raises(FileNotFoundError, match="no dataset"):
        dmmod.ClothDataModule(str(tmp_path / "missing"), IMAGE).prepare_data()
    # non-finite data is refused when the DataModule opens the dataset (the whole-data check at open,
    # pbc.data.dataset.check_dataset), wherever the bad row is
    corrupt = tmp_path / "corrupt"
    shutil.copytree(dataset.dir, corrupt)
    bad = np.array(dataset.verts)
    bad[-1, 0, 0] = np.nan
    np.save(corrupt / "verts.npy", bad)
    with pytest.raises(ValueError, match="corrupt"):
        dmmod.ClothDataModule(str(corrupt), IMAGE).setup()
