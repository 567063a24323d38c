"""The Anny body against Anny itself: pbc's forward kinematics and skinning with the merged weights equal
Anny's own forward pass for poses that move only pbc's posed joints; the body works in every stage's door
(pose pruning, the inside test, body.npz). Needs Anny's asset cache (built once per machine, see the
`anny_body` fixture in tests/conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import ANNY_TO_PBC, anny_rest, arm_angle_deg, check_phenotype, joint_table, load_anny_model
from pbc.geometry.body.base import body_sdf, load_body, pose_body, save_body
from pbc.geometry.body.skeleton import forward_kinematics
from pbc.geometry.garment.sizing import sized_config
from pbc.sim.poses import SamplingSettings, euler_xzy_to_matrix, sample_angles, sample_poses


def _anny_world_orient(cfg, body, rotations):
    """Anny's own forward pass for pbc rotations (B, J, 3, 3): its 'world-orient' parameterization takes each
    bone's world orientation and places the heads itself (Anny's kinematic chain), so pbc's rest heads and
    pivots are checked too. Returns (B, V, 3) in pbc's frame."""
    model = load_anny_model(str(cfg.rig), str(cfg.topology))
    phen = check_phenotype(cfg.phenotype, cfg.phenotype_ranges)
    rest = anny_rest(model, phen)
    column, _ = joint_table(cfg, list(model.bone_labels), list(model.bone_parents))
    C = ANNY_TO_PBC
    G = forward_kinematics(body.skeleton, rotations.double())[..., :3, :3]  # (B, J+1, 3, 3) pbc axes
    A = C.T @ G @ C  # the same rotations in Anny's axes
    R = rest["rest_bone_poses"][:, :3, :3]  # (NB, 3, 3) rest orientations
    W = rest["rest_bone_poses"].expand(rotations.shape[0], -1, -1, -1).clone()
    W[..., :3, :3] = A[:, column] @ R
    with torch.no_grad():
        out = model(W, phenotype_kwargs=phen, pose_parameterization="world-orient")
    origin = rest["rest_bone_heads"][list(model.bone_labels).index(str(cfg.root_bones[0]))]
    return (out["vertices"] - origin) @ C.T


def test_skinning_equals_anny_forward(anny_cfg, anny_body):
    B = 8
    settings = SamplingSettings(halfnormal_joints=("lower_back", "spine", "spine1", "neck", "neck1", "head"))
    angles = sample_angles(anny_body.skeleton, B, np.random.default_rng(7), settings)  # every joint posed
    rot = euler_xzy_to_matrix(torch.from_numpy(angles))  # float64
    ours = pose_body(anny_body, rot)
    theirs = _anny_world_orient(anny_cfg, anny_body, rot)
    moved = (theirs - anny_body.vertices.double()).norm(dim=-1).max()
    assert moved > 0.3  # the poses really move the body (limbs by tens of cm)
    assert (ours - theirs).abs().max() < 1e-5


def test_rest_is_anny_bind_pose_in_pbc_frame(anny_cfg, anny_body):
    model = load_anny_model(str(anny_cfg.rig), str(anny_cfg.topology))
    rest = anny_rest(model, check_phenotype(anny_cfg.phenotype, anny_cfg.phenotype_ranges))
    v = anny_body.vertices
    # y up, z forward, x left: the head is above the feet, the nose in front, the left hand at +x
    head, feet = v[:, 1].max(), v[:, 1].min()
    assert 1.5 < float(head - feet) < 2.0
    labels = list(model.bone_labels)
    assert float(anny_body.skeleton.rest_heads[anny_body.skeleton.index("l_hand"), 0]) > 0.3
    assert torch.allclose(v.double(), (rest["rest_vertices"] - rest["rest_bone_heads"][labels.index("root")])
                          @ ANNY_TO_PBC.T, atol=1e-6)
    # merged weights: rows sum to 1, at most 6 joints per vertex
    assert torch.allclose(anny_body.weights.sum(1), torch.ones(v.shape[0]), atol=1e-5)
    assert int((anny_body.weights > 0).sum(1).max()) <= 6


def test_anny_body_through_the_stages(anny_cfg, anny_body, tmp_path):
    # pose pruning with the fitted inside test: some poses pruned, the kept ones within the limits
    settings = SamplingSettings(posed_joints=tuple(anny_cfg.sampling.posed_joints), block_size=64)
    poses, stats = sample_poses(anny_body.skeleton, 16, 0, anny_body, settings)
    assert poses.shape == (16, 20, 3, 3) and stats["kept"] == 16
    legs = [anny_body.skeleton.index(n) for n in ("l_hip", "r_knee", "l_ankle")]
    assert torch.equal(poses[:, legs], torch.eye(3).expand(16, 3, 3, 3))  # unposed joints stay at rest
    # the inside test: the pelvis centre is inside, a point 30 cm in front of it outside
    rest = torch.eye(3).expand(1, 20, 3, 3)
    d = body_sdf(anny_body, rest, torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3]]))
    assert d[0, 0] < 0 < d[0, 1]
    save_body(anny_body, tmp_path / "body.npz")
    back = load_body(tmp_path / "body.npz")
    assert back.skeleton.names == anny_body.skeleton.names and torch.equal(back.weights, anny_body.weights)


