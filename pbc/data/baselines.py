"""The no-model baseline: every pose gets the training split's mean offsets (the "training mean shape").

A model's vertex error means little alone; beside this number it says how much the network learnt beyond
the average drape. The main job's closing table, the wrong-body study and the whole-model evaluation
report it next to the models.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pbc.data.dataset import ClothDataset, person_kw
from pbc.pixels.frames import from_offsets, to_offsets
from pbc.pixels.target import make_target

CM = 100.0


def _chunks(ds: ClothDataset, skin, name: str, batch: int):
    """(verts, anchors, frames) of split `name` in batches, skinned by `skin`."""
    idx = ds.split(name)
    for s in range(0, len(idx), batch):
        j = idx[s:s + batch]
        pose = torch.from_numpy(np.asarray(ds.poses[j], np.float32))
        verts = torch.from_numpy(np.asarray(ds.verts[j], np.float32))
        anchors, frames = skin(pose, **person_kw(ds, j))
        yield verts, anchors, frames


def mean_offsets(ds: ClothDataset, batch: int = 64, skin=None) -> torch.Tensor:
    """(V, 3) float32: the training split's mean offsets in the local frames (the space the whole model predicts),
    skinned by `skin` (None: the dataset's own skinner). ValueError for a dataset without training samples."""
    if skin is None:
        skin = make_target(ds, None, "fc").skinner  # per-vertex offsets: the skinner, no image operators
    total, count = None, 0
    with torch.inference_mode():
        for v, a, f in _chunks(ds, skin, "train", batch):
            off = to_offsets(v, a, f).sum(0, dtype=torch.float64)
            total = off if total is None else total + off
            count += len(v)
    if not count:
        raise ValueError(f"dataset {ds.dir} has no training samples: no mean shape to compare with")
    return (total / count).float()


def mean_shape_errors(ds: ClothDataset, splits: Sequence[str] = ("train", "test"),
                      vertices: np.ndarray | None = None, batch: int = 64) -> dict[str, float]:
    """Mean vertex error (cm) of the training mean shape on each split: {split: cm}.

    vertices: (n,) garment vertex ids to score over (a patch model's patch); None = every vertex.
    The mean is taken of the offsets in the local frames (the space the whole model predicts), then skinned
    with each pose, so it follows the body like a model's output does.
    """
    skin = make_target(ds, None, "fc").skinner  # per-vertex offsets: the skinner, no image operators
    keep = slice(None) if vertices is None else torch.as_tensor(np.asarray(vertices), dtype=torch.long)
    mean = mean_offsets(ds, batch, skin)[None]
    out = {}
    with torch.inference_mode():
        for name in splits:
            err, n = 0.0, 0
            for v, a, f in _chunks(ds, skin, name, batch):
                pred = from_offsets(mean.expand(len(v), -1, -1), a, f)
                err += float((pred - v)[:, keep].norm(dim=-1).mean(1).sum())
                n += len(v)
            out[name] = err / n * CM if n else float("nan")
    return out
