"""Cloth images -> 3D garments: sample, skin, offset; plus the vertex normals and edge lengths of the result.

One job: the differentiable path image -> vertices -> 3D that the normal and edge losses go through
(paper Fig. 8 (a)-(c)). Pure torch functions on batched tensors.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from pbc.geometry.body.skeleton import forward_kinematics, linear_blend_skinning
from pbc.pixels.frames import FrameBuilder, embedded_anchors, embedded_body_normals, from_offsets


class Skinner:
    """Skinned cloth pixels of one garment/body/embedding: rotations (B, J, 3, 3) -> anchors, frames.

    Only the body vertices of the triangles the garment is embedded in are skinned (a few thousand
    instead of the whole body), which is what makes per-batch rendering cheap.

    shapes: the other people of a dataset spanning several (`data.body_shape`; anything with `vertices`
    (K, Vb, 3) and `heads` (K, J, 3), the rest meshes and joint heads of persons 0..K-1 on the body's mesh
    connectivity, skinning weights and skeleton). A call with `person` (B,) skins sample b on person
    person[b]; without, on `body` (the dataset's base person), by the single-body path.
    """

    def __init__(self, body, garment, emb, shapes=None):
        faces = torch.as_tensor(body.faces).long()[torch.as_tensor(emb.face).long()]  # (V, 3) body vertex ids
        used, inverse = torch.unique(faces.reshape(-1), return_inverse=True)
        self.skeleton = body.skeleton
        self.points = torch.as_tensor(body.vertices).float()[used]
        self.weights = torch.as_tensor(body.weights).float()[used]
        self.local_faces = inverse.reshape(-1, 3)
        self.bary = torch.as_tensor(emb.bary).float()
        self.builder = FrameBuilder(garment)
        self._emb_local = _LocalEmbedding(torch.arange(len(faces)), self.bary)
        # (K, U, 3) and (K, J, 3): each person's used rest vertices and rest heads; None = one body
        self.people_points = self.people_heads = None
        if shapes is not None:
            vertices, heads = torch.as_tensor(shapes.vertices).float(), torch.as_tensor(shapes.heads).float()
            if vertices.shape[1:] != body.vertices.shape or heads.shape[1:] != body.skeleton.rest_heads.shape:
                raise ValueError(f"body shapes: rest vertices {tuple(vertices.shape)} and heads {tuple(heads.shape)}"
                                 f" do not fit the body ({tuple(body.vertices.shape)} vertices, "
                                 f"{tuple(body.skeleton.rest_heads.shape)} heads): regenerate the dataset")
            self.people_points, self.people_heads = vertices[:, used], heads

    @property
    def num_people(self) -> int:
        """K, the people a `person` index may name (0: a single-body skinner)."""
        return 0 if self.people_points is None else len(self.people_points)

    def to(self, device) -> Skinner:
        for name in ("points", "weights", "local_faces", "bary", "people_points", "people_heads"):
            if getattr(self, name) is not None:
                setattr(self, name, getattr(self, name).to(device))
        self._emb_local = _LocalEmbedding(self._emb_local.face.to(device), self.bary)
        self.builder.to(device)
        return self

    def __call__(self, rotations: Tensor, person=None) -> tuple[Tensor, Tensor]:
        """rotations (B, J, 3, 3) [, person: one int or (B,) (`people`)] -> anchors (B, V, 3), frames (B, V, 3, 3)
        (rows t, b, n)."""
        if self.points.device != rotations.device:
            self.to(rotations.device)
        if person is None:
            transforms = forward_kinematics(self.skeleton, rotations)
            body = linear_blend_skinning(self.points, self.weights, transforms)  # (B, U, 3)
        else:
            person = self.people(person, rotations.shape[0]).to(rotations.device)
            transforms = forward_kinematics(self.skeleton, rotations, self.people_heads[person])
            body = linear_blend_skinning(self.people_points[person], self.weights, transforms)
        anchors = embedded_anchors(body, self.local_faces, self._emb_local)
        frames = self.builder(anchors, embedded_body_normals(body, self.local_faces, self._emb_local))
        return anchors, frames

    def people(self, person, n: int | None = None) -> Tensor:
        """`person` checked: one int (every one of n poses) or (n,) indices -> (n,) long (n None: as given, no
        count to match). One ValueError for a non-integer, a single-body skinner, a wrong count or an index
        outside the people."""
        arr = np.asarray(person.cpu() if isinstance(person, Tensor) else person)
        if arr.dtype.kind not in "iu" and not (arr.dtype.kind == "f" and np.all(arr == np.round(arr))):
            raise ValueError(f"person {arr.tolist()!r}: give a person's index, an integer (0..K-1 of the dataset's "
                             "people)")
        if self.people_points is None:
            raise ValueError("a person index was given, but this body has one person: the dataset was draped on one "
                             "body (made without data.body_shape); leave the person out")
        if arr.ndim == 0 and n is not None:
            arr = np.full(n, int(arr))
        idx = torch.as_tensor(arr.astype(np.int64)).reshape(-1)
        if n is not None and len(idx) != n:
            raise ValueError(f"person: expected {n} indices (one per pose), got {len(idx)}")
        if len(idx) and (int(idx.min()) < 0 or int(idx.max()) >= self.num_people):
            raise ValueError(f"person index {idx.tolist()} is outside 0..{self.num_people - 1}, the "
                             f"{self.num_people} people of the dataset (data.body_shapes)")
        return idx


class _LocalEmbedding:
    """An Embedding whose faces index `Skinner.local_faces` (one triangle per garment vertex)."""

    def __init__(self, face: Tensor, bary: Tensor):
        self.face, self.bary = face, bary


def images_to_positions(images: Tensor, ops, anchors: Tensor, frames: Tensor, space: str = "local") -> Tensor:
    """Cloth images (B, 6, H, W) -> garment positions (B, V, 3): sample S, then add to the cloth pixels."""
    return from_offsets(ops.sample(images), anchors, frames, space)


def mesh_edges(faces: Tensor) -> Tensor:
    """Unique undirected edges (E, 2) of a triangle mesh (F, 3), smaller id first."""
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).long()
    return torch.unique(torch.sort(e, dim=1).values, dim=0)


def edge_lengths(positions: Tensor, edges: Tensor) -> Tensor:
    """positions (B, V, 3), edges (E, 2) -> (B, E) lengths."""
    edges = edges.to(positions.device)
    return (positions[:, edges[:, 0]] - positions[:, edges[:, 1]]).norm(dim=-1)
