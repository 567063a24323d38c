"""Stitcher: feather weights, assembly, PCA, inpainting band, seam metric (synthetic tensors first)."""

import numpy as np
import pytest
import torch

from pbc.stitch.assemble import Assembler, crops_from_images, feather_weights
from pbc.stitch.pca import fit_pca, load_pca, project, save_pca
from pbc.stitch.seams import (
    band_weight,
    edge_jump,
    inpaint_band,
    nearest_fill_index,
    patch_disagreement,
    rasterise_segments,
    sample_pixels,
    seam_edges,
)

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


def test_feather_weights_fall_to_edge_and_sum_to_one():
    windows, sides, masks = _layout()
    fw = feather_weights(masks, ramp=4)
    assert fw.shape == masks.shape
    assert (fw[masks] > 0).all() and (fw[~masks] == 0).all()
    # lowest on the crop border, full inside
    assert fw[:, 0, :].max() <= 1 / 5 + 1e-6 and fw[:, 10, 10].min() == 1
    asm = Assembler.build(fw, windows, sides, (H, W))
    ones = asm.images(torch.ones(1, 6, 1, CROP, CROP))[0]  # (2, H, W): the sum of weights per pixel
    cov = asm.coverage()
    assert torch.allclose(ones[cov], torch.ones(()), atol=1e-6)
    assert (ones[~cov] == 0).all()


def test_assembling_consistent_crops_reproduces_image():
    windows, sides, masks = _layout()
    asm = Assembler.build(feather_weights(masks, 4), windows, sides, (H, W))
    img = torch.randn(2, 6, H, W)
    crops = crops_from_images(img, windows, sides, (CROP, CROP))
    out = asm.images(crops)
    cov = asm.coverage()
    for b in range(2):
        for s in range(2):
            ch = slice(3 * s, 3 * s + 3)
            assert torch.allclose(out[b, ch][:, cov[s]], img[b, ch][:, cov[s]], atol=1e-5)
    # the folded (sparse matrix) path equals the index path
    M = asm.matrix()
    flat = crops.permute(1, 3, 4, 0, 2).reshape(-1, 2 * 3)
    via = (M @ flat).view(2, H, W, 2, 3).permute(3, 0, 4, 1, 2).reshape(2, 6, H, W)
    assert torch.allclose(via, out, atol=1e-5)


def test_blend_of_disagreeing_crops_is_a_convex_combination():
    windows, sides, masks = _layout()
    asm = Assembler.build(feather_weights(masks, 4), windows, sides, (H, W))
    vals = torch.arange(6.0).view(1, 6, 1, 1, 1).expand(1, 6, 3, CROP, CROP)
    out = asm.images(vals)[0]
    cov = asm.coverage()
    front = out[0][cov[0]]
    assert front.min() >= 0 and front.max() <= 3  # front crops hold values 0..3


def test_pca_all_components_is_identity_on_training_samples(tmp_path):
    g = torch.Generator().manual_seed(1)
    X = torch.randn(12, 30, 3, generator=g) * 0.01
    basis = fit_pca(X, n_components=128, dataset_hash="abc")
    assert basis.num_components == 12  # clamped to min(N, D)
    assert torch.allclose(project(basis, X[:3]), X[:3], atol=1e-6)
    # fewer components: a contraction toward the mean, orthonormal basis
    C = basis.components
    assert torch.allclose(C @ C.T, torch.eye(12), atol=1e-5)
    save_pca(basis, tmp_path / "pca.pt")
    assert torch.equal(load_pca(tmp_path / "pca.pt", "abc").components, C)
    with pytest.raises(ValueError, match="fitted on dataset"):
        load_pca(tmp_path / "pca.pt", "other")


def test_pca_lowrank_path_matches_exact():
    g = torch.Generator().manual_seed(2)
    X = torch.randn(40, 5, generator=g) @ torch.randn(5, 60, generator=g)  # rank 5
    exact = fit_pca(X, 5)
    approx = fit_pca(X, 5, exact_below=1)
    assert torch.allclose(project(exact, X), X, atol=1e-4)
    assert torch.allclose(project(approx, X), X, atol=1e-3)


def _smooth_images(B=1):
    r = torch.linspace(0, 1, H)[:, None]
    c = torch.linspace(0, 1, W)[None, :]
    base = torch.stack([r + c, r * c, torch.sin(3 * r) + c ** 2])
    return torch.stack([torch.cat([base, 2 * base]) * (b + 1) for b in range(B)])


def test_inpaint_touches_band_only_and_fills_smoothly():
    img = _smooth_images(2)
    curves = rasterise_segments(np.array([[[5.0, 24.0], [42.0, 24.0]]]), np.array([0]), (H, W))
    band = band_weight(curves, 3).numpy() > 0
    assert band[0].sum() > 0 and not band[1].any()
    noisy = img.clone()
    noisy[:, :3, torch.from_numpy(band[0])] += 0.3  # a seam artefact
    out = inpaint_band(noisy, band)
    outside = ~torch.from_numpy(np.concatenate([band[[0]]] * 3 + [band[[1]]] * 3))
    assert torch.equal(out[:, outside], noisy[:, outside])
    err_before = (noisy - img).abs()[:, :3, torch.from_numpy(band[0])].mean()
    err_after = (out - img).abs()[:, :3, torch.from_numpy(band[0])].mean()
    assert err_after < 0.05 * err_before


