"""Training losses on cloth images and on the 3D cloth they decode to (paper eq. 1-3, appendix F eq. 1).

Pure functions on batched tensors; the LightningModule combines them with weights from ``conf/loss/``.
The image loss compares images; the normal and edge losses compare geometry reconstructed from the
predicted image (image -> vertices -> 3D, differentiable, see ``pbc.pixels``), so their gradients
reach the network through that chain.
"""

from __future__ import annotations

import torch
from torch import Tensor

NORMS = ("l1", "l2")


def pixel_error(pred: Tensor, gt: Tensor, norm: str) -> Tensor:
    """Element-wise error: |pred - gt| for ``"l1"``, (pred - gt)^2 for ``"l2"``. Same shape as inputs."""
    if norm == "l1":
        return (pred - gt).abs()
    if norm == "l2":
        return (pred - gt).square()
    raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")


def image_loss(pred: Tensor, gt: Tensor, mask: Tensor, norm: str = "l1") -> Tensor:
    """Eq. 1: sum over garment pieces k of the mask-weighted mean per-pixel error, averaged over the batch.

    Args:
        pred, gt: (B, K*c, H, W) images; channels [k*c, (k+1)*c) belong to piece k (c = 3: du, dv, dn).
        mask: (K, H, W), (1, K, H, W) or (B, K, H, W) padded-UV masks W_k (bool or {0, 1} float);
            a patch model passes its crop mask with K = 1.
        norm: ``"l1"`` (per-pixel sum of |diff| over the piece's channels) or ``"l2"`` (sum of squares).
    Returns:
        scalar  sum_k [ sum_ij W_k(i,j) ||I_pd - I_gt||(i,j) / sum_ij W_k(i,j) ], mean over B.
    """
    b, ch, h, w = pred.shape
    if mask.dim() == 3:
        mask = mask[None]
    k = mask.shape[1]
    if ch % k:
        raise ValueError(f"{ch} image channels do not split into {k} mask pieces")
    err = pixel_error(pred, gt, norm).view(b, k, ch // k, h, w).sum(dim=2)  # (B, K, H, W)
    m = mask.to(err.dtype).expand(b, k, h, w)
    # clamp: an empty piece (cannot happen for valid crops) must not divide by zero
    per_piece = (err * m).sum(dim=(2, 3)) / m.sum(dim=(2, 3)).clamp_min(1.0)
    return per_piece.sum(dim=1).mean()


def vertex_value_loss(pred: Tensor, gt: Tensor, norm: str = "l1") -> Tensor:
    """Per-vertex analogue of eq. 1 for the fully connected baselines (no image, no mask).

    pred, gt (B, V, 3) -> scalar: mean over B, V of the per-vertex summed error.
    """
    return pixel_error(pred, gt, norm).sum(dim=-1).mean()


def normal_loss(n_pred: Tensor, n_gt: Tensor) -> Tensor:
    """Eq. 2: mean over batch and vertices of 1 - cos(n_pd, n_gt).

    n_pred, n_gt: (B, V, 3) vertex normals (re-normalised here, so unnormalised input is fine).
    Returns 0 for identical normals, up to 2 for opposite ones.
    """
    cos = torch.nn.functional.cosine_similarity(n_pred, n_gt, dim=-1, eps=1e-12)
    return (1.0 - cos).mean()


def edge_loss(len_pred: Tensor, len_gt: Tensor) -> Tensor:
    """Appendix F eq. 1: mean over batch and edges of |l_e^pd - l_e^gt|. Inputs (B, E) metres."""
    return (len_pred - len_gt).abs().mean()
