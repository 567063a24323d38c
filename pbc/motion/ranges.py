"""Poses against what a model saw: joint angles vs the training data's range, flags and clamping.

Angles are the body's own Euler angles (conf/body: R = Rx Rz Ry about the joint's rest frame, per axis
x, y, z, degrees), the ones the pose sampler draws within the joint limits. The training range of a run is
the per-joint, per-axis [min, max] over its dataset's training split.

A rotation is inside a range when some rotation the range holds equals it: near the angles' singular point
(z near +-90 degrees, where x and y turn about nearly one axis: a T-posed arm hanging down) a small turn moves
x and y far in opposite directions, so a rotation's own angles can leave the box while the box still holds it
(or its other decomposition, x + 180, y + 180, 180 - z). `nearest_in_range` searches the box for the nearest
rotation; the flag and the clamp both read it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pbc.geometry.body.skeleton import AXES, geodesic_deg, xzy_angles
from pbc.sim.poses import euler_xzy_to_matrix


def angle_range(poses, chunk: int = 4096) -> np.ndarray:
    """(J, 3, 2) per joint and axis [min, max] degrees over poses (N, J, 3, 3) (a memory map is read in
    chunks)."""
    lo = hi = None
    for i in range(0, len(poses), chunk):
        a = xzy_angles(np.asarray(poses[i:i + chunk]))
        lo = a.min(0) if lo is None else np.minimum(lo, a.min(0))
        hi = a.max(0) if hi is None else np.maximum(hi, a.max(0))
    if lo is None:
        raise ValueError("no training poses to take the range from (the training split is empty)")
    return np.stack([lo, hi], -1)


def outside_range(angles: np.ndarray, rng: np.ndarray, tol: float) -> np.ndarray:
    """(N, J, 3) bool: angle (N, J, 3) below min - tol or above max + tol of rng (J, 3, 2)."""
    return (angles < rng[..., 0] - tol) | (angles > rng[..., 1] + tol)


def other_angles(angles: np.ndarray) -> np.ndarray:
    """(..., 3) the other Euler angles (x, y, z) of the same rotations: (x + 180, y + 180, 180 - z), each in
    [-180, 180) (Rx(x + 180) Rz(180 - z) Ry(y + 180) = Rx(x) Rz(z) Ry(y))."""
    a = np.asarray(angles, dtype=np.float64)
    b = np.stack([a[..., 0] + 180.0, a[..., 1] + 180.0, 180.0 - a[..., 2]], -1)
    return (b + 180.0) % 360.0 - 180.0


def nearest_in_range(poses, rng: np.ndarray, tol: float = 0.0, steps: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """The nearest rotation a range holds, per joint: poses (N, J, 3, 3), rng (J, 3, 2) degrees ->
    (angles (N, J, 3) degrees inside rng, their rotation's geodesic distance (N, J) degrees from the pose's).

    A joint whose angles (either decomposition, `other_angles`) are inside rng within tol is itself, at
    distance 0. The others are searched by projected gradient descent on the Frobenius distance, from both
    decompositions clipped into the box, the nearer result kept: inside the box by construction, a local
    optimum (the box is small against a half turn, where the distance has one minimum)."""
    p = np.asarray(poses, dtype=np.float64)
    a = xzy_angles(p)
    b = other_angles(a)
    lo, hi = np.broadcast_to(rng[..., 0], a.shape), np.broadcast_to(rng[..., 1], a.shape)
    in_a, in_b = ~outside_range(a, rng, tol).any(-1), ~outside_range(b, rng, tol).any(-1)
    angles = np.where(in_b[..., None] & ~in_a[..., None], b, np.clip(a, lo, hi))
    dist = np.zeros(a.shape[:-1])
    todo = ~(in_a | in_b)
    if todo.any():
        target = torch.from_numpy(p[todo]).repeat(2, 1, 1)
        tlo = torch.from_numpy(np.ascontiguousarray(lo[todo])).repeat(2, 1)
        thi = torch.from_numpy(np.ascontiguousarray(hi[todo])).repeat(2, 1)
        x = torch.cat([torch.from_numpy(np.clip(a[todo], lo[todo], hi[todo])),
                       torch.from_numpy(np.clip(b[todo], lo[todo], hi[todo]))]).requires_grad_(True)
        opt = torch.optim.Adam([x], lr=2.0)  # degrees
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=1e-4)
        for _ in range(steps):
            opt.zero_grad()
            ((euler_xzy_to_matrix(x) - target) ** 2).sum().backward()
            opt.step()
            sched.step()
            with torch.no_grad():
                x.copy_(torch.minimum(torch.maximum(x, tlo), thi))
        x = x.detach()
        d = geodesic_deg(euler_xzy_to_matrix(x).numpy(), target.numpy()).reshape(2, -1)
        pick = d.argmin(0)
        m = int(todo.sum())
        angles[todo] = x.numpy().reshape(2, m, 3)[pick, np.arange(m)]
        dist[todo] = d[pick, np.arange(m)]
    return angles, dist


def range_report(poses, rng: np.ndarray, names: Sequence[str], tol: float) -> dict:
    """What predict.json records: the frames with a joint farther than tol degrees from every rotation rng
    (J, 3, 2) holds (`nearest_in_range`) and, per such frame, that joint's axes outside with their angles
    (degrees) and the joint's distance (`distance_deg`)."""
    a = xzy_angles(poses)
    _, dist = nearest_in_range(poses, rng, tol)
    far = dist > tol  # (N, J)
    out = outside_range(a, rng, 0.0) & far[..., None]
    frames = np.flatnonzero(far.any(1))
    per_frame, distance = {}, {}
    for f in frames.tolist():
        per_frame[str(f)] = {f"{names[j]}.{AXES[k]}": round(float(a[f, j, k]), 3)
                             for j, k in zip(*np.nonzero(out[f]), strict=True)}
        distance[str(f)] = {names[j]: round(float(dist[f, j]), 3) for j in np.flatnonzero(far[f])}
    axes_out = {f"{names[j]}.{AXES[k]}": int(out[:, j, k].sum()) for j, k in zip(*np.nonzero(out.any(0)),
                                                                                  strict=True)}
    return {"frames_outside": frames.tolist(), "num_outside": int(len(frames)), "num_frames": int(len(a)),
            "joint_axes_outside": axes_out, "outside": per_frame, "distance_deg": distance, "tolerance_deg": tol,
            "range_deg": {n: {ax: [round(float(rng[j, k, 0]), 3), round(float(rng[j, k, 1]), 3)]
                              for k, ax in enumerate(AXES)} for j, n in enumerate(names)}}


