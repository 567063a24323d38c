"""The lower-body garments (pbc/geometry/garment/lowerbody.py) on a tiny hand-made body with legs
(tests/helpers/legged.py):
charts and UVs, seams sewn where a skirt / trousers have them, sizes that follow the body; and the legs' pose
pruning (pbc/sim/poses.py): legs within limits, crossed legs pruned, a no-op where the legs stay at rest."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from helpers.legged import MANNEQUIN, legged_body, legged_body_config
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.geometry.body.mannequin import build_mannequin
from pbc.geometry.body.measure import measurements
from pbc.geometry.garment import garment_from_config, garment_needs_body
from pbc.geometry.garment.lowerbody import lower_landmarks
from pbc.geometry.meshops import boundary_loops
from pbc.sim.poses import (
    SamplingSettings,
    euler_xzy_to_matrix,
    leg_probe_indices,
    legs_collide,
    legs_pruned,
    sample_poses,
    sampling_settings_from_config,
)

LEGS = {"left": ["l_hip", "l_knee", "l_ankle"], "right": ["r_hip", "r_knee", "r_ankle"]}
LEG_JOINTS = ("lower_back", "spine", "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle")


def _gcfg(name: str, **over):
    cfg = load_config([f"garment={name}"]).garment
    for k, v in over.items():
        OmegaConf.update(cfg, k, v)
    return cfg


def _pattern_edges(g):
    """{(a, b): flat-pattern length} over the mesh edges of each face's own chart (m)."""
    f, c = g.faces.numpy(), (g.uv[g.face_uv] * g.uv_scale).double().numpy()
    out = {}
    for i, j in ((0, 1), (1, 2), (2, 0)):
        for k in range(len(f)):
            out.setdefault(tuple(sorted((int(f[k, i]), int(f[k, j])))), []).append(np.linalg.norm(c[k, i] - c[k, j]))
    return out


def _pattern_area(g) -> float:
    t = g.pattern().double().numpy()
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())


@pytest.mark.parametrize(("name", "openings"), [("skirt", 2), ("trousers", 3)])
def test_lower_body_garment_charts_seams_and_cage(name, openings):
    body = legged_body()
    gcfg = _gcfg(name)
    assert garment_needs_body(gcfg)
    with pytest.raises(ValueError, match="sized to the body's legs"):
        garment_from_config(gcfg)
    g, cage = garment_from_config(gcfg, body)
    f = g.faces.numpy()
    # UVs in range, inside the padding, two charts (front, back) that cover every vertex
    uv = g.uv.numpy()
    pad = float(gcfg.uv_padding)
    assert uv.min() >= pad - 1e-6 and uv.max() <= 1.0 - pad + 1e-6
    assert set(g.face_side.tolist()) == {0, 1}
    # every face is counter-clockwise in its chart as seen from outside: front u grows with x, back mirrored
    tri = uv[g.face_uv.numpy()]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    signed = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    assert (signed < 0).all()  # v runs down the image: CCW in (X, Y) is clockwise in (u, v)
    # sewn: a manifold whose only boundaries are the openings (waist + hem, or waist + two ankles), every
    # interior edge in exactly two faces, and a seam edge as long in the front chart as in the back one
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    assert set(count.tolist()) <= {1, 2}
    loops = boundary_loops(f)
    assert len(loops) == openings
    lengths = _pattern_edges(g)
    seams = [v for v in lengths.values() if len(v) == 2]
    assert seams and all(abs(a - b) < 1e-6 for a, b in seams)
    # the waist is the highest opening, level with the body's waist; the hem(s) below it
    y = g.vertices.numpy()[:, 1]
    tops = sorted(float(y[loop].mean()) for loop in loops)
    land = lower_landmarks(body, LEGS)
    assert abs(tops[-1] - land["waist_at"]) < 1e-4 and all(t < land["hips_at"] for t in tops[:-1])
    # the automatic cage covers every vertex with patches of both sides
    owner = cage.vertex_patch(g.num_vertices)
    assert (owner >= 0).all() and {p.side for p in cage.patches} == {0, 1}
    # the pattern's girth at the waistband (the front chart's top row: half of it): the body's waist plus the ease
    front = g.uv.numpy()[np.unique(g.face_uv.numpy()[g.face_side.numpy() == 0])]
    top_row = np.isclose(front[:, 1], front[:, 1].min())
    width = np.ptp(front[top_row, 0]) * g.uv_scale
    assert abs(2.0 * width - (land["waist"] + float(gcfg.waist_ease))) < 1e-3


def test_trousers_legs_part_in_the_charts():
    g, _ = garment_from_config(_gcfg("trousers"), legged_body())
    # the legs' charts touch only at the crotch point: no two vertices of one side share a pixel's worth of uv
    for side in (0, 1):
        faces = g.face_uv.numpy()[g.face_side.numpy() == side]
        uv = g.uv.numpy()[np.unique(faces)]
        d = np.linalg.norm(uv[:, None] - uv[None], axis=2) + np.eye(len(uv))
        assert d.min() > 0.5 / 512


