"""pbc.motion.known: the distance to the nearest training pose (the flags, the guard) on random rotations,
checked against a brute-force geodesic search; the guard's pull lands on the limit and moves nothing else."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pbc.geometry.meshops import edge_stretch, median_edge_lengths, mesh_edges
from pbc.motion.known import nearest_known, pull_towards_known


def rotations(n, j, deg, seed):
    rng = np.random.default_rng(seed)
    return Rotation.from_rotvec(rng.normal(size=(n * j, 3)) * np.radians(deg) / np.sqrt(3)).as_matrix().reshape(
        n, j, 3, 3)


def geodesic_deg(a, b):
    return np.degrees(Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b).magnitude())


def test_nearest_is_the_brute_force_nearest_and_its_distance_an_rms_angle():
    known = rotations(200, 5, 40, seed=0)
    poses = rotations(30, 5, 40, seed=1)
    joints = [0, 2, 3]
    near = nearest_known(poses, known, joints, chunk=7)  # chunks of 7 give what one block gives
    for n in range(len(poses)):
        ang = np.stack([geodesic_deg(poses[n, j], known[:, j]) for j in joints], 1)  # (M, 3) degrees
        chordal = (8 * np.sin(np.radians(ang) / 2) ** 2).sum(1)
        k = int(chordal.argmin())
        assert near.index[n] == k
        # the RMS angle: every read joint turned by it gives the same chordal distance
        assert (8 * len(joints) * np.sin(np.radians(near.distance_deg[n]) / 2) ** 2) == pytest.approx(chordal[k])
        assert near.worst_joint_deg[n] == pytest.approx(ang[k].max(), abs=1e-3)
    # a known pose is at distance 0 from itself, whatever the unread joints do
    same = known[:3].copy()
    same[:, 1] = rotations(3, 1, 90, seed=2)[:, 0]
    assert nearest_known(same, known, joints).distance_deg == pytest.approx(0, abs=1e-3)


def test_pull_lands_on_the_limit_and_leaves_near_poses_and_unread_joints():
    known = rotations(50, 4, 20, seed=3)
    poses = rotations(20, 4, 120, seed=4)
    joints = [0, 1, 3]
    near = nearest_known(poses, known, joints)
    limit = float(np.median(near.distance_deg))
    out = pull_towards_known(poses, known, joints, near, limit)
    after = nearest_known(out, known, joints).distance_deg
    far = near.distance_deg > limit
    assert far.any() and (~far).any()
    # each far frame is at the limit from the pose it was turned towards, and no farther from the nearest
    to_target = np.array([nearest_known(out[n:n + 1], known[near.index[n]][None], joints).distance_deg[0]
                          for n in np.flatnonzero(far)])
    assert np.allclose(to_target, limit, atol=0.01) and (after[far] <= limit + 0.01).all()
    assert np.array_equal(out[~far], poses[~far])  # frames within the limit: untouched
    assert np.array_equal(out[:, 2], poses[:, 2])  # an unread joint: untouched
    assert np.allclose(np.swapaxes(out, -1, -2) @ out, np.eye(3), atol=1e-9)  # still rotations


def test_edge_stretch_is_the_longest_edge_over_its_usual_length():
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    edges = mesh_edges(faces)
    assert edges.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    square = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    usual = np.linalg.norm(square[edges[:, 0]] - square[edges[:, 1]], axis=1)
    torn = square.copy()
    torn[2] = [1, 4, 0]  # vertex 2 pulled away: edge 2-3 from 1 to sqrt(10), edge 1-2 from 1 to 4
    assert edge_stretch(np.stack([square, torn]), edges, usual) == pytest.approx([1.0, 4.0])
    # the usual lengths: each edge's median over meshes
    assert median_edge_lengths(np.stack([square, square, torn]), edges) == pytest.approx(usual)
