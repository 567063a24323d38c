"""Place the P patch crops (one per cage patch) back into the full cloth images, with feathered blending.

One job: turn per-patch crops `(B, P, 3, h, w)` into the two-sided cloth image `(B, 6, H, W)` (or
straight into per-vertex values with a sampling operator folded in). Every covered pixel gets exactly
one value: where crops overlap (their context margins and neighbouring patches) they are blended
with weights that fall to zero toward each crop's edge and are normalised to sum to 1.

Everything here is generic over tensors: windows, sides and crop masks come from the pixels stage
(`pbc.pixels.operators`), but nothing in this module needs a garment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage
from torch import Tensor


def feather_weights(crop_masks: Tensor, ramp: float) -> Tensor:
    """Per-crop blending weights that fall linearly to zero toward the crop's edge.

    crop_masks: (P, h, w) bool, the pixels a crop is trusted on (its patch dilated by the margin,
        inside the padded chart). ramp: pixels over which the weight rises from ~0 to 1.
    Returns (P, h, w) float32: min(1, d / (ramp + 1)) with d the Euclidean distance (>= 1 inside) to
    the nearest pixel outside the mask or outside the crop window; 0 outside the mask.
    The weight is strictly positive on the mask, so a pixel only one crop covers still gets a value.
    """
    m = crop_masks.detach().cpu().numpy().astype(bool)
    out = np.zeros(m.shape, np.float32)
    for p in range(m.shape[0]):
        # pad with False so the window border counts as "outside": the weight must reach ~0 at the
        # crop edge, not just at the mask edge
        d = ndimage.distance_transform_edt(np.pad(m[p], 1))[1:-1, 1:-1]
        out[p] = np.minimum(1.0, d / (ramp + 1.0))
    return torch.from_numpy(out)


def _window_origins(windows: Tensor) -> Tensor:
    """(P, 2) or (P, 4) windows (row0, col0[, row1, col1]) -> (P, 2) long origins."""
    w = torch.as_tensor(windows)
    if w.ndim != 2 or w.shape[1] not in (2, 4):
        raise ValueError(f"windows must be (P, 2) or (P, 4) (row0, col0[, row1, col1]), got {tuple(w.shape)}")
    return w[:, :2].long()


def _flat_targets(windows: Tensor, sides: Tensor, crop_hw: tuple[int, int], size: tuple[int, int]):
    """Flat target index of every crop pixel in a (2, H, W) image, and whether it is inside it.

    Returns (P, h, w) long indices into 2*H*W (clamped where outside) and (P, h, w) bool inside.
    """
    h, w = crop_hw
    H, W = size
    org = _window_origins(windows)
    rows = org[:, 0, None, None] + torch.arange(h)[None, :, None]
    cols = org[:, 1, None, None] + torch.arange(w)[None, None, :]
    inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
    side = torch.as_tensor(sides).long()[:, None, None]
    flat = side * H * W + rows.clamp(0, H - 1) * W + cols.clamp(0, W - 1)
    return flat, inside


def blend_weights(weights: Tensor, windows: Tensor, sides: Tensor, size: tuple[int, int]) -> Tensor:
    """Normalise per-crop weights so that, at every pixel any crop covers, they sum to 1.

    weights: (P, h, w) non-negative (e.g. `feather_weights`); windows: (P, 2|4) crop origins in the
    full image; sides: (P,) 0 front / 1 back; size: (H, W) of one side.
    Returns (P, h, w) float32; zero where the raw weight is zero or the pixel is outside the image.
    """
    P, h, w = weights.shape
    flat, inside = _flat_targets(windows, sides, (h, w), size)
    wt = weights.float() * inside
    total = torch.zeros(2 * size[0] * size[1]).index_add_(0, flat.reshape(-1), wt.reshape(-1))
    denom = total[flat]
    return torch.where(denom > 0, wt / denom.clamp_min(1e-12), torch.zeros_like(wt))


@dataclass
class Assembler:
    """Sparse "crops -> image" map: out[dst[k]] += weight[k] * crops_flat[src[k]] per channel.

    src: (N,) long into P*h*w; dst: (N,) long into 2*H*W; weight: (N,) float32 (normalised blend);
    crop_hw, size: crop and image sizes. Build once per garment with `Assembler.build`.
    """

    src: Tensor
    dst: Tensor
    weight: Tensor
    num_crops: int
    crop_hw: tuple[int, int]
    size: tuple[int, int]

    @classmethod
    def build(cls, weights: Tensor, windows: Tensor, sides: Tensor, size: tuple[int, int]) -> Assembler:
        """weights: (P, h, w) raw per-crop weights (normalised here); windows (P, 2|4); sides (P,)."""
        P, h, w = weights.shape
        norm = blend_weights(weights, windows, sides, size)
        flat, _ = _flat_targets(windows, sides, (h, w), size)
        keep = norm.reshape(-1) > 0
        src = torch.nonzero(keep).squeeze(1)
        return cls(src, flat.reshape(-1)[keep], norm.reshape(-1)[keep], P, (h, w), tuple(size))

    def to(self, device) -> Assembler:
        return Assembler(self.src.to(device), self.dst.to(device), self.weight.to(device),
                         self.num_crops, self.crop_hw, self.size)

    def coverage(self) -> Tensor:
        """(2, H, W) bool: pixels at least one crop covers (with non-zero weight)."""
        H, W = self.size
        cov = torch.zeros(2 * H * W, dtype=torch.bool, device=self.dst.device)
        cov[self.dst] = True
        return cov.view(2, H, W)

    def images(self, crops: Tensor) -> Tensor:
        """crops: (B, P, C, h, w) -> (B, 2*C, H, W); channels of side s are [s*C, (s+1)*C)."""
        B, P, C, h, w = crops.shape
        if (P, (h, w)) != (self.num_crops, self.crop_hw):
            raise ValueError(f"crops {tuple(crops.shape)} do not match the assembler "
                             f"({self.num_crops} crops of {self.crop_hw})")
        H, W = self.size
        vals = crops.permute(0, 2, 1, 3, 4).reshape(B, C, P * h * w)[:, :, self.src] * self.weight
        out = crops.new_zeros(B, C, 2 * H * W).index_add_(2, self.dst, vals)
        # (B, C, 2, H, W) -> side-major channels (B, 2*C, H, W)
        return out.view(B, C, 2, H, W).transpose(1, 2).reshape(B, 2 * C, H, W)

    def matrix(self) -> Tensor:
        """The same map as a sparse (2*H*W, P*h*w) COO matrix, to fold into a sampling operator."""
        H, W = self.size
        n = self.num_crops * self.crop_hw[0] * self.crop_hw[1]
        return torch.sparse_coo_tensor(torch.stack([self.dst, self.src]), self.weight,
                                       (2 * H * W, n), check_invariants=False).coalesce()


def crops_from_images(images: Tensor, windows: Tensor, sides: Tensor, crop_hw: tuple[int, int]) -> Tensor:
    """Cut crops out of full images (the inverse placement; pixels outside the image read 0).

    images: (B, 2*C, H, W); windows: (P, 2|4); sides: (P,) -> (B, P, C, h, w).
    """
    B, C2, H, W = images.shape
    C = C2 // 2
    flat, inside = _flat_targets(windows, sides, crop_hw, (H, W))
    per_side = images.view(B, 2, C, H, W).transpose(1, 2).reshape(B, C, 2 * H * W)
    out = per_side[:, :, flat.reshape(-1)] * inside.reshape(-1).to(images.dtype)
    P = flat.shape[0]
    return out.view(B, C, P, *crop_hw).transpose(1, 2)
