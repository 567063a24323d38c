"""Dataset generation: a finished tiny dataset, resume after a kill, shards, refusals of bad input."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.generate_runs import tiny_cfg

from pbc.data.dataset import load_dataset

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def reference(tiny_dataset: Path) -> Path:
    """The session's uninterrupted run (2 workers), the yardstick for the resumed and sharded ones."""
    return tiny_dataset


def test_missing_dataset_names_the_fix(tmp_path: Path):
    with pytest.raises(FileNotFoundError, match="manifest.json is missing"):
        load_dataset(tmp_path)


def test_split_sizes_never_leave_a_split_empty():
    from pbc.data.generate import split_sizes

    assert split_sizes(20011) == (16009, 2001)
    for n in range(3, 40):
        n_train, n_val = split_sizes(n)
        assert n_train >= 1 and n_val >= 1 and n - n_train - n_val == n_val


def test_user_garment_goes_through_the_same_door(tmp_path: Path):
    """An OBJ with UVs plus a cage file (what the procedural generator writes) gives the same garment."""
    import torch

    from pbc.data.generate import garment_from_config
    from pbc.geometry.cage.base import save_cage
    from pbc.geometry.garment.base import save_garment_obj

    procedural, cage = garment_from_config(tiny_cfg(tmp_path).garment)
    save_garment_obj(procedural, tmp_path / "shirt.obj")
    save_cage(cage, tmp_path / "cage.json")
    cfg = tiny_cfg(tmp_path, f"garment.obj={tmp_path / 'shirt.obj'}", f"garment.cage={tmp_path / 'cage.json'}")
    garment, loaded = garment_from_config(cfg.garment)
    assert torch.equal(garment.faces, procedural.faces) and torch.allclose(garment.uv, procedural.uv)
    assert [p.vertices.tolist() for p in loaded.patches] == [p.vertices.tolist() for p in cage.patches]
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="bad.obj"):
        garment_from_config(tiny_cfg(tmp_path, f"garment.obj={tmp_path / 'bad.obj'}").garment)
