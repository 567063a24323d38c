"""Synthetic garments for fast tests: no body mesh, no drape, operators in milliseconds."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch


def two_chart_garment(n: int = 6):
    """Two flat n x n vertex sheets: front chart (side 0) and back chart (side 1), uv in [0.1, 0.9]^2."""
    t = np.linspace(0.1, 0.9, n)
    uv = np.stack(np.meshgrid(t, t), -1).reshape(-1, 2)
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    tri = np.array([[a, c, b] for a, b, c, d in quads] + [[b, c, d] for a, b, c, d in quads])
    faces = np.concatenate([tri, tri + n * n])
    verts = np.concatenate([np.c_[uv, np.zeros(n * n)], np.c_[uv, np.full(n * n, -0.1)]]) * 0.5
    return SimpleNamespace(
        vertices=torch.tensor(verts, dtype=torch.float32), faces=torch.tensor(faces),
        uv=torch.tensor(np.concatenate([uv, uv]), dtype=torch.float32), face_uv=torch.tensor(faces),
        face_side=torch.tensor([0] * len(tri) + [1] * len(tri)),
        vertex_uv=torch.tensor(np.concatenate([uv, uv]), dtype=torch.float32),
        vertex_side=torch.tensor([0] * n * n + [1] * n * n))


class FakeSkinner:
    """Every cloth pixel at its rest position with identity frames: targets are the stored vertices."""

    def __init__(self, rest):
        self.rest = rest

    def __call__(self, rot):
        b, v = rot.shape[0], self.rest.shape[0]
        return self.rest.to(rot)[None].expand(b, -1, -1), torch.eye(3).to(rot).expand(b, v, 3, 3)


def batch_for(g, b: int = 4, seed: int = 0) -> dict:
    """A batch of random rotations (B, 10, 3, 3) and vertices jittered around the rest shape."""
    gen = torch.Generator().manual_seed(seed)
    q, r = torch.linalg.qr(torch.randn(b, 10, 3, 3, generator=gen))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1))[..., None, :]  # unique QR: proper orthogonal factor
    pose = q * torch.linalg.det(q)[..., None, None]  # det +1: a rotation, as the model's door demands
    verts = g.vertices[None] + 0.01 * torch.randn(b, len(g.vertices), 3, generator=gen)
    return {"pose": pose, "verts": verts, "index": torch.arange(b)}
