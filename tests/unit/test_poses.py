"""Pose sampling (appendix D.3): Euler convention, limits, determinism, arm-torso pruning, histograms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.geometry.body.skeleton import Skeleton
from pbc.sim.poses import (
    SamplingSettings,
    arm_depth_in_torso,
    arm_probe_indices,
    clear_arms,
    euler_xzy_to_matrix,
    plot_angle_histograms,
    probes_inside_torso,
    sample_angles,
    sample_poses,
    sampling_settings_from_config,
)

BODY_CONFIG = Path(__file__).resolve().parents[2] / "conf" / "body" / "mannequin.yaml"
SMALL = SamplingSettings(block_size=64)  # small blocks keep these tests to a fraction of a second


def _single(deg, axis):
    angles = torch.zeros(3)
    angles["xyz".index(axis)] = deg
    return euler_xzy_to_matrix(angles)


def test_euler_convention_is_x_then_z_then_y():
    angles = torch.tensor([[10.0, 20.0, 30.0], [-70.0, 45.0, 5.0]])  # per axis (x, y, z)
    R = euler_xzy_to_matrix(angles)
    assert R.shape == (2, 3, 3)
    for i, (x, y, z) in enumerate(angles.tolist()):
        expected = _single(x, "x") @ _single(z, "z") @ _single(y, "y")  # intrinsic x, z', y''
        torch.testing.assert_close(R[i], expected)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3).expand(2, 3, 3), atol=1e-6, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(2))
    torch.testing.assert_close(euler_xzy_to_matrix(torch.zeros(4, 10, 3)), torch.eye(3).expand(4, 10, 3, 3))
    # right-handed: +90 about z takes x to y
    torch.testing.assert_close(_single(90.0, "z") @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
    # twist (y) leaves the bone direction (local y) alone
    torch.testing.assert_close(
        euler_xzy_to_matrix(torch.tensor([25.0, 80.0, -40.0]))[:, 1],
        euler_xzy_to_matrix(torch.tensor([25.0, 0.0, -40.0]))[:, 1],
    )
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        euler_xzy_to_matrix(torch.zeros(5, 2))


def test_settings_defaults_match_config():
    assert sampling_settings_from_config(OmegaConf.load(BODY_CONFIG).sampling) == SamplingSettings()
    with pytest.raises(ValueError, match="unknown sampling settings"):
        sampling_settings_from_config({"typo": 1})


def test_sampled_angles_within_limits(skeleton):
    angles = sample_angles(skeleton, 2000, np.random.default_rng(0), SamplingSettings())
    lim = skeleton.limits_deg.double().numpy()
    assert angles.shape == (2000, skeleton.num_joints, 3)
    assert (angles >= lim[..., 0]).all() and (angles <= lim[..., 1]).all()
    # both directions are sampled on every axis of every joint
    assert ((angles < 0).any(axis=0) & (angles > 0).any(axis=0)).all()
    # centre line: half-normals pile up near zero; arm azimuth: uniform (mean near the middle of the range)
    lb = skeleton.index("lower_back")
    assert np.median(np.abs(angles[:, lb, 0])) < 0.25 * (lim[lb, 0, 1] - lim[lb, 0, 0])
    arm = skeleton.index("l_arm")
    mid = lim[arm, 0].mean()
    assert abs(angles[:, arm, 0].mean() - mid) < 0.05 * (lim[arm, 0, 1] - lim[arm, 0, 0])
    # altitude uniform in sine space
    s = np.sin(np.deg2rad(angles[:, arm, 2]))
    s_lo, s_hi = np.sin(np.deg2rad(lim[arm, 2]))
    assert abs(s.mean() - (s_lo + s_hi) / 2) < 0.05 * (s_hi - s_lo)


def test_same_seed_same_poses_and_prefix(skeleton):
    a, sa = sample_poses(skeleton, 100, seed=7, settings=SMALL)
    b, sb = sample_poses(skeleton, 100, seed=7, settings=SMALL)
    c, _ = sample_poses(skeleton, 30, seed=7, settings=SMALL)
    d, _ = sample_poses(skeleton, 100, seed=8, settings=SMALL)
    assert a.shape == (100, skeleton.num_joints, 3, 3) and a.dtype == torch.float32
    assert torch.equal(a, b) and torch.equal(sa["angles_deg"], sb["angles_deg"])
    assert torch.equal(a[:30], c)  # sample i does not depend on n
    assert not torch.equal(a, d)
    torch.testing.assert_close(euler_xzy_to_matrix(sa["angles_deg"]), a)
    assert sa["pruned"] == 0 and sa["kept"] == sa["requested"] == 100


def test_probes_are_fixed_arm_vertices_away_from_the_shoulder(body):
    settings = SamplingSettings()
    probes = arm_probe_indices(body, settings)
    assert torch.equal(probes, arm_probe_indices(body, settings))
    assert len(probes) == 2 * settings.probes_per_arm == len(set(probes.tolist()))
    half = settings.probes_per_arm
    assert body.parts[1, probes[:half]].all() and body.parts[2, probes[half:]].all()
    assert not body.parts[0, probes].any()
    skel = body.skeleton
    for ids, joint in ((probes[:half], "l_arm"), (probes[half:], "r_arm")):
        dist = (body.vertices[ids] - skel.rest_heads[skel.index(joint)]).norm(dim=1)
        assert (dist >= settings.probe_min_distance).all()


def test_pruning_rejects_arm_in_torso(body):
    skel = body.skeleton
    probes = arm_probe_indices(body, SamplingSettings())
    angles = torch.zeros(3, skel.num_joints, 3)
    angles[1, skel.index("l_arm"), 2] = -90.0  # left arm straight down: through the chest's side
    angles[2, skel.index("r_arm"), 0] = -110.0  # right arm swung forward across the chest
    angles[2, skel.index("r_arm"), 2] = -30.0
    inside = probes_inside_torso(body, euler_xzy_to_matrix(angles), probes, SamplingSettings())
    assert inside.tolist() == [False, True, True]


def test_clear_arms_raises_an_arm_just_out_of_the_torso(body):
    """An arm retargeted through the torso is raised sideways (about its rest frame's z, the sampler's
    raising axis) by the smallest step that clears it; an arm outside is left bit for bit, as is every other
    joint. Checked against the sampler's own test (probes_inside_torso) and a turn one step short."""
    skel = body.skeleton
    settings = SamplingSettings()
    probes = arm_probe_indices(body, settings)
    angles = torch.zeros(3, skel.num_joints, 3)
    angles[1, skel.index("l_arm"), 2] = -100.0  # past hanging: into the chest's side
    angles[2, skel.index("r_arm"), 2] = -95.0
    angles[2, skel.index("spine"), 0] = 10.0
    poses = euler_xzy_to_matrix(angles)
    depth = arm_depth_in_torso(body, poses, probes)
    assert depth[0].tolist() == [0.0, 0.0] and depth[1, 0] > 0.01 and depth[2, 1] > 0.005 and depth[1, 1] == 0
    assert ((depth > 0).any(1) == probes_inside_torso(body, poses, probes, settings)).all()
    out, turned = clear_arms(body, poses, settings, step_deg=2.0, max_deg=40.0)
    assert not probes_inside_torso(body, out, probes, settings).any()
    assert turned[0].tolist() == [0.0, 0.0] and turned[1, 1] == 0 and turned[2, 0] == 0
    assert 0 < turned[1, 0] < 40 and 0 < turned[2, 1] < 40
    moved = [(1, skel.index("l_arm"), 0), (2, skel.index("r_arm"), 1)]
    untouched = torch.ones(3, skel.num_joints, dtype=torch.bool)
    for b, j, side in moved:
        untouched[b, j] = False
        raise_by = out[b, j] @ poses[b, j].T  # a turn about z alone, by the recorded angle
        want = euler_xzy_to_matrix(torch.tensor([0.0, 0.0, float(turned[b, side])]))
        torch.testing.assert_close(raise_by, want, atol=1e-5, rtol=0)
        short = poses.clone()  # one step less is still inside: the smallest turn
        short[b, j] = euler_xzy_to_matrix(torch.tensor([0.0, 0.0, float(turned[b, side]) - 2.0])) @ poses[b, j]
        assert arm_depth_in_torso(body, short[b:b + 1], probes)[0, side] > 0
    assert torch.equal(out[untouched], poses[untouched])


