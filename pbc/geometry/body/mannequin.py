"""The procedural mannequin: capsules and ellipsoids from ``conf/body/mannequin.yaml`` meshed at their
smooth union (marching cubes), with skinning weights and part masks from the primitives' distances."""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from skimage.measure import marching_cubes
from torch import Tensor

from pbc.geometry.body.base import CAPSULE, KINDS, Body, Primitives, rest_primitive_distances, smooth_union
from pbc.geometry.body.skeleton import (
    ROOT_NAME,
    Skeleton,
    skeleton_from_config,
)


def primitives_from_config(cfg, skel: Skeleton) -> Primitives:
    """Primitives from the body config (`primitives`, `part_names`, `mesh.blend_radius`)."""
    part_names = [str(p) for p in cfg["part_names"]]
    bones = {ROOT_NAME: 0} | {name: j + 1 for j, name in enumerate(skel.names)}
    names, kind, bone, a, b, radii, parts = [], [], [], [], [], [], []
    for p in cfg["primitives"]:
        name = str(p["name"])
        if p["bone"] not in bones:
            raise ValueError(f"primitive {name!r}: unknown bone {p['bone']!r}; known: {list(bones)}")
        if p["kind"] not in KINDS:
            raise ValueError(f"primitive {name!r}: kind must be one of {list(KINDS)}, got {p['kind']!r}")
        unknown = [q for q in p["parts"] if q not in part_names]
        if unknown:
            raise ValueError(f"primitive {name!r}: unknown parts {unknown}; known: {part_names}")
        names.append(name)
        kind.append(KINDS[p["kind"]])
        bone.append(bones[p["bone"]])
        if p["kind"] == "capsule":
            a.append([float(v) for v in p["a"]])
            b.append([float(v) for v in p["b"]])
            radii.append([float(p["radius"][0]), float(p["radius"][1]), 0.0])
        else:
            a.append([float(v) for v in p["centre"]])
            b.append(a[-1])
            radii.append([float(v) for v in p["radii"]])
        parts.append([q in p["parts"] for q in part_names])
    return Primitives(
        names=tuple(names),
        kind=torch.tensor(kind, dtype=torch.long),
        bone=torch.tensor(bone, dtype=torch.long),
        a=torch.tensor(a, dtype=torch.float32),
        b=torch.tensor(b, dtype=torch.float32),
        radii=torch.tensor(radii, dtype=torch.float32),
        parts=torch.tensor(parts, dtype=torch.bool).T.contiguous(),
        blend=float(cfg["mesh"]["blend_radius"]),
    )


def _bounds(prims: Primitives) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) of the rest primitives, each (3,)."""
    r_caps = prims.radii[:, :2].max(dim=1, keepdim=True).values.expand(-1, 3)
    ext = torch.where((prims.kind == CAPSULE)[:, None], r_caps, prims.radii)
    lo = torch.minimum(prims.a, prims.b) - ext
    hi = torch.maximum(prims.a, prims.b) + ext
    return lo.min(dim=0).values.double().numpy(), hi.max(dim=0).values.double().numpy()


def _mesh_rest_surface(prims: Primitives, voxel: float, padding: int):
    """Watertight, outward-oriented trimesh of the rest smooth union (marching cubes)."""
    lo, hi = _bounds(prims)
    lo = lo - (padding * voxel)
    counts = np.ceil((hi + padding * voxel - lo) / voxel).astype(int) + 1
    axes = [lo[i] + voxel * np.arange(counts[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    with torch.no_grad():
        d = rest_primitive_distances(prims, torch.from_numpy(grid).to(torch.float32))
        sdf = smooth_union(d, prims.blend).numpy().reshape(*counts)
    # the padding layer must be outside, or the surface would be cut open at the box
    border = np.concatenate([sdf[[0, -1]].ravel(), sdf[:, [0, -1]].ravel(), sdf[:, :, [0, -1]].ravel()])
    if border.min() <= 0:
        raise RuntimeError("body primitives reach the meshing box border; increase mesh.padding_voxels")
    verts, faces, _, _ = marching_cubes(
        sdf, level=0.0, spacing=(voxel,) * 3, gradient_direction="ascent", allow_degenerate=False
    )
    mesh = trimesh.Trimesh(verts + lo, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if mesh.body_count != 1:
        # a stray sliver would be a separate shell: keep the body itself, the largest one
        mesh = max(mesh.split(only_watertight=False), key=lambda m: len(m.faces))
    if not mesh.is_watertight or not mesh.is_winding_consistent:
        raise RuntimeError(
            f"marching cubes gave a non-watertight body at voxel size {voxel}; try a smaller mesh.voxel_size"
        )
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _skinning_weights(prims: Primitives, num_bones: int, d: Tensor, smoothing: float, cutoff: float) -> Tensor:
    """(V, J+1) weights from per-primitive distances d (V, K): soft-min over primitives, summed per bone."""
    # clamp inside values: a vertex sunk into a neighbour's volume should not outweigh its own surface
    soft = torch.softmax(-d.clamp_min(0.0) / smoothing, dim=1)
    w = torch.zeros(d.shape[0], num_bones, dtype=d.dtype)
    w.index_add_(1, prims.bone, soft)
    w = torch.where(w < cutoff, torch.zeros_like(w), w)
    return w / w.sum(dim=1, keepdim=True)


def _part_masks(prims: Primitives, d: Tensor, margin: float, exclusive: list[list[int]]) -> Tensor:
    """(P, V) part masks from per-primitive distances d (V, K).

    A vertex is in a part within `margin` of the part's union, so parts overlap (the torso takes the
    upper-arm root, an arm its shoulder); within each `exclusive` group (e.g. the two arms, whose
    shoulder primitives meet at the sternum) it keeps only the nearest; strays go to the nearest part.
    """
    part_sdf = torch.stack([smooth_union(d[:, m], prims.blend) for m in prims.parts])  # (P, V)
    masks = part_sdf < margin
    for group in exclusive:
        group = torch.tensor(group, dtype=torch.long)
        nearest = group[part_sdf[group].argmin(dim=0)]  # (V,)
        for p in group:
            masks[p] &= nearest == p
    stray = ~masks.any(dim=0)
    masks[part_sdf.argmin(dim=0)[stray], stray.nonzero()[:, 0]] = True
    return masks


def build_mannequin(cfg) -> Body:
    """Procedural mannequin from the body config (conf/body/mannequin.yaml); deterministic."""
    skel = skeleton_from_config(cfg)
    prims = primitives_from_config(cfg, skel)
    mesh = _mesh_rest_surface(prims, float(cfg["mesh"]["voxel_size"]), int(cfg["mesh"]["padding_voxels"]))
    vertices = torch.tensor(np.asarray(mesh.vertices), dtype=torch.float64)
    with torch.no_grad():
        d = rest_primitive_distances(prims, vertices)
        skin = cfg["skinning"]
        weights = _skinning_weights(prims, skel.num_joints + 1, d, float(skin["smoothing"]), float(skin["cutoff"]))
        part_names = [str(p) for p in cfg["part_names"]]
        exclusive = [[part_names.index(str(p)) for p in group] for group in cfg["parts"].get("exclusive", [])]
        parts = _part_masks(prims, d, float(cfg["parts"]["margin"]), exclusive)
    return Body(
        skeleton=skel,
        vertices=vertices.to(torch.float32),
        faces=torch.tensor(np.asarray(mesh.faces), dtype=torch.long),
        weights=weights.to(torch.float32),
        parts=parts,
        primitives=prims,
    )
