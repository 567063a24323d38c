"""Evaluation metrics reported in train/val/test logs and metrics.json (paper Table 1 and Table 2).

Pure functions on batched tensors. ``vertex_ids`` restricts a metric to a subset of vertices (a patch
model is scored over the vertices inside its patch only).
"""

from __future__ import annotations

from torch import Tensor

from pbc.models.losses import normal_loss

CM_PER_M = 100.0


def _subset(x: Tensor, vertex_ids: Tensor | None) -> Tensor:
    return x if vertex_ids is None else x[:, vertex_ids]


def vertex_error_cm(pred: Tensor, gt: Tensor, vertex_ids: Tensor | None = None) -> Tensor:
    """Mean per-vertex Euclidean position error in centimetres. pred, gt (B, V, 3) metres -> scalar."""
    d = _subset(pred, vertex_ids) - _subset(gt, vertex_ids)
    return d.norm(dim=-1).mean() * CM_PER_M


def vertex_error_cm_per_pose(pred: Tensor, gt: Tensor, vertex_ids: Tensor | None = None) -> Tensor:
    """Each pose's mean per-vertex Euclidean error in centimetres. pred, gt (B, V, 3) metres -> (B,)."""
    d = _subset(pred, vertex_ids) - _subset(gt, vertex_ids)
    return d.norm(dim=-1).mean(-1) * CM_PER_M


def normal_cosine_distance(n_pred: Tensor, n_gt: Tensor, vertex_ids: Tensor | None = None) -> Tensor:
    """Mean unit-normal cosine distance 1 - cos (as Table 1). n_pred, n_gt (B, V, 3) -> scalar."""
    return normal_loss(_subset(n_pred, vertex_ids), _subset(n_gt, vertex_ids))