def range_summary(report: dict) -> str:
    """One line for the console."""
    n, total = report["num_outside"], report["num_frames"]
    if not n:
        return f"all {total} frames are inside the training poses' joint-angle range"
    worst = sorted(report["joint_axes_outside"].items(), key=lambda kv: -kv[1])[:4]
    return (f"{n} of {total} frames have joint angles outside the training poses' range (the network "
            f"extrapolates there; frames in predict.json 'pose_range'): "
            + ", ".join(f"{k} in {v} frames" for k, v in worst)
            + ("" if report.get("clamped") else "; --clamp-to-range clamps them"))


def clamp_to_range(poses, rng: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Poses (N, J, 3, 3) with every joint moved to the nearest rotation rng (J, 3, 2) holds
    (`nearest_in_range`); joints within tol degrees of one are returned unchanged."""
    p = np.array(poses, dtype=np.float64)
    angles, dist = nearest_in_range(p, rng, tol)
    out = dist > tol  # (N, J)
    if out.any():
        p[out] = euler_xzy_to_matrix(torch.from_numpy(angles[out])).numpy()
    return p


def range_record(poses, names: Sequence[str], split: str = "train") -> dict:
    """What a run records of its training poses (N, J, 3, 3) (pbc.core.runs.RunRecord.pose_range, written by
    pbc.train): the per-joint, per-axis [min, max] degrees (`angle_range`) keyed by joint name, so predict
    compares new poses with it without the dataset."""
    return range_table_record(angle_range(poses), names, len(poses), split)


def range_table_record(rng: np.ndarray, names: Sequence[str], num_poses: int, split: str = "train") -> dict:
    """`range_record` of a range rng (J, 3, 2) degrees already taken over `num_poses` poses."""
    return {"split": split, "poses": int(num_poses),
            "angles": "the body's Euler angles x, y, z, R = Rx Rz Ry about the joint's rest frame (conf/body)",
            "deg": {n: {ax: [float(rng[j, k, 0]), float(rng[j, k, 1])] for k, ax in enumerate(AXES)}
                    for j, n in enumerate(names)}}


def range_from_record(record: dict | None, names: Sequence[str]) -> np.ndarray | None:
    """`range_record`'s table as (J, 3, 2) degrees in the joint order `names`; None when there is no record
    or it lacks one of the joints (a record of another body: the caller takes the range elsewhere)."""
    deg = (record or {}).get("deg") or {}
    if not deg or any(n not in deg for n in names):
        return None
    return np.array([[deg[n][ax] for ax in AXES] for n in names], dtype=np.float64)
