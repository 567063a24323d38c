"""Stitcher: feather weights, assembly, PCA, inpainting band, seam metric (synthetic tensors first)."""

import numpy as np
import torch

H = W = 48
CROP = 20


def _layout():
    """Six overlapping crops over two sides with irregular masks (one window partly off-image)."""
    windows = torch.tensor([[0, 0], [10, 12], [25, 30], [-5, 35], [5, 5], [28, 20]])
    sides = torch.tensor([0, 0, 0, 0, 1, 1])
    g = torch.Generator().manual_seed(0)
    masks = torch.rand(6, CROP, CROP, generator=g) > 0.15
    masks[:, 3:17, 3:17] = True
    return windows, sides, masks


def _smooth_images(B=1):
    r = torch.linspace(0, 1, H)[:, None]
    c = torch.linspace(0, 1, W)[None, :]
    base = torch.stack([r + c, r * c, torch.sin(3 * r) + c ** 2])
    return torch.stack([torch.cat([base, 2 * base]) * (b + 1) for b in range(B)])


def test_ground_truth_crops_on_the_real_garment(tmp_path):
    """R(x) cropped per patch and re-assembled is R(x) wherever a crop covers (the padded charts), and
    every seam method returns x from ground-truth crops (inpaint: within its biharmonic smoothing)."""
    import sys
    from pathlib import Path

    from omegaconf import OmegaConf

    from pbc.pixels.operators import ImageOperators
    from pbc.stitch.pca import fit_pca
    from pbc.stitch.seams import build_stitcher

    sys.path.insert(0, str(Path(__file__).parents[1] / "unit"))
    from helpers.evaluate_world import IMAGE, fake_dataset

    ds = fake_dataset(tmp_path / "ds")
    ops = ImageOperators.for_garment(ds.garment, 512, int(IMAGE.pad))
    crops_ops = [ops.crop(p, int(IMAGE.crop_size), int(IMAGE.margin)) for p in ds.cage.patches]
    cfg = OmegaConf.create({"feather_ramp": 16, "band_width": 8, "pca_components": None, "pca_band_only": True,
                           "detail_sigma": 16})
    x = torch.from_numpy(np.array(ds.verts)) - torch.from_numpy(np.array(ds.verts)).mean(0)  # offsets stand-in
    st = build_stitcher(ops, crops_ops, ds.garment, ds.cage, cfg, pca=fit_pca(x, 1000))
    sample = x[:2]
    img = ops.render(sample)
    crops = torch.stack([c.render(sample) for c in crops_ops], 1)
    out = st.assembler.images(crops)
    cov = st.assembler.coverage()
    # crops cover every chart pixel (so every vertex's bilinear taps); some padding of the back chart's
    # side seams lies farther than the margin from any back patch pixel and is left uncovered
    assert (cov & ~ops.mask).sum() == 0 and (ops.chart & ~cov).sum() == 0
    assert cov.reshape(-1)[torch.from_numpy(ops.arrays["S_pix"]).reshape(-1)].all()
    cov6 = cov[:, None].expand(2, 3, 512, 512).reshape(6, 512, 512)
    assert torch.allclose(out[:, cov6], img[:, cov6], atol=1e-6)
    for m in ("average", "pca", "hierarchy", "hierarchy_detail"):
        assert (st(crops, m, sample) - sample).abs().max() < 1e-5, m
    inp = st(crops, "inpaint")
    assert (inp - sample).norm(dim=-1).mean() < 0.1 * sample.norm(dim=-1).mean()


