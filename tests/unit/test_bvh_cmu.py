"""Real CMU mocap files (tests/data/bvh/, where each comes from and what it broke): both BVH releases read
with the right table, every joint mapped or knowingly ignored, per-joint Euler orders, units, frame time,
the two dialects of the same instant giving the same body pose, and a walk giving a walk's arms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.geometry.body.skeleton import forward_kinematics, skeleton_from_config, xzy_angles
from pbc.motion.bvh import read_bvh
from pbc.motion.fit import clear_clip_arms, cleared_note
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, parse_frames
from pbc.sim.poses import SamplingSettings, arm_depth_in_torso, arm_probe_indices

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "bvh"
SKEL = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
CMU_UNIT = 0.05644  # m: the CMU ASF length unit (1/0.45 inch), conf/motion/sequence.yaml
# the first walk frame's upper arms hang within this of straight down, in every walk frame kept: the arm
# swing of normal gait is about 20-25 degrees either side of vertical; the T-pose rest is 90 degrees away
ARM_SWING_DEG = 30.0
TORSO_LEAN_DEG = 15.0  # the upper spine within this of vertical while walking (the measured lean: 7-11)


def mapped_clip(name: str, frames: str | None = None):
    bvh = read_bvh(DATA / name)
    return bvh, bvh_to_poses(bvh, SKEL, choose_joint_map(bvh), parse_frames(frames))


def bone_directions(poses: np.ndarray, joint: str) -> np.ndarray:
    """(N, 3) the body's `joint` bone direction (its rest frame's y axis) at poses (N, J, 3, 3), root axes."""
    j = SKEL.index(joint)
    transforms = forward_kinematics(SKEL, torch.from_numpy(poses)).numpy()
    return transforms[:, 1 + j, :3, :3] @ SKEL.frames().double().numpy()[j][:, 1]


def degrees_between(a: np.ndarray, b) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(a @ np.asarray(b, float), -1.0, 1.0)))


@pytest.mark.parametrize(("name", "table", "frames", "orders"), [
    ("cmu_mb_02_01_walk.bvh", "cmu_mb", 16, {"ZYX"}),
    ("cmu_mb_01_01_lfingers.bvh", "cmu_mb", 4, {"ZYX"}),
    ("cmu_max_01_01.bvh", "cmu_max", 1, {"ZYX", "ZXY"}),
])
def test_real_cmu_files_read_with_their_table(name, table, frames, orders):
    bvh, m = mapped_clip(name)
    assert len(bvh.joints) == 31 and bvh.num_frames == frames and bvh.motion.shape[1] == 6 + 30 * 3
    assert {j.rotation_order for j in bvh.joints} == orders  # each joint's own CHANNELS order
    assert m.table.name == table and m.units == "cmu" and m.metres_per_unit == CMU_UNIT
    assert np.allclose(m.axes, np.eye(3))  # Y up, Z forward, as the body
    # every joint of the file is in its table: mapped, or a bone the mannequin lacks (legs, forearms, hands)
    assert m.unknown == [] and m.missing == [] and set(m.mapped) == set(SKEL.names)
    assert set(m.mapped.values()) | set(m.ignored) | {"Hips"} == set(bvh.names)
    assert not any("not in the joint map" in n for n in m.notes)


def test_frame_time_and_fps():
    walk, _ = mapped_clip("cmu_mb_02_01_walk.bvh")
    assert walk.frame_time == pytest.approx(0.083333)  # the excerpt keeps every 10th frame of 120 fps
    _, m = mapped_clip("cmu_max_01_01.bvh")
    assert m.fps == pytest.approx(120.0, rel=1e-4)  # "Frame Time: .0083333" (no leading zero)


def test_the_max_arms_order_is_read_per_joint():
    bvh = read_bvh(DATA / "cmu_max_01_01.bvh")
    orders = {j.name: j.rotation_order for j in bvh.joints}
    assert orders["LeftCollar"] == "ZYX" and orders["LeftShoulder"] == "ZXY" and orders["LeftElbow"] == "ZXY"


def test_both_releases_of_one_instant_give_the_same_body_pose():
    """Frame 1 of CMU 01_01 in the MotionBuilder release and the same instant in the 3ds Max release: other
    joint names, another rest pose (T vs arms down), other Euler orders on the arms; the body's pose must be
    the same. (Before the tables were checked against these files the neck differed: cmu_max's neck rows
    were shifted by one joint.)"""
    _, mb = mapped_clip("cmu_mb_01_01_lfingers.bvh", "1")
    _, mx = mapped_clip("cmu_max_01_01.bvh")
    np.testing.assert_allclose(mx.poses, mb.poses, atol=1e-6)


def test_a_walk_has_a_walks_arms_and_they_follow_the_file():
    """CMU 02_01 (walk). The body's rest is a T-pose, so walking arms are far from rest: each upper arm hangs
    within ARM_SWING_DEG of straight down in every walk frame (frames 1-15), while frame 0 (the converter's
    calibration pose, arms near horizontal) is more than 60 degrees from down. And the body's upper-arm
    direction is the file's own (its forward kinematics, root rotation removed) to 1e-4 degrees."""
    bvh, m = mapped_clip("cmu_mb_02_01_walk.bvh")
    down, up = [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]
    for arm in ("l_arm", "r_arm"):
        off_down = degrees_between(bone_directions(m.poses, arm), down)
        assert off_down[0] > 60.0 and (off_down[1:] < ARM_SWING_DEG).all(), (arm, off_down.round(1))
    assert (degrees_between(bone_directions(m.poses[1:], "spine1"), up) < TORSO_LEAN_DEG).all()
    rel = bvh.root_relative_rotations()
    for arm, (joint, child) in {"l_arm": ("LeftArm", "LeftForeArm"), "r_arm": ("RightArm", "RightForeArm")}.items():
        child_offset = bvh.joints[bvh.names.index(child)].offset
        in_file = rel[:, bvh.names.index(joint)] @ child_offset
        body = bone_directions(m.poses, arm)
        cos = np.einsum("na,na->n", in_file / np.linalg.norm(in_file, axis=1, keepdims=True), body)
        assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 1e-4


