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


def training_mean(pred: ClothPredictor) -> tuple[torch.Tensor, str]:
    """The training mean shape of `pred`'s data: (V, 3) offsets and their space (a shipped model's recorded mean,
    else its training split's, in the local frames)."""
    return recorded_mean_offsets(pred.dataset) or (mean_offsets(pred.dataset), "local")


def mean_shape(pred: ClothPredictor, poses: np.ndarray, mean: tuple[torch.Tensor, str] | None = None) -> torch.Tensor:
    """(N, V, 3) the training mean shape (`training_mean`, or `mean` as it returns) skinned onto poses (N, J, 3, 3),
    as the model's own output is."""
    p = torch.from_numpy(np.array(poses, np.float32))
    with torch.inference_mode():
        mean, space = training_mean(pred) if mean is None else mean
        anchors, frames = pred.frames(p)
        return from_offsets(mean.expand(len(p), -1, -1), anchors, frames, space)


def frame_errors(pred: ClothPredictor, poses: np.ndarray, drapes: np.ndarray, batch: int = 64
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame (N,) cm: the whole model's mean vertex error against drapes (N, V, 3) of poses (N, J, 3, 3), and the
    training mean shape's; and the model's positions (N, V, 3)."""
    model, base, positions = [], [], []
    mean = training_mean(pred)
    for s in range(0, len(poses), batch):
        p, v = np.array(poses[s:s + batch], np.float32), torch.from_numpy(np.array(drapes[s:s + batch], np.float32))
        with torch.inference_mode():
            x = pred(torch.from_numpy(p), model="whole")
        model.append(((x - v).norm(dim=-1).mean(1) * CM).numpy())
        base.append(((mean_shape(pred, p, mean) - v).norm(dim=-1).mean(1) * CM).numpy())
        positions.append(x.numpy())
    if not model:
        return np.zeros(0, np.float32), np.zeros(0, np.float32), np.zeros((0, *drapes.shape[1:]), np.float32)
    return np.concatenate(model), np.concatenate(base), np.concatenate(positions)
