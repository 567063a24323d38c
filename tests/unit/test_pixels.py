"""Cloth pixels: frames and offsets, render/sample operators, masks, crops, images -> 3D.

Runs on its own tiny two-chart garment (a tube split into a front and a back chart, embedded in a
slightly thinner tube as the "body"), so it needs no dataset; the real-dataset floor is in bench/.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pbc.geometry.meshops import vertex_normals
from pbc.pixels.frames import FrameBuilder, from_offsets, tangent_frames, to_offsets
from pbc.pixels.operators import ImageOperators, load_or_build, operator_key, rasterize
from pbc.pixels.reconstruct import edge_lengths, images_to_positions, mesh_edges


def tube_garment(n: int = 8, m: int = 10, radius: float = 0.2, height: float = 0.5):
    """A tube of 2n x m vertices: columns 0..n (front chart, seams at 0 and n), n..2n back (mirrored u)."""
    theta = -math.pi / 2 + np.arange(2 * n) * math.pi / n
    y = np.linspace(height, 0, m)
    vid = np.arange(m * 2 * n).reshape(m, 2 * n)
    verts = np.stack(
        [
            radius * np.sin(theta)[None].repeat(m, 0),
            y[:, None].repeat(2 * n, 1),
            radius * np.cos(theta)[None].repeat(m, 0),
        ],
        -1,
    ).reshape(-1, 3)
    # uv: front column j at u = 0.1 + 0.8 j/n; back column j (n..2n) at u = 0.9 - 0.8 (j-n)/n (mirrored)
    vs = 0.1 + 0.8 * np.arange(m) / (m - 1)
    uf = 0.1 + 0.8 * np.arange(n + 1) / n
    ub = 0.9 - 0.8 * np.arange(n + 1) / n
    uv = np.concatenate(
        [np.stack(np.meshgrid(uf, vs), -1).reshape(-1, 2), np.stack(np.meshgrid(ub, vs), -1).reshape(-1, 2)]
    )
    front_uv = lambda i, j: i * (n + 1) + j  # noqa: E731
    back_uv = lambda i, j: m * (n + 1) + i * (n + 1) + (j - n)  # noqa: E731
    faces, face_uv, side = [], [], []
    for i in range(m - 1):
        for j in range(2 * n):
            a, b, c, d = vid[i, j], vid[i, (j + 1) % (2 * n)], vid[i + 1, j], vid[i + 1, (j + 1) % (2 * n)]
            f = front_uv if j < n else back_uv
            ta, tb, tc, td = f(i, j), f(i, j + 1), f(i + 1, j), f(i + 1, j + 1)
            faces += [[a, c, b], [b, c, d]]
            face_uv += [[ta, tc, tb], [tb, tc, td]]
            side += [int(j >= n)] * 2
    vertex_side = np.tile((np.arange(2 * n) > n).astype(np.int64), m)
    vertex_uv = np.zeros((len(verts), 2))
    for i in range(m):
        for j in range(2 * n):
            vertex_uv[vid[i, j]] = uv[front_uv(i, j) if j <= n else back_uv(i, j)]
    g = SimpleNamespace(
        vertices=torch.tensor(verts, dtype=torch.float32),
        faces=torch.tensor(faces),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(face_uv),
        face_side=torch.tensor(side),
        vertex_uv=torch.tensor(vertex_uv, dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side),
        uv_scale=1.0,
    )
    # the "body": the same tube 10% thinner; each garment vertex sits on a corner of one of its faces
    faces_np = np.asarray(faces)
    f_of_v = np.full(len(verts), -1)
    k_of_v = np.zeros(len(verts), np.int64)
    for fi, tri in enumerate(faces_np):
        for k, v in enumerate(tri):
            if f_of_v[v] < 0:
                f_of_v[v], k_of_v[v] = fi, k
    bary = np.eye(3)[k_of_v]
    body_v = torch.tensor(verts * np.array([0.9, 1.0, 0.9]), dtype=torch.float32)
    emb = SimpleNamespace(
        face=torch.tensor(f_of_v),
        bary=torch.tensor(bary, dtype=torch.float32),
        part=torch.zeros(len(verts), dtype=torch.long),
    )
    return g, body_v, torch.tensor(faces), emb


def smooth_field(verts: torch.Tensor, batch: int = 2) -> torch.Tensor:
    """A smooth per-vertex (B, V, 3) field, like cloth offsets (cm-scale, metres)."""
    p = verts[None] * torch.arange(1, batch + 1)[:, None, None]
    return 0.01 * torch.stack(
        [torch.sin(7 * p[..., 1]), torch.cos(5 * p[..., 0] + 3 * p[..., 1]), p[..., 2] * 3], -1
    )


@pytest.fixture(scope="module")
def tube():
    return tube_garment()


@pytest.fixture(scope="module")
def ops(tube):
    return ImageOperators.for_garment(tube[0], 64, pad=4)


def _posed(body_v: torch.Tensor, batch: int = 3) -> torch.Tensor:
    """Deform the body tube: bend, twist, scale, per batch element."""
    out = []
    for b in range(batch):
        a = 0.3 * (b + 1)
        rot = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        p = body_v @ rot.T
        out.append(
            p + 0.05 * torch.stack([p[:, 1] ** 2, torch.zeros_like(p[:, 1]), torch.sin(4 * p[:, 1])], -1)
        )
    return torch.stack(out)


def test_frames_orthonormal_and_round_trip(tube):
    g, body_v, body_f, emb = tube
    bv = _posed(body_v)
    frames = tangent_frames(bv, body_f, g, emb)
    assert frames.shape == (3, len(g.vertices), 3, 3)
    eye = frames @ frames.transpose(-1, -2)
    assert torch.allclose(eye, torch.eye(3).expand_as(eye), atol=1e-5)
    # n points away from the tube axis (outward), t along +u; on the front +u is +x at theta=0
    anchors = bv[:, body_f[emb.face]].mul(emb.bary[None, :, :, None]).sum(2)
    radial = anchors.clone()
    radial[..., 1] = 0
    assert ((frames[..., 2, :] * radial).sum(-1) > 0).all()
    x = anchors + smooth_field(g.vertices, 3)
    for space in ("local", "root", "position"):
        off = to_offsets(x, anchors, frames, space)
        assert torch.allclose(from_offsets(off, anchors, frames, space), x, atol=1e-6)
    with pytest.raises(ValueError, match="unknown offset space"):
        to_offsets(x, anchors, frames, "uv")


def test_frames_differentiable(tube):
    g, body_v, body_f, emb = tube
    bv = _posed(body_v, 1).requires_grad_(True)
    FrameBuilder(g)  # builds without a device
    tangent_frames(bv, body_f, g, emb).sum().backward()
    assert torch.isfinite(bv.grad).all() and bv.grad.abs().sum() > 0


def test_rasterize_covers_square_once():
    tri = np.array([[[0, 0], [1, 0], [0, 1]], [[1, 0], [1, 1], [0, 1]]], float)
    pix, face, bary = rasterize(tri, 16)
    assert len(pix) == 256 and len(np.unique(pix)) == 256
    assert np.allclose(bary.sum(1), 1)


def test_operator_shapes_and_sparsity(tube, ops):
    g = tube[0]
    V = len(g.vertices)
    R, S = ops.scipy_R(), ops.scipy_S()
    assert R.shape == (2 * 64 * 64, V) and S.shape == (V, 2 * 64 * 64)
    assert R.nnz < 12 * ops.mask.sum().item()  # a few entries per covered pixel
    assert (np.diff(S.indptr) == 4).all()
    x = smooth_field(g.vertices)
    img = ops.render(x)
    assert img.shape == (2, 6, 64, 64)
    assert ops.sample(img).shape == (2, V, 3)
    assert ops.image_mask().shape == (1, 6, 64, 64)
    # nothing is written outside the padded mask; the padded mask strictly contains the chart
    assert (img * (1 - ops.image_mask())).abs().max() == 0
    assert (ops.mask & ~ops.chart).any() and not (ops.chart & ~ops.mask).any()


def test_render_constant_is_constant_inside_mask(tube, ops):
    x = torch.ones(1, len(tube[0].vertices), 3) * torch.tensor([0.3, -0.2, 0.7])
    img = ops.render(x)
    m = ops.image_mask().bool()
    expect = torch.tensor([0.3, -0.2, 0.7]).repeat(2)[None, :, None, None].expand_as(img)
    assert torch.allclose(img[m.expand_as(img)], expect[m.expand_as(img)], atol=1e-5)


@pytest.mark.parametrize("method", ["gather", "sparse"])
def test_round_trip_exact_and_methods_agree(tube, ops, method):
    g = tube[0]
    x = smooth_field(g.vertices)
    other = ImageOperators(ops.arrays, method=method)
    img = other.render(x)
    assert torch.allclose(img, ops.render(x), atol=1e-6)
    assert (other.sample(img) - x).abs().max() < 1e-6
    assert ops.residual < 1e-6


def test_plain_rasterisation_round_trip_is_approximate(tube):
    g = tube[0]
    plain = ImageOperators.for_garment(g, 64, pad=4, exact=False)
    x = smooth_field(g.vertices)
    err = (plain.sample(plain.render(x)) - x).abs().max()
    assert 0 < err < 0.01  # bilinear of piecewise-linear: close but not exact


def test_cache_on_disk(tube, tmp_path):
    g = tube[0]
    a = load_or_build(g, 32, 2, True, tmp_path)
    files = list(tmp_path.glob("operators_*.npz"))
    assert len(files) == 1 and operator_key(g, 32, 2, True) in files[0].name
    b = load_or_build(g, 32, 2, True, tmp_path)
    assert np.array_equal(a["R_data"], b["R_data"])
    files[0].write_bytes(b"garbage")  # a corrupt cache is rebuilt, not an error
    c = load_or_build(g, 32, 2, True, tmp_path)
    assert np.array_equal(a["R_data"], c["R_data"])
    assert operator_key(g, 64, 2, True) != operator_key(g, 32, 2, True)


def test_crop_window_contains_patch_with_margin(tube):
    g = tube[0]
    ops512 = ImageOperators.for_garment(g, 128, pad=4)
    front = np.nonzero(g.vertex_side.numpy() == 0)[0]
    uv = g.vertex_uv.numpy()[front] * 512
    box = (int(uv[:, 1].min()), int(uv[:, 0].min()), int(uv[:, 1].max()) + 1, int(uv[:, 0].max()) + 1)
    patch = SimpleNamespace(id=0, side=0, vertices=front, box_512=box)
    crop = ops512.crop(patch, crop_size=120, margin=4)
    r0, c0, size = crop.window
    px = g.vertex_uv.numpy()[front] * 128
    assert (px[:, 1] - r0 >= 4).all() and (r0 + size - px[:, 1] >= 4).all()
    assert (px[:, 0] - c0 >= 4).all() and (c0 + size - px[:, 0] >= 4).all()
    x = smooth_field(g.vertices)
    img = crop.render(x)
    assert img.shape == (2, 3, size, size)
    full = ops512.render(x)[:, 0:3, r0 : r0 + size, c0 : c0 + size]
    assert torch.allclose(img, full)
    assert torch.allclose(crop.sample(img), x[:, front], atol=1e-6)
    assert crop.mask.any() and not (crop.mask & ~ops512.mask[0, r0 : r0 + size, c0 : c0 + size]).any()


def test_gradients_flow_from_3d_loss_to_image(tube, ops):
    g, body_v, body_f, emb = tube
    bv = _posed(body_v, 2)
    frames = tangent_frames(bv, body_f, g, emb)
    anchors = bv[:, body_f[emb.face]].mul(emb.bary[None, :, :, None]).sum(2)
    img = ops.render(smooth_field(g.vertices)).requires_grad_(True)
    pos = images_to_positions(img, ops, anchors, frames)
    n = vertex_normals(pos, g.faces)
    e = edge_lengths(pos, mesh_edges(g.faces))
    assert n.shape == pos.shape and torch.allclose(n.norm(dim=-1), torch.ones(()), atol=1e-5)
    assert e.shape[1] == len(mesh_edges(g.faces)) and (e > 0).all()
    (pos.square().sum() + (1 - n[..., 2]).sum() + e.sum()).backward()
    assert img.grad is not None and img.grad.abs().sum() > 0
