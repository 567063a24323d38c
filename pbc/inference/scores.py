"""A model's error on drapes it never saw, beside the no-model baseline: the training mean shape (its recorded mean
offsets) skinned onto the same poses. Pure: predictor and arrays in, per-frame centimetres out."""

from __future__ import annotations

import numpy as np
import torch

from pbc.data.baselines import mean_offsets
from pbc.data.trimmed import recorded_mean_offsets
from pbc.inference.predictor import ClothPredictor
from pbc.pixels.frames import from_offsets

CM = 100.0


def mean_shape(pred: ClothPredictor, poses: np.ndarray) -> torch.Tensor:
    """(N, V, 3) the training mean shape of `pred`'s data (a shipped model's recorded mean offsets, else its
    training split's) skinned onto poses (N, J, 3, 3), as the model's own output is."""
    p = torch.from_numpy(np.array(poses, np.float32))
    with torch.inference_mode():
        mean, space = recorded_mean_offsets(pred.dataset) or (mean_offsets(pred.dataset), "local")
        anchors, frames = pred.frames(p)
        return from_offsets(mean.expand(len(p), -1, -1), anchors, frames, space)


def frame_errors(pred: ClothPredictor, poses: np.ndarray, drapes: np.ndarray, batch: int = 64
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame (N,) cm: the whole model's mean vertex error against drapes (N, V, 3) of poses (N, J, 3, 3), and the
    training mean shape's."""
    model, base = [], []
    for s in range(0, len(poses), batch):
        p, v = np.array(poses[s:s + batch], np.float32), torch.from_numpy(np.array(drapes[s:s + batch], np.float32))
        with torch.inference_mode():
            x = pred(torch.from_numpy(p), model="whole")
        model.append(((x - v).norm(dim=-1).mean(1) * CM).numpy())
        base.append(((mean_shape(pred, p) - v).norm(dim=-1).mean(1) * CM).numpy())
    empty = np.zeros(0, np.float32)
    return (np.concatenate(model) if model else empty), (np.concatenate(base) if base else empty)
