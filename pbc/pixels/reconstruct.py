"""Cloth images -> 3D garments: sample, skin, offset; plus the vertex normals and edge lengths of the result.

One job: the differentiable path image -> vertices -> 3D that the normal and edge losses go through
(paper Fig. 8 (a)-(c)). Pure torch functions on batched tensors.
"""

from __future__ import annotations

import torch
from torch import Tensor

from pbc.geometry.skeleton import forward_kinematics, linear_blend_skinning
from pbc.pixels.frames import FrameBuilder, embedded_anchors, embedded_body_normals, from_offsets


class Skinner:
    """Skinned cloth pixels of one garment/body/embedding: rotations (B, J, 3, 3) -> anchors, frames.

    Only the body vertices of the triangles the garment is embedded in are skinned (a few thousand
    instead of the whole body), which is what makes per-batch rendering cheap.
    """

    def __init__(self, body, garment, emb):
        faces = torch.as_tensor(body.faces).long()[torch.as_tensor(emb.face).long()]  # (V, 3) body vertex ids
        used, inverse = torch.unique(faces.reshape(-1), return_inverse=True)
        self.skeleton = body.skeleton
        self.points = torch.as_tensor(body.vertices).float()[used]
        self.weights = torch.as_tensor(body.weights).float()[used]
        self.local_faces = inverse.reshape(-1, 3)
        self.bary = torch.as_tensor(emb.bary).float()
        self.builder = FrameBuilder(garment)
        self._emb_local = _LocalEmbedding(torch.arange(len(faces)), self.bary)

    def to(self, device) -> Skinner:
        for name in ("points", "weights", "local_faces", "bary"):
            setattr(self, name, getattr(self, name).to(device))
        self._emb_local = _LocalEmbedding(self._emb_local.face.to(device), self.bary)
        self.builder.to(device)
        return self

    def __call__(self, rotations: Tensor) -> tuple[Tensor, Tensor]:
        """rotations (B, J, 3, 3) -> anchors (B, V, 3), frames (B, V, 3, 3) (rows t, b, n)."""
        if self.points.device != rotations.device:
            self.to(rotations.device)
        transforms = forward_kinematics(self.skeleton, rotations)
        body = linear_blend_skinning(self.points, self.weights, transforms)  # (B, U, 3)
        anchors = embedded_anchors(body, self.local_faces, self._emb_local)
        frames = self.builder(anchors, embedded_body_normals(body, self.local_faces, self._emb_local))
        return anchors, frames


class _LocalEmbedding:
    """An Embedding whose faces index `Skinner.local_faces` (one triangle per garment vertex)."""

    def __init__(self, face: Tensor, bary: Tensor):
        self.face, self.bary = face, bary


def images_to_positions(images: Tensor, ops, anchors: Tensor, frames: Tensor, space: str = "local") -> Tensor:
    """Cloth images (B, 6, H, W) -> garment positions (B, V, 3): sample S, then add to the cloth pixels."""
    return from_offsets(ops.sample(images), anchors, frames, space)


def vertex_normals(positions: Tensor, faces: Tensor) -> Tensor:
    """Area-weighted unit vertex normals: positions (B, V, 3), faces (F, 3) -> (B, V, 3)."""
    faces = faces.to(positions.device)
    a, b, c = (positions.index_select(1, faces[:, k]) for k in range(3))  # (B, F, 3) each
    e1, e2 = b - a, c - a
    # the cross product by components: torch.cross on (B, F, 3) costs several times more on the CPU,
    # and one index_add per corner avoids materialising the (B, 3F, 3) expanded copy (forward and backward)
    x1, y1, z1 = e1.unbind(-1)
    x2, y2, z2 = e2.unbind(-1)
    n_f = torch.stack([y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2], dim=-1)
    n = positions.new_zeros(positions.shape)
    for k in range(3):
        n = n.index_add(1, faces[:, k], n_f)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def mesh_edges(faces: Tensor) -> Tensor:
    """Unique undirected edges (E, 2) of a triangle mesh (F, 3), smaller id first."""
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).long()
    return torch.unique(torch.sort(e, dim=1).values, dim=0)


def edge_lengths(positions: Tensor, edges: Tensor) -> Tensor:
    """positions (B, V, 3), edges (E, 2) -> (B, E) lengths."""
    edges = edges.to(positions.device)
    return (positions[:, edges[:, 0]] - positions[:, edges[:, 1]]).norm(dim=-1)
