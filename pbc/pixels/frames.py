"""Local frames at the skinned cloth pixels, and per-vertex offsets in the three spaces of Table 2.

One job: turn draped garment positions into offsets from the skinned cloth pixels (and back).

A cloth pixel is a garment vertex embedded in a body triangle (paper section 5). Its local frame has
rows (t, b, n): t along the garment's u direction and b along its v direction as they lie on the posed
body, n the outward normal. They are measured on the *embedded* garment mesh (the cloth pixels skinned
with the body), so the frame is as smooth as that mesh and needs only the body triangles the garment
is embedded in. Everything is batched torch and differentiable.

Spaces (``space`` argument):
    local     (du, dv, dn) = frame @ (x - anchor)      the paper's default
    root      (dx, dy, dz) = x - anchor                 offsets in the root-joint frame
    position  x                                         root-frame positions, no body at all
"""

from __future__ import annotations

import torch
from torch import Tensor

from pbc.geometry.shrinkwrap import embedded_points

SPACES = ("local", "root", "position")
_EPS = 1e-12


def _check_space(space: str) -> None:
    if space not in SPACES:
        raise ValueError(f"unknown offset space {space!r}; choose one of {SPACES}")


# Skinned cloth-pixel positions, barycentric points on the posed body: the geometry stage's one definition
# (body_vertices (B, Vb, 3), body_faces (Fb, 3) long, emb.face (V,), emb.bary (V, 3) -> (B, V, 3)).
embedded_anchors = embedded_points


class FrameBuilder:
    """Precomputed, pose-independent pieces of the tangent-frame computation for one garment.

    The per-face inverse UV Jacobians and the face -> vertex incidence do not depend on the pose, so
    they are built once; `__call__` then costs a few gathers and scatter-adds per batch.
    """

    def __init__(self, garment):
        faces = torch.as_tensor(garment.faces).long()
        uv = torch.as_tensor(garment.uv).double()[torch.as_tensor(garment.face_uv).long()]  # (F, 3, 2)
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
        # Degenerate UV triangles contribute nothing rather than NaNs.
        ok = det.abs() > 1e-14
        inv = torch.where(ok, 1.0 / torch.where(ok, det, torch.ones_like(det)), torch.zeros_like(det))
        # [T B] = [e1 e2] @ inv([d1 d2]) (columns d1, d2):
        #   T = (e1 d2v - e2 d1v) / det,  B = (e2 d1u - e1 d2u) / det
        self.coef_t = torch.stack([d2[:, 1], -d1[:, 1]], 1) * inv[:, None]  # (F, 2): weights of e1, e2
        self.coef_b = torch.stack([-d2[:, 0], d1[:, 0]], 1) * inv[:, None]
        # Only faces in a vertex's own sampling chart define its (u, v) directions: the back chart may
        # be mirrored, so mixing charts at a seam would cancel the tangents.
        side_f = torch.as_tensor(garment.face_side).long()
        side_v = torch.as_tensor(garment.vertex_side).long()
        same = side_f[:, None] == side_v[faces]  # (F, 3)
        self.uv_area = det.abs()  # weights the tangent average by UV area (scale-free)
        self.faces = faces
        self.same = same
        self.coef_t, self.coef_b = self.coef_t.float(), self.coef_b.float()
        self.uv_area = self.uv_area.float()
        self.num_vertices = int(torch.as_tensor(garment.vertices).shape[0])

    def to(self, device) -> FrameBuilder:
        for name in ("faces", "same", "coef_t", "coef_b", "uv_area"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    def __call__(self, anchors: Tensor, body_normals: Tensor) -> Tensor:
        """anchors (B, V, 3) embedded points, body_normals (B, V, 3) outward (any length) -> (B, V, 3, 3).

        Rows are (t, b, n), orthonormal: n is the area-weighted normal of the embedded garment mesh
        turned to agree with the body, t and b the UV-gradient directions Gram-Schmidt'ed against it.
        """
        if self.faces.device != anchors.device:
            self.to(anchors.device)
        B, V = anchors.shape[:2]
        p = anchors[:, self.faces]  # (B, F, 3, 3)
        e1, e2 = p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0]
        t_f = e1 * self.coef_t[:, 0, None] + e2 * self.coef_t[:, 1, None]  # (B, F, 3)
        b_f = e1 * self.coef_b[:, 0, None] + e2 * self.coef_b[:, 1, None]
        n_f = torch.cross(e1, e2, dim=-1)  # length = 2 * area: area-weighted accumulation
        w = self.same.to(anchors.dtype) * self.uv_area[:, None]  # (F, 3)
        idx = self.faces.reshape(-1)

        def accumulate(face_vec: Tensor, weight: Tensor | None) -> Tensor:
            vals = face_vec[:, :, None, :].expand(B, -1, 3, 3)
            if weight is not None:
                vals = vals * weight[None, :, :, None]
            out = anchors.new_zeros(B, V, 3)
            return out.index_add(1, idx, vals.reshape(B, -1, 3))

        t = accumulate(t_f, w)
        b = accumulate(b_f, w)
        n = accumulate(n_f, None)
        # Garment winding is not trusted to be outward: orient each normal by the body's.
        sign = torch.where((n * body_normals).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(n)
        n = _normalize(n * sign)
        t = _normalize(t - (t * n).sum(-1, keepdim=True) * n)
        b = b - (b * n).sum(-1, keepdim=True) * n - (b * t).sum(-1, keepdim=True) * t
        return torch.stack([t, _normalize(b), n], dim=-2)


def _normalize(x: Tensor) -> Tensor:
    return x / x.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def embedded_body_normals(body_vertices: Tensor, body_faces: Tensor, emb) -> Tensor:
    """Outward (unnormalised) normal of the body triangle each cloth pixel sits in: (B, V, 3)."""
    tri = body_faces.to(body_vertices.device)[emb.face.to(body_vertices.device)]
    c = body_vertices[:, tri]  # (B, V, 3, 3)
    return torch.cross(c[:, :, 1] - c[:, :, 0], c[:, :, 2] - c[:, :, 0], dim=-1)


def tangent_frames(
    body_vertices: Tensor, body_faces: Tensor, garment, emb, builder: FrameBuilder | None = None
) -> Tensor:
    """Local frames of the cloth pixels on the posed body.

    body_vertices (B, Vb, 3), body_faces (Fb, 3) -> (B, V, 3, 3), rows t (along u), b (along v), n.
    Pass a cached `builder` (FrameBuilder(garment)) to skip the per-garment precomputation.
    """
    builder = builder or FrameBuilder(garment)
    anchors = embedded_anchors(body_vertices, body_faces, emb)
    return builder(anchors, embedded_body_normals(body_vertices, body_faces, emb))


def to_offsets(positions: Tensor, anchors: Tensor, frames: Tensor, space: str = "local") -> Tensor:
    """Garment positions -> offsets. positions, anchors (B, V, 3), frames (B, V, 3, 3) -> (B, V, 3)."""
    _check_space(space)
    if space == "position":
        return positions
    d = positions - anchors
    if space == "root":
        return d
    return torch.einsum("bvij,bvj->bvi", frames, d)


def from_offsets(offsets: Tensor, anchors: Tensor, frames: Tensor, space: str = "local") -> Tensor:
    """Offsets -> garment positions (inverse of `to_offsets`; frames are orthonormal, so R^-1 = R^T)."""
    _check_space(space)
    if space == "position":
        return offsets
    if space == "root":
        return anchors + offsets
    return anchors + torch.einsum("bvij,bvi->bvj", frames, offsets)
