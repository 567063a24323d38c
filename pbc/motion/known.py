"""Whether a model knows a pose: its distance to the nearest pose the model was trained on (pure numpy).

One notion serves the flags, the guard against poses outside the data and the scoring of real motion
(docs/architecture.md): a pose's distance to the training poses over the joints the model reads, as the
root mean square over those joints of the angle between the pose's rotation and the nearest training pose's.
A per-joint box of angles holds combinations no training pose had, and a joint a few degrees past the box
on a pose the model predicts well flags it all the same; the nearest training pose does neither.

Distances are chordal in the rotations (||R_a - R_b||_F^2 = 8 sin^2(theta / 2) for an angle theta between
them), so the nearest pose is one matrix product over the flattened rotations; the reported angle is
2 asin(sqrt(d^2 / (8 J))) in degrees: every joint turned by that angle gives the same distance.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation


class Nearest(NamedTuple):
    """Per pose: the distance to the nearest known pose (RMS angle over the read joints, degrees), that
    pose's row in the known poses, and the largest single joint's angle to it (degrees)."""

    distance_deg: np.ndarray  # (N,)
    index: np.ndarray  # (N,) int64
    worst_joint_deg: np.ndarray  # (N,)


def features(poses, joints) -> np.ndarray:
    """(N, J, 3, 3) rotations -> (N, len(joints) * 9) float32: the joints' rotations, flattened."""
    p = np.asarray(poses, dtype=np.float32)
    return np.ascontiguousarray(p[:, list(joints)].reshape(len(p), -1))


def _rms_deg(sq: np.ndarray, num_joints: int) -> np.ndarray:
    """Chordal squared distances summed over num_joints -> the RMS angle, degrees."""
    s = np.clip(np.asarray(sq, np.float64) / (8.0 * num_joints), 0.0, 1.0)
    return np.degrees(2.0 * np.arcsin(np.sqrt(s)))


def nearest_known(poses, known, joints, chunk: int = 2048) -> Nearest:
    """The nearest of `known` (M, J, 3, 3) training poses to each of `poses` (N, J, 3, 3), over `joints`
    (indices of the joints the model reads); see `Nearest`. M >= 1."""
    a, b = features(poses, joints), features(known, joints)
    if len(b) == 0:
        raise ValueError("no known poses to measure against (the training split is empty)")
    bb = (b.astype(np.float64) ** 2).sum(1)
    dist = np.empty(len(a))
    index = np.empty(len(a), np.int64)
    for i in range(0, len(a), chunk):
        x = a[i:i + chunk].astype(np.float64)
        sq = (x ** 2).sum(1)[:, None] + bb[None] - 2.0 * x @ b.T.astype(np.float64)
        k = sq.argmin(1)
        index[i:i + chunk] = k
        dist[i:i + chunk] = sq[np.arange(len(k)), k]
    j = len(joints)
    per_joint = ((a.reshape(len(a), j, 9) - b[index].reshape(len(a), j, 9)) ** 2).sum(-1)  # (N, J) chordal^2
    return Nearest(_rms_deg(dist, j), index, _rms_deg(per_joint.max(1), 1))


STILL_TOL = 1e-4  # a joint whose rotation matrix is within this of the identity, entry by entry, is at rest


def still_joints(poses) -> np.ndarray:
    """(J,) bool: the joints at rest in every one of `poses` (N, J, 3, 3), the joints the data never moved
    (all of them for N = 0)."""
    p = np.asarray(poses, dtype=np.float32)
    return ~(np.abs(p - np.eye(3, dtype=np.float32)) > STILL_TOL).any(axis=(0, 2, 3))


def pull_towards_known(poses, known, joints, nearest: Nearest, limit_deg: float) -> np.ndarray:
    """Poses (N, J, 3, 3) with each pose farther than `limit_deg` from the known poses (`nearest`, over
    `joints`) turned towards its nearest known pose, every read joint along its own geodesic by one shared
    fraction, until its distance is `limit_deg`; the other poses and joints are returned as they are. The
    guard against poses outside the data: the model is asked for a pose it knows, as close to the clip's as
    it knows. The fraction is found by bisection, all far poses at once."""
    out = np.array(poses, dtype=np.float64)
    far = np.flatnonzero(nearest.distance_deg > limit_deg)
    if len(far) == 0:
        return out
    joints = list(joints)
    start = out[far][:, joints]  # (n, j, 3, 3)
    target = np.stack([_orthonormal(m) for m in np.asarray(known, np.float64)[nearest.index[far]][:, joints]
                       .reshape(-1, 3, 3)]).reshape(start.shape)
    turn = Rotation.from_matrix((np.swapaxes(start, -1, -2) @ target).reshape(-1, 3, 3)).as_rotvec()  # (n*j, 3)

    def at(t):  # (n,) fractions -> (n, j, 3, 3): each joint turned by t along its geodesic towards the target
        step = Rotation.from_rotvec(turn * np.repeat(t, len(joints))[:, None]).as_matrix().reshape(start.shape)
        return start @ step

    lo, hi = np.zeros(len(far)), np.ones(len(far))  # the distance falls as t grows
    for _ in range(30):
        t = 0.5 * (lo + hi)
        dist = _rms_deg(((at(t) - target) ** 2).sum((1, 2, 3)), len(joints))
        lo, hi = np.where(dist > limit_deg, t, lo), np.where(dist > limit_deg, hi, t)
    turned = out[far]
    turned[:, joints] = at(hi)
    out[far] = turned
    return out


def _orthonormal(m: np.ndarray) -> np.ndarray:
    """The rotation nearest m (3, 3) (stored poses are float16/float32: re-orthonormalised)."""
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r