def test_a_walk_on_a_broader_body_gets_its_arms_out_of_the_torso(body):
    """The CMU walk retargeted onto the mannequin hangs an arm inside its torso in some frames: every door that
    takes a clip (read_motion: pbc predict and view; data.poses) raises those arms just out of it and says so;
    frames already clear keep their exact rotations; max_deg 0 keeps the clip as retargeted."""
    _, motion = mapped_clip("cmu_mb_02_01_walk.bvh", "1:")
    probes = arm_probe_indices(body, SamplingSettings())
    before = arm_depth_in_torso(body, torch.from_numpy(motion.poses).float(), probes).numpy()
    assert (before > 0).any()  # the premise: this clip on this body has an arm in the torso
    cleared, turned = clear_clip_arms(motion.poses, body, OmegaConf.create({"step_deg": 2.0, "max_deg": 40.0}))
    after = arm_depth_in_torso(body, torch.from_numpy(cleared).float(), probes).numpy()
    assert (after == 0).all() and ((turned > 0) == (before > 0)).all() and turned.max() < 40
    still = ~(turned > 0).any(1)
    assert np.array_equal(cleared[still], motion.poses[still]) and cleared.dtype == motion.poses.dtype
    note = cleared_note(turned)
    assert note.startswith(f"arms raised out of the torso in {int((~still).sum())} of {len(turned)} frames")
    same, none = clear_clip_arms(motion.poses, body, OmegaConf.create({"step_deg": 2.0, "max_deg": 0.0}))
    assert same is motion.poses and not none.any() and cleared_note(none) is None


def test_a_walks_feet_on_a_body_whose_ankle_ends_the_chain(anny_body):
    """Anny's ankle has no child joint in pbc's skeleton (its frame's y runs down the shin) and the CMU foot
    points forward to the toes: the feet are aligned as the shins, so the clip's calibration frame (a T-pose
    standing on flat feet) leaves the ankles at rest, and the walk flexes them as a walk does (within 30
    degrees), instead of every frame turning them about 70 degrees."""
    bvh = read_bvh(DATA / "cmu_mb_02_01_walk.bvh")
    skel = anny_body.skeleton
    m = bvh_to_poses(bvh, skel, choose_joint_map(bvh), parse_frames(None))
    angles = xzy_angles(m.poses)
    for ankle in ("l_ankle", "r_ankle"):
        j = skel.index(ankle)
        assert np.abs(angles[0, j]).max() < 5.0, (ankle, angles[0, j])
        assert np.abs(angles[1:, j]).max() < 30.0, (ankle, angles[1:, j].min(0), angles[1:, j].max(0))
        assert np.ptp(angles[1:, j, 0]) > 10.0  # and they do move with the gait
