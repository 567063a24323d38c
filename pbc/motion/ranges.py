"""Poses against what a model saw: joint angles vs the training data's range, flags and clamping.

The training range of a run is the per-joint, per-axis [min, max] of its training split's joint angles
(`PoseRange`), in one of two charts of a joint's rotation about its rest frame, per axis x, y, z, degrees:
- `SWING_TWIST` (what runs record): the swing that turns the bone (local y) from its rest direction, as axis
  times angle (x, z), then the twist about the bone (y) (pbc.geometry.body.skeleton.swing_twist_angles);
- `EULER`: the body's Euler angles R = Rx Rz Ry (conf/body), the ones the pose sampler draws within the joint
  limits; runs recorded before the swing-twist chart hold these.
Euler angles are singular where a T-posed arm hangs down (z near -90: x and y turn about nearly one axis), the
posture real motion holds most: a box of them misses a hanging arm swung 10 degrees back with its twist
unchanged (x -100, y +100 against a box of +-60), or holds one never seen. The swing-twist chart is singular
only for a bone turned fully about, which no joint reaches.

A rotation is inside a range when some rotation the range holds equals it (for Euler boxes also through the
angles' other decomposition, x + 180, y + 180, 180 - z). `nearest_in_range` searches the box for the nearest
rotation; the flag and the clamp both read it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch

from pbc.core.runs import POSE_CHARTS, check_pose_range
from pbc.geometry.body.skeleton import AXES, geodesic_deg, swing_twist_angles, swing_twist_to_matrix, xzy_angles
from pbc.sim.poses import euler_xzy_to_matrix

EULER, SWING_TWIST = POSE_CHARTS  # a record without a chart is EULER's: runs recorded those first
CHART_TEXT = {
    EULER: "the body's Euler angles x, y, z, R = Rx Rz Ry about the joint's rest frame (conf/body)",
    SWING_TWIST: "swing and twist about the joint's rest frame: x and z the swing turning the bone (local y) from "
                 "its rest direction, as axis times angle; y the twist about the bone after it",
}


class PoseRange(NamedTuple):
    """A training range: deg (J, 3, 2) per joint and axis [min, max] degrees, in `chart` (EULER or
    SWING_TWIST)."""

    deg: np.ndarray
    chart: str = SWING_TWIST


def joint_angles(poses, chart: str = SWING_TWIST) -> np.ndarray:
    """Rotations (..., 3, 3) -> their angles (..., 3) degrees in `chart`."""
    if chart == EULER:
        return xzy_angles(poses)
    if chart == SWING_TWIST:
        return swing_twist_angles(poses)
    raise ValueError(f"unknown joint-angle chart {chart!r}: one of {EULER!r}, {SWING_TWIST!r}")


def angles_to_matrix(angles: torch.Tensor, chart: str) -> torch.Tensor:
    """Angles (..., 3) degrees in `chart` -> rotations (..., 3, 3); the inverse of `joint_angles`."""
    return euler_xzy_to_matrix(angles) if chart == EULER else swing_twist_to_matrix(angles)


def angle_range(poses, chunk: int = 4096, chart: str = SWING_TWIST) -> PoseRange:
    """The per joint and axis [min, max] degrees over poses (N, J, 3, 3) in `chart` (a memory map is read in
    chunks)."""
    lo = hi = None
    for i in range(0, len(poses), chunk):
        a = joint_angles(np.asarray(poses[i:i + chunk]), chart)
        lo = a.min(0) if lo is None else np.minimum(lo, a.min(0))
        hi = a.max(0) if hi is None else np.maximum(hi, a.max(0))
    if lo is None:
        raise ValueError("no training poses to take the range from (the training split is empty)")
    return PoseRange(np.stack([lo, hi], -1), chart)


def outside_range(angles: np.ndarray, rng: np.ndarray, tol: float) -> np.ndarray:
    """(N, J, 3) bool: angle (N, J, 3) below min - tol or above max + tol of rng (J, 3, 2)."""
    return (angles < rng[..., 0] - tol) | (angles > rng[..., 1] + tol)


def other_angles(angles: np.ndarray) -> np.ndarray:
    """(..., 3) the other Euler angles (x, y, z) of the same rotations: (x + 180, y + 180, 180 - z), each in
    [-180, 180) (Rx(x + 180) Rz(180 - z) Ry(y + 180) = Rx(x) Rz(z) Ry(y))."""
    a = np.asarray(angles, dtype=np.float64)
    b = np.stack([a[..., 0] + 180.0, a[..., 1] + 180.0, 180.0 - a[..., 2]], -1)
    return (b + 180.0) % 360.0 - 180.0


def nearest_in_range(poses, rng: PoseRange, tol: float = 0.0, steps: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """The nearest rotation a range holds, per joint: poses (N, J, 3, 3), rng (deg (J, 3, 2)) ->
    (angles (N, J, 3) degrees in rng's chart inside its box, their rotation's geodesic distance (N, J) degrees
    from the pose's).

    A joint whose angles (for an Euler box either decomposition, `other_angles`) are inside the box within tol
    is itself, at distance 0. The others are searched by projected gradient descent on the Frobenius distance,
    from each decomposition clipped into the box, the nearest result kept: inside the box by construction, a
    local optimum (the box is small against a half turn, where the distance has one minimum)."""
    p = np.asarray(poses, dtype=np.float64)
    box, chart = rng
    a = joint_angles(p, chart)
    starts = [a, other_angles(a)] if chart == EULER else [a]
    lo, hi = np.broadcast_to(box[..., 0], a.shape), np.broadcast_to(box[..., 1], a.shape)
    inside = [~outside_range(s, box, tol).any(-1) for s in starts]
    angles = np.clip(a, lo, hi)
    for s, held in zip(starts[::-1], inside[::-1], strict=True):  # the first decomposition that is held wins
        angles = np.where(held[..., None], s, angles)
    dist = np.zeros(a.shape[:-1])
    todo = ~np.logical_or.reduce(inside)
    if todo.any():
        k = len(starts)
        target = torch.from_numpy(p[todo]).repeat(k, 1, 1)
        tlo = torch.from_numpy(np.ascontiguousarray(lo[todo])).repeat(k, 1)
        thi = torch.from_numpy(np.ascontiguousarray(hi[todo])).repeat(k, 1)
        x = torch.cat([torch.from_numpy(np.clip(s[todo], lo[todo], hi[todo])) for s in starts]).requires_grad_(True)
        opt = torch.optim.Adam([x], lr=2.0)  # degrees
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=1e-4)
        for _ in range(steps):
            opt.zero_grad()
            ((angles_to_matrix(x, chart) - target) ** 2).sum().backward()
            opt.step()
            sched.step()
            with torch.no_grad():
                x.copy_(torch.minimum(torch.maximum(x, tlo), thi))
        x = x.detach()
        d = geodesic_deg(angles_to_matrix(x, chart).numpy(), target.numpy()).reshape(k, -1)
        pick = d.argmin(0)
        m = int(todo.sum())
        angles[todo] = x.numpy().reshape(k, m, 3)[pick, np.arange(m)]
        dist[todo] = d[pick, np.arange(m)]
    return angles, dist


def range_report(poses, rng: PoseRange, names: Sequence[str], tol: float) -> dict:
    """What predict.json records: the frames with a joint farther than tol degrees from every rotation rng
    holds (`nearest_in_range`) and, per such frame, that joint's axes outside with their angles (degrees, in
    rng's chart) and the joint's distance (`distance_deg`)."""
    a = joint_angles(poses, rng.chart)
    _, dist = nearest_in_range(poses, rng, tol)
    far = dist > tol  # (N, J)
    out = outside_range(a, rng.deg, 0.0) & far[..., None]
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
            "chart": rng.chart, "angles": CHART_TEXT[rng.chart],
            "range_deg": {n: {ax: [round(float(rng.deg[j, k, 0]), 3), round(float(rng.deg[j, k, 1]), 3)]
                              for k, ax in enumerate(AXES)} for j, n in enumerate(names)}}


def range_summary(report: dict) -> str:
    """One line for the console: the frames past what the model knows (report["known"], pbc.motion.known) and
    the guard taken, else the frames outside the joint-angle range."""
    known, guard = report.get("known"), report.get("guard")
    if known:
        n, total = known["num_flagged"], report["num_frames"]
        how = {"nearest": "turned towards their nearest training pose to the limit, joints clamped into its range",
               "range": "clamped into the training poses' joint-angle range",
               "none": "predicted as they are (--guard nearest turns them towards the data)"}.get(guard, guard)
        return (f"{n} of {total} frames are past the model's data (their nearest training pose more than "
                f"{known['limit_deg']:.1f} degrees away, RMS over the {len(known['read_joints'])} joints it reads; "
                f"predict.json pose_range.known)" + (f": {how}" if n else ""))
    n, total = report["num_outside"], report["num_frames"]
    if not n:
        return f"all {total} frames are inside the training poses' joint-angle range"
    worst = sorted(report["joint_axes_outside"].items(), key=lambda kv: -kv[1])[:4]
    return (f"{n} of {total} frames have joint angles outside the training poses' range (the network "
            f"extrapolates there; frames in predict.json 'pose_range'): "
            + ", ".join(f"{k} in {v} frames" for k, v in worst)
            + (" (swing-twist axes: x, z the swing, y the twist)" if report.get("chart") == SWING_TWIST else "")
            + ("" if report.get("clamped") else "; --guard range clamps them"))


def clamp_to_range(poses, rng: PoseRange, tol: float = 0.0) -> np.ndarray:
    """Poses (N, J, 3, 3) with every joint moved to the nearest rotation rng holds (`nearest_in_range`);
    joints within tol degrees of one are returned unchanged."""
    p = np.array(poses, dtype=np.float64)
    angles, dist = nearest_in_range(p, rng, tol)
    out = dist > tol  # (N, J)
    if out.any():
        p[out] = angles_to_matrix(torch.from_numpy(angles[out]), rng.chart).numpy()
    return p


def range_record(poses, names: Sequence[str], split: str = "train") -> dict:
    """What a run records of its training poses (N, J, 3, 3) (pbc.core.runs.RunRecord.pose_range, written by
    pbc.train): the per-joint, per-axis [min, max] degrees (`angle_range`, swing-twist) keyed by joint name, so
    predict compares new poses with it without the dataset."""
    return range_table_record(angle_range(poses), names, len(poses), split)


def range_table_record(rng: PoseRange, names: Sequence[str], num_poses: int, split: str = "train") -> dict:
    """`range_record` of a range already taken over `num_poses` poses."""
    return {"split": split, "poses": int(num_poses), "chart": rng.chart, "angles": CHART_TEXT[rng.chart],
            "deg": {n: {ax: [float(rng.deg[j, k, 0]), float(rng.deg[j, k, 1])] for k, ax in enumerate(AXES)}
                    for j, n in enumerate(names)}}


def range_from_record(record: dict | None, names: Sequence[str]) -> PoseRange | None:
    """`range_record`'s table as a PoseRange in the joint order `names` (a record without a chart is of the
    Euler angles: runs recorded those before); None when there is no record or it lacks one of the joints (a
    record of another body: the caller takes the range elsewhere)."""
    deg = (record or {}).get("deg") or {}
    if not deg or any(n not in deg for n in names):
        return None
    check_pose_range(record)  # the run record's own check: its chart among POSE_CHARTS, finite [min, max]
    return PoseRange(np.array([[deg[n][ax] for ax in AXES] for n in names], dtype=np.float64),
                     record.get("chart", EULER))
