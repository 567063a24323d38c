"""Cage Poisson blendshapes (pbc.stitch.cage_basis): partition of unity, linear precision on a flat patch,
exact cage values, and the `cage` seam method removing the patches' disagreement. Synthetic data only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pbc.stitch.cage_basis import (
    CageSeams,
    anisotropic_tensor,
    build_cage_basis,
    fill_from_cage,
    harmonic_basis,
)

TENSORS = {"isotropic": None, "anisotropic": anisotropic_tensor(0.05, 30.0)}


def flat_patch(n: int = 9, seed: int = 0):
    """A jittered n x n grid on [0, 1]^2: points (n*n, 2), faces, boundary ids."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0, 1, n)
    x, y = np.meshgrid(g, g, indexing="xy")
    pts = np.stack([x.ravel(), y.ravel()], 1)
    on_edge = (pts == 0).any(1) | (pts == 1).any(1)
    pts[~on_edge] += rng.uniform(-0.2, 0.2, (int((~on_edge).sum()), 2)) / (n - 1)
    vid = np.arange(n * n).reshape(n, n)
    a, b, c, d = vid[:-1, :-1].ravel(), vid[:-1, 1:].ravel(), vid[1:, :-1].ravel(), vid[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return pts, faces, np.nonzero(on_edge)[0]


@pytest.mark.parametrize("kind", list(TENSORS))
def test_partition_of_unity_and_linear_precision(kind):
    pts, faces, cage = flat_patch()
    W = harmonic_basis(pts, faces, cage, TENSORS[kind])
    free = np.setdiff1d(np.arange(len(pts)), cage)
    assert W.shape == (len(free), len(cage))
    np.testing.assert_allclose(W.sum(1), 1.0, atol=1e-10)
    lin = 0.3 + 1.7 * pts[:, 0] - 0.8 * pts[:, 1]
    np.testing.assert_allclose(W @ lin[cage], lin[free], atol=1e-10)
    # a bump on the boundary is not linear: the fill is a real interpolation below the bump's peak
    bump = np.exp(-((pts[:, 0] - 0.5) ** 2) / 0.02) * (pts[:, 1] == 1)
    fill = W @ bump[cage]
    assert 1e-3 < fill.max() < bump.max()
    if kind == "isotropic":  # the discrete maximum principle (cotangent weights >= 0 on this mesh);
        assert fill.min() > -1e-9  # linear FEM with a rotated anisotropic D is no M-matrix: small undershoot


def test_anisotropy_spreads_along_its_axis():
    pts, faces, cage = flat_patch(15)
    left = (pts[cage, 0] == 0) & (np.abs(pts[cage, 1] - 0.5) < 0.2)  # a bump on the left edge
    vals = left.astype(float)
    free = np.setdiff1d(np.arange(len(pts)), cage)
    along_u = harmonic_basis(pts, faces, cage, anisotropic_tensor(1.0, 0.0) * np.diag([1.0, 1.0]))
    aniso_u = harmonic_basis(pts, faces, cage, anisotropic_tensor(0.05, 0.0))  # strong along u
    mid = free[np.abs(pts[free, 1] - 0.5) < 0.05]
    far = mid[pts[mid, 0] > 0.6]
    pos = np.searchsorted(free, far)
    assert (aniso_u @ vals)[pos].mean() > 2 * (along_u @ vals)[pos].mean()


@pytest.fixture(scope="module")
def shirt():
    from pbc.core.config import load_garment_config
    from pbc.geometry.garment.tshirt import make_tshirt
    from pbc.pixels.operators import ImageOperators

    garment, cage = make_tshirt(load_garment_config("conf/garment/tshirt_coarse.yaml"))
    ops = ImageOperators.for_garment(garment, 256, pad=4)
    crops = [ops.crop(p, 80, 8) for p in cage.patches]
    return garment, cage, ops, crops


def test_garment_basis_sums_to_one_and_keeps_cage_values(shirt):
    garment, cage, ops, crops = shirt
    for tensor in TENSORS.values():
        bases = build_cage_basis(garment, cage, tensor)
        assert len(bases) == len(cage.patches)
        covered = np.sort(np.concatenate([np.r_[b.cage, b.interior] for b in bases]))
        np.testing.assert_array_equal(covered, np.arange(garment.vertices.shape[0]))
        for b in bases:
            if len(b.interior):
                np.testing.assert_allclose(b.weights.sum(1), 1.0, atol=1e-9)
        x = torch.randn(2, garment.vertices.shape[0], 3, dtype=torch.float64)
        filled = fill_from_cage(bases, x)
        cg = torch.as_tensor(np.concatenate([b.cage for b in bases]))
        assert torch.equal(filled[:, cg], x[:, cg])
        assert sum(len(b.interior) for b in bases) > 100


def _seam_jump(x, garment, cage):
    from pbc.stitch.seams import seam_edges, vertex_patch_ids

    vp = vertex_patch_ids([p.vertices for p in cage.patches], garment.vertices.shape[0])
    e = seam_edges(garment.faces, vp)
    return (x[:, e[:, 0]] - x[:, e[:, 1]]).norm(dim=-1).mean()


def test_cage_method_removes_seam_disagreement(shirt):
    garment, cage, ops, crops = shirt
    seams = CageSeams(garment, cage, crops, ops.res)
    assert (seams.readers > 1).sum() > 50  # neighbours do see each other's cage vertices
    V = garment.vertices.shape[0]
    smooth = 0.02 * torch.sin(4 * garment.vertices[None].float() @ torch.randn(3, 3))  # (1, V, 3)
    gt_crops = torch.stack([c.render(smooth) for c in crops], 1)
    # patches that agree: the method changes nothing, exactly where every reading is at a vertex's own
    # sampling position; a front/back seam vertex read in its other chart carries the representation floor
    out = seams(gt_crops)
    exact = torch.ones(V, dtype=torch.bool)
    for b in seams.bases:
        if seams.cross_chart[torch.as_tensor(b.cage)].any():
            exact[torch.as_tensor(np.r_[b.cage, b.interior])] = False
    assert exact.sum() > V // 3
    torch.testing.assert_close(out[:, exact], smooth[:, exact], atol=1e-6, rtol=0)
    torch.testing.assert_close(out, smooth, atol=1e-3, rtol=0)
    # each patch off by its own constant: the raw readings jump at every seam, the cage result does not
    bias = 0.01 * torch.randn(len(crops), 3, generator=torch.Generator().manual_seed(1))
    biased = gt_crops + bias[None, :, :, None, None]
    own, agreed = seams.agreed(biased)
    out = seams(biased)
    raw_jump = _seam_jump(own - smooth, garment, cage)
    cage_jump = _seam_jump(out - smooth, garment, cage)
    assert raw_jump > 0.005
    assert cage_jump < 0.35 * raw_jump, (float(cage_jump), float(raw_jump))
    # every cage vertex carries the agreed value, and away from the seams a patch keeps its own prediction
    cg = torch.as_tensor(np.concatenate([b.cage for b in seams.bases]))
    assert torch.equal(out[:, cg], agreed[:, cg])
    assert out.shape == (1, V, 3)
