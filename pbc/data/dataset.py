"""Read a finished dataset directory (written by `pbc.data.generate`): memory-mapped arrays plus geometry.

Layout (see docs/interfaces.md):
    manifest.json   format version, seed, hashes, counts, splits
    garment.obj     garment with UV charts;  cage.json  its 28 patches
    body.npz        body mesh, skinning weights, parts, skeleton
    embedding.npz   body triangle + barycentric weights + collision part of every garment vertex
    poses.npy       (N, J, 3, 3) float32 joint rotations of the kept samples
    verts.npy       (N, V, 3) float32 draped garment vertices (root frame, metres)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pbc.geometry.body import Body, load_body
from pbc.geometry.cage import Cage, load_cage
from pbc.geometry.garment import Garment, load_garment_obj
from pbc.geometry.shrinkwrap import Embedding
from pbc.io import atomic_path, load_npy, read_json

FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")


@dataclass
class ClothDataset:
    """A dataset on disk. Arrays are memory-mapped: indexing them reads only what is used."""

    dir: Path
    manifest: dict
    poses: np.ndarray  # (N, J, 3, 3)
    verts: np.ndarray  # (N, V, 3)
    garment: Garment
    cage: Cage
    body: Body
    embedding: Embedding

    def __len__(self) -> int:
        return len(self.poses)

    def split(self, name: str) -> np.ndarray:
        """Sample indices of split `name` ('train', 'val' or 'test')."""
        if name not in SPLITS:
            raise ValueError(f"unknown split {name!r}; choose one of {SPLITS}")
        return np.asarray(self.manifest["splits"][name], dtype=np.int64)


def save_embedding(emb: Embedding, path: str | Path) -> None:
    """Write the embedding to .npz, atomically."""
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, face=emb.face.numpy(), bary=emb.bary.numpy(), part=emb.part.numpy())


def load_embedding(path: str | Path) -> Embedding:
    """Read an embedding written by `save_embedding`, with a clear error when missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"embedding not found: {path}")
    try:
        with np.load(path) as z:
            return Embedding(
                face=torch.from_numpy(z["face"]).long(),
                bary=torch.from_numpy(z["bary"]).float(),
                part=torch.from_numpy(z["part"]).long(),
            )
    except (KeyError, ValueError, OSError) as err:
        raise ValueError(f"embedding {path} is corrupt ({err}); regenerate the dataset") from err


def load_dataset(directory: str | Path) -> ClothDataset:
    """Open the dataset in `directory`, checking it is complete and self-consistent."""
    d = Path(directory)
    manifest_path = d / "manifest.json"
    if not manifest_path.is_file():
        hint = " (generation is unfinished: re-run `python -m pbc.generate` to resume)" if (d / "work").exists() else ""
        raise FileNotFoundError(f"no dataset at {d}: {manifest_path.name} is missing{hint}")
    manifest = read_json(manifest_path, "dataset manifest")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"dataset {d} has format version {manifest.get('format_version')}, this pbc reads {FORMAT_VERSION}; "
            "regenerate it with `python -m pbc.generate`"
        )
    garment = load_garment_obj(d / "garment.obj")
    cage = load_cage(d / "cage.json", garment)
    body = load_body(d / "body.npz")
    emb = load_embedding(d / "embedding.npz")
    n, v, j = manifest["counts"]["kept"], garment.vertices.shape[0], len(body.skeleton.names)
    poses = load_npy(d / "poses.npy", shape=(n, j, 3, 3))
    verts = load_npy(d / "verts.npy", shape=(n, v, 3))
    if emb.face.shape[0] != v:
        raise ValueError(f"embedding in {d} has {emb.face.shape[0]} vertices, the garment {v}; regenerate the dataset")
    return ClothDataset(d, manifest, poses, verts, garment, cage, body, emb)