def test_nearest_fill_extends_known_values():
    known = np.zeros((2, 8, 8), bool)
    known[:, 2:6, 2:6] = True
    idx = nearest_fill_index(known)
    img = np.arange(64.0).reshape(8, 8)
    filled = img.reshape(-1)[idx[0].reshape(-1)].reshape(8, 8)
    assert (filled[known[0]] == img[known[0]]).all()
    assert filled[0, 0] == img[2, 2]


def test_band_weight_profile():
    curves = np.zeros((2, 20, 20), bool)
    curves[0, 10, :] = True
    w = band_weight(curves, 4).numpy()
    assert w[0, 10, 5] == 1 and np.isclose(w[0, 12, 5], 0.5) and w[0, 14, 5] == 0
    assert (w[1] == 0).all()


def test_sample_pixels_reads_pixel_centres():
    img = torch.randn(1, 6, H, W, generator=torch.Generator().manual_seed(0))
    pix = torch.tensor([[3.0, 7.0], [10.0, 40.0]])
    side = torch.tensor([0, 1])
    v = sample_pixels(img, pix, side)
    # grid_sample's coordinate round trip costs a few ulps: an absolute tolerance, not exact equality
    assert torch.allclose(v[0, 0], img[0, :3, 3, 7], atol=1e-5)
    assert torch.allclose(v[0, 1], img[0, 3:, 10, 40], atol=1e-5)


def test_seam_edges_and_jump_metrics():
    faces = torch.tensor([[0, 1, 2], [1, 3, 2]])
    vp = torch.tensor([0, 0, 1, 1])
    e = seam_edges(faces, vp)
    assert {tuple(x) for x in e.tolist()} == {(0, 2), (1, 2), (1, 3)}
    gt = torch.randn(1, 4, 3)
    assert edge_jump(gt, gt, e).item() == 0
    moved = gt.clone()
    moved[:, 2:] += torch.tensor([0.0, 0.0, 1.0])  # patch 1 shifted: every seam edge jumps by 1
    assert torch.isclose(edge_jump(moved, gt, e), torch.ones(1)).all()
    # two crops with a constant disagreement of 0.5 at every vertex
    crops = torch.zeros(1, 2, 3, 8, 8)
    crops[:, 1] += 0.5
    pix = torch.tensor([[3.0, 3.0], [3.0, 4.0], [4.0, 3.0], [4.0, 4.0]])
    d = patch_disagreement(crops, torch.zeros(2, 2), pix, e, vp)
    assert torch.isclose(d, torch.full((1,), 0.5 * 3 ** 0.5)).all()


def test_masked_blur_keeps_constants_and_lowers_noise():
    from pbc.stitch.seams import masked_blur

    torch.manual_seed(0)
    mask = torch.zeros(2, 32, 32, dtype=torch.bool)
    mask[0, 4:20, 6:30] = True
    mask[1, 10:30, 2:12] = True
    const = torch.arange(6.0).view(1, 6, 1, 1).expand(2, 6, 32, 32)
    m6 = mask[:, None].expand(2, 3, 32, 32).reshape(1, 6, 32, 32).expand(2, -1, -1, -1)
    for sigma in (3.0, 8.0):  # 8: the coarsened (pooled) path
        out = masked_blur(const * m6, mask, sigma)  # outside values never leak in: mask edge stays exact
        assert torch.allclose(out[m6], const[m6], atol=1e-5) and (out[~m6] == 0).all(), sigma
        noise = torch.randn(2, 6, 32, 32) * m6
        assert masked_blur(noise, mask, sigma)[m6].std() < 0.5 * noise[m6].std(), sigma


def test_hierarchy_detail_takes_low_frequencies_from_the_whole_model(tmp_path):
    """Patches off by a constant everywhere (a pure low-frequency error) + a correct whole model:
    `hierarchy_detail` gives back the truth, `average` keeps the error."""
    import sys
    from pathlib import Path

    from omegaconf import OmegaConf

    from pbc.pixels.operators import ImageOperators
    from pbc.stitch.seams import build_stitcher

    root = Path(__file__).parents[2]
    sys.path.insert(0, str(Path(__file__).parent))
    from helpers.evaluate_world import IMAGE, fake_dataset

    ds = fake_dataset(tmp_path / "ds")
    ops = ImageOperators.for_garment(ds.garment, 512, int(IMAGE.pad))
    crops_ops = [ops.crop(p, int(IMAGE.crop_size), int(IMAGE.margin)) for p in ds.cage.patches]
    cfg = OmegaConf.load(root / "conf/stitch/average.yaml")
    st = build_stitcher(ops, crops_ops, ds.garment, ds.cage, cfg)
    x = torch.from_numpy(np.array(ds.verts[:2])).float()
    x = x - x.mean(1, keepdim=True)
    shift = torch.tensor([0.01, -0.02, 0.005])
    crops = torch.stack([c.render(x + shift) for c in crops_ops], 1)
    assert torch.allclose(st(crops, "average"), x + shift, atol=1e-5)
    assert st.cage is None  # the cage basis is built on the first `cage` call only
    assert st(crops, "cage").shape == x.shape and st.cage is not None
    assert (st(crops, "hierarchy_detail", x) - x).abs().max() < 1e-4
    with pytest.raises(ValueError, match="needs the whole-shirt"):
        st(crops, "hierarchy_detail")
