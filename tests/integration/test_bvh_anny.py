"""A real CMU walk (tests/data/bvh/cmu_mb_02_01_walk.bvh) drives the real body's legs: with body=anny every
joint of the clip's table reaches a body joint (hips, knees, ankles, forearms and hands included), the knees
bend as the file's do, and the posed body's legs move. No garment model is needed: this is the pose path
that `pbc predict RUN --poses clip.bvh` runs for a model trained on Anny."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pbc.geometry.body.base import pose_body
from pbc.geometry.body.skeleton import forward_kinematics
from pbc.motion.bvh import Bvh, read_bvh
from pbc.motion.retarget import bvh_to_poses, choose_joint_map

WALK = Path(__file__).resolve().parents[1] / "data" / "bvh" / "cmu_mb_02_01_walk.bvh"
LEGS = {"l": ("LeftUpLeg", "LeftLeg", "LeftFoot"), "r": ("RightUpLeg", "RightLeg", "RightFoot")}
# a walking knee straightens to about 0-15 degrees at heel strike and bends to 60-70 in swing; the excerpt
# (every 10th frame over 1.25 s, one gait cycle) must show most of that
KNEE_SWING_DEG = (40.0, 90.0)  # (least max - min over the clip, most flexion)


def joint_positions(skel, poses: np.ndarray, joint: str) -> np.ndarray:
    """(N, 3) the head of `joint` posed by poses (N, J, 3, 3), root axes."""
    j = skel.index(joint)
    t = forward_kinematics(skel, torch.from_numpy(poses)).numpy()[:, 1 + j]
    return t[:, :3, :3] @ skel.rest_heads.double().numpy()[j] + t[:, :3, 3]


def file_positions(bvh: Bvh, name: str) -> np.ndarray:
    """(F, 3) joint `name`'s position by the file's own kinematics, root rotation and translation removed."""
    rel = bvh.root_relative_rotations()
    chain, k = [], bvh.names.index(name)
    while bvh.joints[k].parent >= 0:
        chain.append(k)
        k = bvh.joints[k].parent
    p = np.zeros((bvh.num_frames, 3))
    for k in reversed(chain):
        p = p + rel[:, bvh.joints[k].parent] @ bvh.joints[k].offset
    return p


def bend(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N,) degrees between segments a->b and b->c (0: straight)."""
    u, v = b - a, c - b
    cos = (u * v).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_a_cmu_walk_drives_annys_legs(anny_body):
    skel = anny_body.skeleton
    bvh = read_bvh(WALK)
    m = bvh_to_poses(bvh, skel, choose_joint_map(bvh))
    assert m.table.name == "cmu_mb" and m.units == "cmu" and m.missing == [] and m.unknown == []
    assert {m.mapped[f"{s}_{j}"] for s in "lr" for j in ("hip", "knee", "ankle")} == {
        n for leg in LEGS.values() for n in leg}
    for side, (hip, knee, ankle) in LEGS.items():
        body_knee = bend(*(joint_positions(skel, m.poses, f"{side}_{j}") for j in ("hip", "knee", "ankle")))
        file_knee = bend(*(file_positions(bvh, n) for n in (hip, knee, ankle)))
        np.testing.assert_allclose(body_knee, file_knee, atol=1e-3)  # the knee bends as the file's does
        walk = body_knee[1:]  # frame 0 is the converter's calibration pose (legs straight)
        assert walk.max() - walk.min() > KNEE_SWING_DEG[0] and walk.max() < KNEE_SWING_DEG[1], (side, walk)
        # the posed body: the shin's skin follows the knee (vertices skinned mostly to the knee's column)
        shin = anny_body.weights[:, 1 + skel.index(f"{side}_knee")] > 0.5
        verts = pose_body(anny_body, torch.from_numpy(m.poses).float())[:, shin]
        straight, bent = int(np.argmin(walk)) + 1, int(np.argmax(walk)) + 1
        moved = (verts[bent] - verts[straight]).norm(dim=-1).mean()
        assert int(shin.sum()) > 100 and float(moved) > 0.05, (side, int(shin.sum()), float(moved))
