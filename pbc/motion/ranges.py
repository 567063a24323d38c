"""Poses against what a model saw: joint angles vs the training data's range, flags and clamping.

Angles are the body's own Euler angles (conf/body: R = Rx Rz Ry about the joint's rest frame, per axis
x, y, z, degrees), the ones the pose sampler draws within the joint limits. The training range of a run is
the per-joint, per-axis [min, max] over its dataset's training split.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from pbc.geometry.body.skeleton import AXES, xzy_angles
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


def range_report(poses, rng: np.ndarray, names: Sequence[str], tol: float) -> dict:
    """What predict.json records: the frames outside rng (J, 3, 2) and, per such frame, each joint axis
    outside with its angle (degrees)."""
    a = xzy_angles(poses)
    out = outside_range(a, rng, tol)
    frames = np.flatnonzero(out.any((1, 2)))
    per_frame = {}
    for f in frames.tolist():
        per_frame[str(f)] = {f"{names[j]}.{AXES[k]}": round(float(a[f, j, k]), 3)
                             for j, k in zip(*np.nonzero(out[f]), strict=True)}
    axes_out = {f"{names[j]}.{AXES[k]}": int(out[:, j, k].sum()) for j, k in zip(*np.nonzero(out.any(0)),
                                                                                  strict=True)}
    return {"frames_outside": frames.tolist(), "num_outside": int(len(frames)), "num_frames": int(len(a)),
            "joint_axes_outside": axes_out, "outside": per_frame, "tolerance_deg": tol,
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
    """Poses (N, J, 3, 3) with every joint angle clamped into rng (J, 3, 2); joints inside (within tol)
    are returned unchanged, the others rebuilt from their clamped angles."""
    p = np.array(poses, dtype=np.float64)
    a = xzy_angles(p)
    out = outside_range(a, rng, tol).any(-1)  # (N, J)
    if out.any():
        clamped = np.clip(a[out], rng[None, ..., 0].repeat(len(p), 0)[out], rng[None, ..., 1].repeat(len(p), 0)[out])
        p[out] = euler_xzy_to_matrix(torch.from_numpy(clamped)).numpy()
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