def test_turned_rest_pose_is_config(anny_body):
    cfg = OmegaConf.merge(load_config(["body=anny_tpose"]).body, {"rest": {"legs_apart_deg": 10.0}})
    t_pose = body_from_config(cfg)
    sk = t_pose.skeleton
    for side in ("l", "r"):
        assert abs(arm_angle_deg(sk, side)) < 0.5
        upper = sk.rest_heads[sk.index(f"{side}_forearm")] - sk.rest_heads[sk.index(f"{side}_arm")]
        fore = sk.rest_heads[sk.index(f"{side}_hand")] - sk.rest_heads[sk.index(f"{side}_forearm")]
        assert float(torch.nn.functional.cosine_similarity(upper, fore, dim=0)) > 0.9999  # straight forearms
    shin = sk.rest_heads[sk.index("l_knee")] - sk.rest_heads[sk.index("l_hip")]
    assert float(shin[0]) > 0.05  # the left thigh turned outward (the bind pose has it at 0.04)
    # limits are the body's range: the T-posed arm's zero is the bind pose's arm raised by its A angle
    a = sk.index("l_arm")
    lift = arm_angle_deg(anny_body.skeleton, "l")
    assert torch.allclose(sk.limits_deg[a, 2], anny_body.skeleton.limits_deg[a, 2] - lift, atol=1e-3)
    assert bool((sk.limits_deg[..., 0] <= 0).all() and (sk.limits_deg[..., 1] >= 0).all())  # the rest is allowed
    # the trunk does not move in a re-rest
    lower = [sk.index(n) for n in ("lower_back", "spine", "neck")]
    assert torch.equal(sk.rest_heads[lower], anny_body.skeleton.rest_heads[lower])


def test_shirt_sized_to_anny_wraps_onto_it():
    # the shirt preset sized to the T-posed Anny (garment.size_to_body): its sleeves sit on Anny's arm axis, not
    # the mannequin's 5 cm lower, and the wrap stretches no patch past the limit the drape would discard
    from pbc.data.generate import build_scene  # noqa: PLC0415 - a drape-stage import, only this test needs it

    cfg = load_config(["body=anny_tpose", "garment=tshirt_coarse", "garment.size_to_body.enabled=true"])
    scene, stats = build_scene(cfg)
    sk = scene.body.skeleton
    arm_y = float(sk.rest_heads[sk.index("l_arm"), 1])
    v = np.asarray(scene.garment.vertices)
    sized = sized_config(cfg.garment, scene.body)
    half_torso = (0.5 * float(sized.chest_girth) + float(sized.chest_ease)) / 2.0  # the panel's half width
    sleeves = v[np.abs(v[:, 0]) > half_torso + 0.02]
    assert len(sleeves) > 0 and abs(float(sleeves[:, 1].mean()) - arm_y) < 0.03
    assert stats["patch_stretch_max"] < float(cfg.garment.shrinkwrap.max_patch_stretch)
    # against the arm's skin there (pbc.geometry.garment.checks.sleeve_axes): 7.9 degrees, the straight procedural
    # sleeve
    # against the slope of Anny's deltoid (against the arm bones it read 1-5; a MakeHuman T-shirt read 18-22 there)
    assert max(stats["sleeve_left_angle_deg"], stats["sleeve_right_angle_deg"]) < 10.0


def test_phenotype_trial_is_another_person_on_the_same_mesh(anny_cfg, anny_body):
    # the wrong-body study on Anny (pbc.jobs.robustness): a taller person, the same connectivity (the embedding holds)
    from pbc.geometry.body.measure import measurements  # noqa: PLC0415 - only this test measures
    from pbc.jobs.robustness import load_settings, trial_body  # noqa: PLC0415 - a job module, only this test needs it

    taller = trial_body(anny_body, "phenotype_height_0.20", load_settings(), anny_cfg)
    assert torch.equal(taller.faces, anny_body.faces) and taller.vertices.shape == anny_body.vertices.shape
    assert measurements(taller)["height"] > measurements(anny_body)["height"] + 0.05
    older = trial_body(anny_body, "phenotype_age_-0.20", load_settings(), anny_cfg)  # 0.7 - 0.2: the band's edge
    assert older.vertices.shape == anny_body.vertices.shape
    with pytest.raises(ValueError, match="height"):  # out of the phenotype's band: named with the bands
        trial_body(anny_body, "phenotype_height_0.60", load_settings(), anny_cfg)


def test_necktie_sized_to_anny_sits_at_its_neck():
    # the tie's collar follows Anny's neck joint (12 cm above the mannequin's) and its band the neck's radius
    from pbc.data.generate import build_scene  # noqa: PLC0415 - a drape-stage import, only this test needs it

    cfg = load_config(["data=necktie_small", "body=anny_tpose", "garment.size_to_body.enabled=true"])
    scene, stats = build_scene(cfg)
    sk = scene.body.skeleton
    neck_y = float(sk.rest_heads[sk.index("neck"), 1])
    top = float(np.asarray(scene.garment.vertices)[:, 1].max())
    assert abs(top - neck_y) < 0.05
    assert stats["patch_stretch_max"] < float(cfg.garment.shrinkwrap.max_patch_stretch)
