"""The body's skeleton (any body: the mannequin's upper body, Anny's with legs): its rest layout, forward
kinematics and linear blend skinning (pure torch).

Conventions: the root (hip) is fixed at the origin of the root frame (y up, x to the body's left,
z forward, metres). Joint j has a rest head position and a rest frame whose columns are its local axes
in root coordinates (local y along the bone). A pose is one local rotation per joint, expressed in the
joint's rest frame, relative to the body's rest pose (the mannequin's T-pose, Anny's A-pose or T-pose:
conf/body).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

AXES = ("x", "y", "z")
ROOT_NAME = "root"
# a joint (or a point of a spine bone) this close to x = 0 is on the body's centre line (m); not exactly 0:
# a measured body is not perfectly symmetric (Anny's neck02 sits 0.2 mm off the mid-plane)
MIDPLANE_TOL = 1e-3


@dataclass(frozen=True)
class Skeleton:
    names: tuple[str, ...]  # (J,) posable joints, model-input order
    parents: tuple[int, ...]  # (J,) parent index into names, -1 = the fixed root (hip)
    rest_heads: Tensor  # (J, 3) joint positions in the rest pose, root frame
    limits_deg: Tensor  # (J, 3, 2) per-axis (x, y, z) [min, max] in degrees
    # (J, 3, 3) columns = the joint's local x, y, z axes in root coordinates; None = identity frames.
    # Addition to docs/interfaces.md: it makes the Euler axes mean azimuth/altitude/twist for the arms.
    rest_frames: Tensor | None = None

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def frames(self) -> Tensor:
        """(J, 3, 3) rest frames, identity where none were given."""
        if self.rest_frames is not None:
            return self.rest_frames
        return torch.eye(3, dtype=self.rest_heads.dtype).expand(self.num_joints, 3, 3).clone()

    def indices(self, names, key: str) -> list[int]:
        """Indices of joint `names` in the model-input order; one ValueError naming config `key`, every
        unknown name and the skeleton's joints."""
        unknown = [n for n in names if n not in self.names]
        if unknown:
            raise ValueError(f"{key}: unknown joints {unknown}; the body's joints are {list(self.names)}")
        return [self.names.index(n) for n in names]

    def index(self, name: str) -> int:
        """Index of a joint name in the model-input order."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown joint {name!r}; joints are {list(self.names)}") from None


def frame_from_axes(spec: Mapping) -> Tensor:
    """(3, 3) right-handed orthonormal frame from its y and z axes (columns x, y, z)."""
    y = torch.tensor([float(v) for v in spec["y"]], dtype=torch.float64)
    z = torch.tensor([float(v) for v in spec["z"]], dtype=torch.float64)
    y = y / y.norm()
    z = z - (z @ y) * y  # tolerate a slightly non-orthogonal spec
    z = z / z.norm()
    x = torch.linalg.cross(y, z)
    return torch.stack([x, y, z], dim=1)


def skeleton_from_config(cfg) -> Skeleton:
    """Build the Skeleton from the body config (conf/body/mannequin.yaml: `joints`, `frames`)."""
    joints = list(cfg["joints"])
    names = tuple(str(j["name"]) for j in joints)
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate joint names in body config: {names}")
    frame_specs = cfg.get("frames") or {}
    parents, heads, limits, frames = [], [], [], []
    for j, joint in enumerate(joints):
        parent = str(joint["parent"])
        if parent == ROOT_NAME:
            parents.append(-1)
        else:
            if parent not in names[:j]:
                raise ValueError(f"joint {names[j]!r}: parent {parent!r} must be 'root' or a joint listed before it")
            parents.append(names.index(parent))
        heads.append([float(v) for v in joint["head"]])
        lim = joint["limits"]
        limits.append([[float(lim[a][0]), float(lim[a][1])] for a in AXES])
        if any(lo > hi for lo, hi in limits[-1]):
            raise ValueError(f"joint {names[j]!r}: limits must be [min, max], got {limits[-1]}")
        frame = joint.get("frame")
        if frame is None:
            frames.append(torch.eye(3, dtype=torch.float64))
        elif frame not in frame_specs:
            raise ValueError(f"joint {names[j]!r}: unknown frame {frame!r}; known: {list(frame_specs)}")
        else:
            frames.append(frame_from_axes(frame_specs[frame]))
    return Skeleton(
        names=names,
        parents=tuple(parents),
        rest_heads=torch.tensor(heads, dtype=torch.float32),
        limits_deg=torch.tensor(limits, dtype=torch.float32),
        rest_frames=torch.stack(frames).to(torch.float32),
    )


def check_rotations(skel: Skeleton, rotations: Tensor) -> None:
    """Raise one clear ValueError unless rotations is a finite (B, J, 3, 3) tensor."""
    J = skel.num_joints
    if not isinstance(rotations, Tensor):
        raise ValueError(f"rotations must be a torch.Tensor of shape (B, {J}, 3, 3), got {type(rotations)}")
    if rotations.ndim != 4 or rotations.shape[1:] != (J, 3, 3):
        raise ValueError(
            f"rotations: expected shape (B, {J}, 3, 3) (batch, joints in order {list(skel.names)}, "
            f"3x3 matrix), got {tuple(rotations.shape)}"
        )
    bad = ~torch.isfinite(rotations).reshape(rotations.shape[0], -1).all(dim=1)
    if bool(bad.any()):
        i = int(bad.nonzero()[0, 0])
        j = int((~torch.isfinite(rotations[i])).reshape(J, -1).any(dim=1).nonzero()[0, 0])
        raise ValueError(
            f"rotations: NaN/inf at sample {i} (joint {j} {skel.names[j]!r}); "
            f"{int(bad.sum())} of {rotations.shape[0]} samples are not finite"
        )


def forward_kinematics(skel: Skeleton, rotations: Tensor, heads: Tensor | None = None) -> Tensor:
    """Skinning transforms of every bone relative to rest.

    rotations: (B, J, 3, 3) local rotations in each joint's rest frame.
    heads: (J, 3) or (B, J, 3) rest heads to use instead of the skeleton's: another person of the same rig
    (same joints, parents and frames; `data.body_shape`), per sample. None: the skeleton's.
    Returns (B, J+1, 4, 4): index 0 = the fixed root (identity), 1+j = joint j; a rest-pose point p
    attached to bone k lands at transforms[:, k] @ [p, 1].
    """
    check_rotations(skel, rotations)
    B, J = rotations.shape[:2]
    dtype, device = rotations.dtype, rotations.device
    heads = (skel.rest_heads if heads is None else heads).to(dtype=dtype, device=device)
    frames = skel.frames().to(dtype=dtype, device=device)
    # the rotation about each joint in root axes: F R F^T
    world_rot = frames @ rotations @ frames.transpose(-1, -2)  # (B, J, 3, 3)
    # rotate about the rest head: p -> A (p - h) + h
    trans = heads - (world_rot @ heads[..., None])[..., 0]  # (B, J, 3)
    local = torch.zeros(B, J, 4, 4, dtype=dtype, device=device)
    local[..., :3, :3] = world_rot
    local[..., :3, 3] = trans
    local[..., 3, 3] = 1.0
    root = torch.eye(4, dtype=dtype, device=device).expand(B, 4, 4)
    out = [root]
    for j, p in enumerate(skel.parents):
        out.append(out[p + 1] @ local[:, j])  # parents precede children (checked at config time)
    return torch.stack(out, dim=1)


def linear_blend_skinning(points: Tensor, weights: Tensor, transforms: Tensor) -> Tensor:
    """Linear blend skinning.

    points (V, 3) or (B, V, 3) rest positions, weights (V, J+1) rows summing to 1,
    transforms (B, J+1, 4, 4) from forward_kinematics. Returns (B, V, 3).
    """
    if transforms.ndim != 4 or transforms.shape[-2:] != (4, 4):
        raise ValueError(f"transforms: expected shape (B, J+1, 4, 4), got {tuple(transforms.shape)}")
    if weights.ndim != 2 or weights.shape[1] != transforms.shape[1]:
        raise ValueError(
            f"weights: expected shape (V, {transforms.shape[1]}) to match transforms "
            f"{tuple(transforms.shape)}, got {tuple(weights.shape)}"
        )
    if points.shape[-1] != 3 or points.ndim not in (2, 3) or points.shape[-2] != weights.shape[0]:
        raise ValueError(
            f"points: expected shape (V, 3) or (B, V, 3) with V={weights.shape[0]}, got {tuple(points.shape)}"
        )
    weights = weights.to(transforms.dtype)
    # blend the 3x4 matrices first: one (B, V, 3, 4) tensor instead of J+1 transformed copies
    blended = torch.einsum("vk,bkij->bvij", weights, transforms[..., :3, :])
    rot, trans = blended[..., :3], blended[..., 3]
    points = points.to(transforms.dtype)
    if points.ndim == 2:
        points = points.expand(transforms.shape[0], *points.shape)
    return torch.einsum("bvij,bvj->bvi", rot, points) + trans


def xzy_angles(poses) -> np.ndarray:
    """Rotations (..., 3, 3) = Rx(x) Rz(z) Ry(y) -> angles (..., 3) in degrees, per axis (x, y, z); the
    inverse of pbc.sim.poses.euler_xzy_to_matrix for |z| < 90 degrees (the body's limits keep it there)."""
    r = np.asarray(poses, dtype=np.float64)
    x = np.arctan2(r[..., 2, 1], r[..., 1, 1])
    y = np.arctan2(r[..., 0, 2], r[..., 0, 0])
    z = np.arcsin(np.clip(-r[..., 0, 1], -1.0, 1.0))
    return np.degrees(np.stack([x, y, z], -1))


def swing_twist_angles(poses) -> np.ndarray:
    """Rotations (..., 3, 3) of joints whose bone runs along local y -> angles (..., 3) in degrees, per axis
    (x, y, z): x and z the swing (the turn taking the bone's rest direction onto its posed one, as axis times
    angle; its axis lies in the x-z plane: `swing_to`), y the twist about the bone after it. The inverse of
    `swing_twist_to_matrix`.

    Why a second chart: the body's Euler angles (`xzy_angles`) are singular where a T-posed arm hangs down
    (z = -90, x and y turn about one axis), so a box of them holds or misses hanging arms by accident. The swing
    is singular only for a bone turned fully about (180 degrees), which no joint reaches."""
    r = np.asarray(poses, dtype=np.float64)
    angles = swing_to(r[..., :, 1])  # the bone's posed direction in its rest frame; twist 0
    twist = np.swapaxes(swing_twist_to_matrix(angles).numpy(), -1, -2) @ r  # a turn about y alone
    angles[..., 1] = np.degrees(np.arctan2(twist[..., 0, 2], twist[..., 0, 0]))
    return angles


def swing_to(directions) -> np.ndarray:
    """Unit directions (..., 3) in a joint's rest frame -> (..., 3) swing-twist angles in degrees (x, 0, z) of
    the swing taking the bone (local y) onto each: the axis (in the x-z plane) times the angle."""
    d = np.asarray(directions, dtype=np.float64)
    theta = np.degrees(np.arccos(np.clip(d[..., 1], -1.0, 1.0)))
    h = np.hypot(d[..., 0], d[..., 2])
    scale = np.where(h > 1e-12, theta / np.maximum(h, 1e-12), 0.0)  # no swing (or a half turn): no axis to take
    return np.stack([d[..., 2] * scale, np.zeros_like(theta), -d[..., 0] * scale], -1)


def swing_twist_to_matrix(angles_deg) -> Tensor:
    """Angles (..., 3) in degrees, per axis (x, y, z) of `swing_twist_angles` -> rotations (..., 3, 3):
    the swing (axis-angle (x, 0, z)) after the twist y about the bone. Differentiable everywhere (the range
    search descends on it)."""
    a = torch.deg2rad(torch.as_tensor(angles_deg))
    sx, tw, sz = a[..., 0], a[..., 1], a[..., 2]
    zero = torch.zeros_like(sx)
    k = torch.stack([torch.stack([zero, -sz, zero], -1), torch.stack([sz, zero, -sx], -1),
                     torch.stack([zero, sx, zero], -1)], -2)
    t2 = sx**2 + sz**2
    small = t2 < 1e-12
    t = torch.sqrt(torch.where(small, torch.ones_like(t2), t2))  # a safe root: no NaN gradient at no swing
    a1 = torch.where(small, 1.0 - t2 / 6.0, torch.sin(t) / t)[..., None, None]
    b1 = torch.where(small, 0.5 - t2 / 24.0, (1.0 - torch.cos(t)) / t**2)[..., None, None]
    eye = torch.eye(3, dtype=a.dtype).expand(k.shape)
    swing = eye + a1 * k + b1 * (k @ k)
    c, s = torch.cos(tw), torch.sin(tw)
    one = torch.ones_like(tw)
    twist = torch.stack([torch.stack([c, zero, s], -1), torch.stack([zero, one, zero], -1),
                         torch.stack([-s, zero, c], -1)], -2)
    return swing @ twist


def geodesic_deg(a, b) -> np.ndarray:
    """(...,) the angle in degrees of the rotation between rotations a and b (..., 3, 3)."""
    c = (np.einsum("...ij,...ij->...", np.asarray(a, np.float64), np.asarray(b, np.float64)) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def descendants(sk: Skeleton, joint: str) -> set[int]:
    """The joint (model-input index) named ``joint`` and every joint below it."""
    chain = {sk.index(joint)}
    for j, parent in enumerate(sk.parents):  # parents precede children
        if parent in chain:
            chain.add(j)
    return chain


def limb_segments(sk: Skeleton, joint: str) -> np.ndarray:
    """The bone segments (S, 2, 3) (rest heads, m) of the limb starting at ``joint``: joint -> its first child ->
    ... -> the last joint (l_arm -> l_forearm -> l_hand: 2 segments). A limb of one joint (the mannequin's arm)
    is one segment along its bone axis, as long as the skeleton is wide."""
    names, parents = list(sk.names), list(sk.parents)
    heads = sk.rest_heads.double().cpu().numpy()
    chain = [names.index(joint)]
    while (children := [j for j, par in enumerate(parents) if par == chain[-1]]):
        chain.append(children[0])
    if len(chain) == 1:
        axis = sk.frames()[chain[0]][:, 1].double().cpu().numpy()
        a = heads[chain[0]]
        return np.asarray([(a, a + float(np.ptp(heads[:, 0])) * axis)])
    return np.asarray([(heads[a], heads[b]) for a, b in zip(chain[:-1], chain[1:], strict=True)])
