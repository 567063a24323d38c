"""Where a garment vertex lies in the patch-resolution image and in a patch's crop.

One job: the pixel helpers every seam method shares (`pbc.stitch.seams`, the cage seams of
`pbc.stitch.cage_basis`), below both so neither imports the other for them. Pixel (r, c) has its centre at
uv = ((c + 0.5) / W, (r + 0.5) / H), as in `pbc.pixels.operators`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def uv_to_pixel(uv: Tensor, size: tuple[int, int]) -> Tensor:
    """(..., 2) uv in [0, 1]^2 (u -> column, v -> row) -> (..., 2) (row, col), pixel centres at integers."""
    H, W = size
    return torch.stack([uv[..., 1] * H - 0.5, uv[..., 0] * W - 0.5], -1)


def sample_crops(crops: Tensor, crop_ids: Tensor, pix: Tensor, origins: Tensor) -> Tensor:
    """Bilinear values of given crops at full-image pixel positions.

    crops: (B, P, C, h, w); crop_ids: (K,) which crop; pix: (K, 2) (row, col) in the full image;
    origins: (P, 2) crop origins -> (B, K, C).
    """
    B, P, C, h, w = crops.shape
    local = pix - origins[crop_ids].to(pix)
    grid = torch.stack([(local[:, 1] + 0.5) / w * 2 - 1, (local[:, 0] + 0.5) / h * 2 - 1], -1).to(crops)
    sel = crops[:, crop_ids]  # (B, K, C, h, w)
    vals = F.grid_sample(sel.reshape(B * len(crop_ids), C, h, w), grid.repeat(B, 1)[:, None, None, :],
                         mode="bilinear", align_corners=False)
    return vals.view(B, -1, C)