def test_sampler_keeps_only_clean_poses(body):
    poses, stats = sample_poses(body.skeleton, 60, seed=3, body=body, settings=SMALL)
    assert poses.shape[0] == stats["kept"] == 60
    assert stats["candidates"] == stats["kept"] + stats["pruned"] and stats["pruned"] > 0
    assert stats["probes"] == 2 * SMALL.probes_per_arm
    probes = arm_probe_indices(body, SMALL)
    assert not probes_inside_torso(body, poses, probes, SMALL).any()
    unpruned, _ = sample_poses(body.skeleton, 60, seed=3, settings=SMALL)
    assert probes_inside_torso(body, unpruned, probes, SMALL).any()  # the pruning had work to do


def test_histogram_png(skeleton, tmp_path):
    # two joints of the real skeleton: a 2 x 3 grid draws in a fraction of the full 10 x 3 figure's time
    small = Skeleton(skeleton.names[:2], skeleton.parents[:2], skeleton.rest_heads[:2], skeleton.limits_deg[:2])
    _, stats = sample_poses(small, 50, seed=0, settings=SamplingSettings(block_size=64, halfnormal_joints=()))
    path = tmp_path / "angles.png"
    plot_angle_histograms(stats["angles_deg"], small, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*"))
    with pytest.raises(ValueError, match="expected shape"):
        plot_angle_histograms(np.zeros((5, 3)), small, path)
