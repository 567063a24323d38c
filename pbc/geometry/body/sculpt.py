"""Intentionally wrong bodies (appendix D.2): a sculpted shape change and painted skinning artifacts.

One job: derive, from the true body, the bodies the wrong-body study skins and embeds the same cloth with.
Nothing here changes the body's mesh connectivity, so a garment's embedding (body triangle + barycentric
weights) stays valid and the cloth pixels sit on the same surface points of the changed body.

- Shape: the sculpt is a displacement of the rest vertices along their outward normals, a sum of Gaussian
  bumps `depth * exp(-|x - centre|^2 / (2 radius^2))` (e.g. a thicker chest and belly). Shape parameter
  t: vertices + t * displacement, so t = 0 is the true body, t = 1 the sculpted one, t = -1 the opposite
  change and t = 2 twice the sculpt.
- Skinning artifacts: the weights of one joint (the upper arm) painted onto a region of other vertices
  (the torso; the torso and the opposite arm): w <- (1 - a) w + a e_joint, a = amount * falloff, so those
  vertices follow the arm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from pbc.geometry.body.base import Body
from pbc.geometry.meshops import vertex_normals


def _gaussian(points: Tensor, centre: Sequence[float], radius: float) -> Tensor:
    c = torch.as_tensor(centre, dtype=points.dtype)
    if radius <= 0:
        raise ValueError(f"a sculpt / paint radius must be > 0 metres, got {radius}")
    return torch.exp(-((points - c) ** 2).sum(-1) / (2.0 * float(radius) ** 2))


def sculpt_displacement(body: Body, bumps: Sequence[dict], part: int | None = 0) -> Tensor:
    """Displacement (Vb, 3) of the rest vertices: sum of bumps {centre: [x, y, z], radius, depth} (metres)
    along the outward normal; only vertices of body part `part` move (0 torso; None = everywhere)."""
    if not bumps:
        raise ValueError("a sculpt needs at least one bump {centre: [x, y, z], radius, depth}")
    n = vertex_normals(body.vertices.double(), body.faces).to(body.vertices.dtype)
    amount = torch.zeros(body.vertices.shape[0], dtype=body.vertices.dtype)
    for b in bumps:
        missing = {"centre", "radius", "depth"} - set(b)
        if missing:
            raise ValueError(f"sculpt bump {dict(b)} lacks {sorted(missing)}")
        amount = amount + float(b["depth"]) * _gaussian(body.vertices, b["centre"], float(b["radius"]))
    if part is not None:
        amount = amount * body.parts[part].to(amount.dtype)
    return amount[:, None] * n


def shaped_body(body: Body, displacement: Tensor, t: float) -> Body:
    """The body at shape parameter t: rest vertices + t * displacement; weights, faces, skeleton kept."""
    if displacement.shape != body.vertices.shape:
        raise ValueError(f"displacement {tuple(displacement.shape)} must match the body's vertices "
                         f"{tuple(body.vertices.shape)}")
    return replace(body, vertices=(body.vertices + float(t) * displacement).to(body.vertices.dtype))


def paint_weights(body: Body, joint: str, regions: Sequence[dict]) -> Body:
    """Paint `joint`'s skinning weight onto regions {centre, radius, amount, part}: w <- (1 - a) w + a e_joint
    with a = amount * Gaussian falloff, restricted to body part `part` (0 torso, 1 left arm, 2 right arm).
    Rows still sum to 1."""
    names = list(body.skeleton.names)
    if joint not in names:
        raise ValueError(f"unknown joint {joint!r}; the skeleton has {names}")
    col = 1 + names.index(joint)  # column 0 of the weights is the fixed root
    w = body.weights.clone().double()
    target = torch.zeros_like(w)
    target[:, col] = 1.0
    for r in regions:
        a = float(r["amount"]) * _gaussian(body.vertices.double(), r["centre"], float(r["radius"]))
        if r.get("part") is not None:
            a = a * body.parts[int(r["part"])].double()
        if not 0.0 <= float(r["amount"]) <= 1.0:
            raise ValueError(f"a paint amount must be in [0, 1], got {r['amount']}")
        w = (1 - a)[:, None] * w + a[:, None] * target
    return replace(body, weights=(w / w.sum(1, keepdim=True)).to(body.weights.dtype))