@pytest.mark.parametrize("name", ["skirt", "trousers"])
def test_sizes_follow_the_body(name):
    """A body 15% wider and deeper gets a wider garment with more cloth; one without legs is refused."""
    base = legged_body()
    g0, _ = garment_from_config(_gcfg(name), base)
    big = dataclasses.replace(base, vertices=base.vertices * torch.tensor([1.15, 1.0, 1.15]))
    g1, _ = garment_from_config(_gcfg(name), big)
    w0, w1 = (np.ptp(g.vertices.numpy()[:, 0]) for g in (g0, g1))
    assert w1 > 1.08 * w0
    a0, a1 = (_pattern_area(g) for g in (g0, g1))
    assert a1 > 1.08 * a0
    # the waistband moves with the body's waist
    m0, m1 = measurements(base), measurements(big)
    assert abs(m0["waist_at"] - m1["waist_at"]) < 0.02
    # a body without legs: one line naming the joints and the fix
    cfg = OmegaConf.load(MANNEQUIN)
    cfg.mesh.voxel_size = 0.04
    with pytest.raises(ValueError, match="no joints .*body=anny"):
        garment_from_config(_gcfg(name), build_mannequin(cfg))


# ------------------------------------------------------------------------------------------ leg pruning


def _leg_settings(**over) -> SamplingSettings:
    st = sampling_settings_from_config(legged_body_config().sampling)
    return dataclasses.replace(st, block_size=64, posed_joints=LEG_JOINTS, **over)


def test_leg_pruning_is_off_unless_a_leg_moves():
    body = legged_body()
    skel = body.skeleton
    st = _leg_settings()
    assert legs_pruned(skel, st)
    assert not legs_pruned(skel, dataclasses.replace(st, posed_joints=("lower_back", "l_arm")))
    assert not legs_pruned(skel, SamplingSettings())  # the mannequin's settings name no legs
    # upper-body sampling on a legged body: the same poses as without the leg settings (legs at rest)
    upper = dataclasses.replace(st, posed_joints=("lower_back", "spine", "l_arm", "r_arm"))
    plain = dataclasses.replace(upper, left_leg=(), right_leg=(), leg_torso_joints=())
    a, sa = sample_poses(skel, 40, 1, body, upper)
    b, sb = sample_poses(skel, 40, 1, body, plain)
    assert torch.equal(a, b) and "leg_probes" not in sa and sa["pruned"] == sb["pruned"]
    with pytest.raises(ValueError, match="unknown joints"):
        legs_pruned(skel, dataclasses.replace(st, left_leg=("l_hipp",)))


def test_crossed_legs_are_pruned_and_sampled_legs_stay_in_limits():
    body = legged_body()
    skel = body.skeleton
    st = _leg_settings()
    probes = leg_probe_indices(body, st)
    assert all(len(p) == st.probes_per_leg for p in probes)
    for p, hip in zip(probes, ("l_hip", "r_hip"), strict=True):
        dist = (body.vertices[p] - skel.rest_heads[skel.index(hip)]).norm(dim=1)
        assert (dist >= st.leg_probe_min_distance).all()
    angles = torch.zeros(4, skel.num_joints, 3)
    # 1: both thighs turned fully inward (z -15: adduction, in either leg's frame), the left swung forward
    # more than the right: the knees meet
    angles[1, skel.index("l_hip"), 2] = -15.0
    angles[1, skel.index("r_hip"), 2] = -15.0
    angles[1, skel.index("l_hip"), 0] = 20.0
    angles[1, skel.index("r_hip"), 0] = 10.0
    angles[1, skel.index("l_hip"), 1] = 30.0
    # 2: the left knee folded back hard with the thigh raised and turned in: the foot ends inside the right leg
    angles[2, skel.index("l_hip"), 0] = 60.0
    angles[2, skel.index("l_hip"), 2] = -15.0
    angles[2, skel.index("l_knee"), 0] = -130.0
    angles[2, skel.index("l_hip"), 1] = -30.0
    # 3: a plain stride (left forward, right back): clean
    angles[3, skel.index("l_hip"), 0] = 30.0
    angles[3, skel.index("r_hip"), 0] = 20.0
    angles[3, skel.index("l_knee"), 0] = -40.0
    bad = legs_collide(body, euler_xzy_to_matrix(angles), probes, st)
    assert bad.tolist() == [False, True, True, False]
    # sampling: legs within their limits, and no kept pose has a leg inside the other
    poses, stats = sample_poses(skel, 64, 0, body, st)
    lim = skel.limits_deg.numpy()
    a = stats["angles_deg"].numpy()
    assert (a >= lim[..., 0] - 1e-4).all() and (a <= lim[..., 1] + 1e-4).all()
    legs = [skel.index(j) for j in LEG_JOINTS[2:]]
    assert (np.abs(a[:, legs]) > 1.0).any(axis=0).any()
    assert stats["leg_probes"] == 2 * st.probes_per_leg and stats["pruned"] > 0
    assert not legs_collide(body, poses, probes, st).any()
