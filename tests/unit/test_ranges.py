"""The training-range test on rotations, not on their angles: pbc.motion.ranges.nearest_in_range against a
brute-force search of the box, near the Euler angles' singular point where the angles alone mislead, in both
charts (Euler, and the swing-twist chart runs record)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pbc.geometry.body.skeleton import swing_twist_to_matrix, xzy_angles
from pbc.motion.ranges import (
    EULER,
    SWING_TWIST,
    PoseRange,
    angle_range,
    clamp_to_range,
    geodesic_deg,
    joint_angles,
    nearest_in_range,
    other_angles,
    range_report,
    range_summary,
)
from pbc.sim.poses import euler_xzy_to_matrix

# one joint, a T-posed arm hanging down: z (the middle angle) near -90, where x and y turn about nearly one axis
HANGING = PoseRange(np.array([[[-10.0, 10.0], [-10.0, 10.0], [-95.0, -80.0]]]), EULER)


def rot(*angles) -> np.ndarray:
    """(N, 1, 3, 3) rotations of (x, y, z) degree triples."""
    return euler_xzy_to_matrix(torch.tensor(angles, dtype=torch.float64)).numpy()[:, None]


def brute_force_distance(r: np.ndarray, box: np.ndarray, chart: str = EULER, n: int = 41) -> float:
    """The naive reference: the smallest geodesic distance (deg) from r (3, 3) to an n^3 grid over box (3, 2) of
    angles in chart."""
    grid = np.array(list(itertools.product(*(np.linspace(lo, hi, n) for lo, hi in box))))
    to_matrix = euler_xzy_to_matrix if chart == EULER else swing_twist_to_matrix
    return float(geodesic_deg(to_matrix(torch.from_numpy(grid)).numpy(), r[None]).min())


def test_other_angles_are_the_same_rotation():
    a = np.random.default_rng(0).uniform(-170, 170, (64, 3))
    b = other_angles(a)
    assert np.all((b >= -180) & (b < 180)) and not np.allclose(a, b)
    np.testing.assert_allclose(euler_xzy_to_matrix(torch.from_numpy(b)).numpy(),
                               euler_xzy_to_matrix(torch.from_numpy(a)).numpy(), atol=1e-12)


def test_a_rotation_the_box_holds_is_inside_whatever_its_own_angles_say():
    # inside the box at z = -89.9; a turn of 0.2 degrees takes its own decomposition to x = 175, y = -175
    held = rot([5.0, -5.0, -89.9])[0, 0] @ rot([0.0, 0.0, -0.2])[0, 0]
    own = xzy_angles(held)
    assert abs(own[0]) > 150 and abs(own[1]) > 150  # far outside the box by its own angles
    angles, dist = nearest_in_range(held[None, None], HANGING, 1e-3)
    assert dist[0, 0] < 1e-6
    assert np.all((angles[0, 0] >= HANGING.deg[0, :, 0]) & (angles[0, 0] <= HANGING.deg[0, :, 1]))
    assert range_report(held[None, None], HANGING, ["l_arm"], 1e-3)["frames_outside"] == []


@pytest.mark.parametrize("angles", [[30.0, 0.0, -85.0], [14.0, -14.0, -89.0], [0.0, 40.0, -60.0], [-25.0, 3.0, -99.0]])
def test_nearest_in_range_matches_a_brute_force_search_of_the_box(angles):
    r = rot(angles)
    found, dist = nearest_in_range(r, HANGING, 1e-3)
    assert np.all((found[0, 0] >= HANGING.deg[0, :, 0] - 1e-9) & (found[0, 0] <= HANGING.deg[0, :, 1] + 1e-9))
    # the distance reported is the distance of the angles returned
    assert geodesic_deg(euler_xzy_to_matrix(torch.from_numpy(found[0, 0])).numpy(), r[0, 0]) == pytest.approx(
        dist[0, 0], abs=1e-6)
    reference = brute_force_distance(r[0, 0], HANGING.deg[0])
    assert dist[0, 0] <= reference + 1e-6  # at least as near as the grid's best (grid step 0.4-0.5 degrees)
    assert dist[0, 0] >= reference - 0.5


def test_range_report_and_clamp_agree_on_a_joint_past_the_box():
    poses = np.concatenate([rot([0.0, 0.0, -88.0]), rot([0.0, 0.0, -60.0])])  # inside; 20 degrees past z = -80
    rep = range_report(poses, HANGING, ["l_arm"], 1e-3)
    assert rep["frames_outside"] == [1] and list(rep["outside"]["1"]) == ["l_arm.z"]
    assert rep["distance_deg"]["1"]["l_arm"] == pytest.approx(20.0, abs=1e-3)
    c = clamp_to_range(poses, HANGING, 1e-3)
    np.testing.assert_array_equal(c[0], poses[0])  # inside: untouched
    assert geodesic_deg(c[1, 0], poses[1, 0]) == pytest.approx(20.0, abs=1e-3)
    assert range_report(c, HANGING, ["l_arm"], 1e-3)["frames_outside"] == []


# the same hanging arm in the swing-twist chart: swung down 80-95 degrees about z, up to 10 back or forward
# (about x), twisted up to 10 either way
HANGING_ST = PoseRange(np.array([[[-10.0, 10.0], [-10.0, 10.0], [-95.0, -80.0]]]), SWING_TWIST)


def st_rot(*angles) -> np.ndarray:
    """(N, 1, 3, 3) rotations of swing-twist (x, y, z) degree triples."""
    return swing_twist_to_matrix(torch.tensor(angles, dtype=torch.float64)).numpy()[:, None]


def test_swing_twist_angles_invert_and_read_the_bone_and_its_twist():
    r = Rotation.random(500, random_state=0).as_matrix()
    a = joint_angles(r, SWING_TWIST)
    np.testing.assert_allclose(swing_twist_to_matrix(torch.from_numpy(a)).numpy(), r, atol=1e-12)
    # the naive reference: the swing's angle is the bone's (local y) turn, its axis is y x the posed bone
    bone = r[:, :, 1]
    np.testing.assert_allclose(np.linalg.norm(a[:, [0, 2]], axis=1), np.degrees(np.arccos(bone[:, 1])), atol=1e-9)
    axis = np.cross([0.0, 1.0, 0.0], bone)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    np.testing.assert_allclose(np.radians(a[:, [0, 2]]), (axis * np.radians(np.linalg.norm(a[:, [0, 2]], axis=1,
                                                                                          keepdims=True)))[:, [0, 2]],
                               atol=1e-9)
    # a pure twist about the bone and a pure swing about z read as such
    tw = Rotation.from_euler("y", 37.0, degrees=True).as_matrix()
    sw = Rotation.from_euler("z", -85.0, degrees=True).as_matrix()
    np.testing.assert_allclose(joint_angles(tw, SWING_TWIST), [0.0, 37.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(joint_angles(sw @ tw, SWING_TWIST), [0.0, 37.0, -85.0], atol=1e-9)


def test_a_hanging_arm_swung_back_reads_as_swing_not_as_euler_angles_far_apart():
    # hanging 85 degrees down, swung 8 back, no twist: Euler angles x and y run far apart (49, -44) and cancel
    r = st_rot([8.0, 0.0, -85.0])
    euler = joint_angles(r, EULER)[0, 0]
    assert abs(euler[0]) > 40 and abs(euler[1]) > 40 and abs(euler[0] + euler[1]) < 10
    assert range_report(r, HANGING_ST, ["l_arm"], 1e-3)["frames_outside"] == []
    # swing-twist boxes of poses hold those poses (angle_range's chart), whatever their Euler angles do
    poses = st_rot([9.0, -9.0, -94.0], [-9.0, 9.0, -81.0], [0.0, 0.0, -88.0])
    rng = angle_range(poses)
    assert rng.chart == SWING_TWIST
    assert range_report(poses, rng, ["l_arm"], 1e-3)["frames_outside"] == []


@pytest.mark.parametrize("angles", [[20.0, 0.0, -85.0], [14.0, -14.0, -99.0], [0.0, 40.0, -60.0]])
def test_nearest_in_a_swing_twist_range_matches_a_brute_force_search_of_the_box(angles):
    r = st_rot(angles)
    found, dist = nearest_in_range(r, HANGING_ST, 1e-3)
    box = HANGING_ST.deg[0]
    assert np.all((found[0, 0] >= box[:, 0] - 1e-9) & (found[0, 0] <= box[:, 1] + 1e-9))
    assert geodesic_deg(swing_twist_to_matrix(torch.from_numpy(found[0, 0])).numpy(), r[0, 0]) == pytest.approx(
        dist[0, 0], abs=1e-6)
    reference = brute_force_distance(r[0, 0], box, SWING_TWIST)
    assert reference - 0.5 <= dist[0, 0] <= reference + 1e-6
    c = clamp_to_range(r, HANGING_ST, 1e-3)
    assert range_report(c, HANGING_ST, ["l_arm"], 1e-3)["frames_outside"] == []


def test_the_console_line_names_the_axes_outside_and_their_chart():
    poses = np.concatenate([st_rot([0.0, 0.0, -88.0]), st_rot([0.0, 0.0, -60.0])])  # inside; 20 past z = -80
    line = range_summary(range_report(poses, HANGING_ST, ["l_arm"], 1e-3))
    assert line.startswith("1 of 2 frames have joint angles outside") and "l_arm.z in 1 frames" in line
    assert "swing-twist axes" in line and "--guard range" in line
    assert "swing-twist" not in range_summary(range_report(rot([0.0, 0.0, -60.0]), HANGING, ["l_arm"], 1e-3))
    assert range_summary(range_report(poses[:1], HANGING_ST, ["l_arm"], 1e-3)) == (
        "all 1 frames are inside the training poses' joint-angle range")
