"""Skeleton (FK, LBS) and the procedural body: mesh, weights, parts, SDF, I/O, input checks."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from pbc.geometry.body.base import body_sdf, load_body, pose_body, save_body
from pbc.geometry.body.mannequin import build_mannequin
from pbc.geometry.body.skeleton import Skeleton, forward_kinematics, linear_blend_skinning

BODY_CONFIG = Path(__file__).resolve().parents[2] / "conf" / "body" / "mannequin.yaml"
TRIANGLES_DEFAULT = (5_000, 20_000)  # the range conf/body/mannequin.yaml promises at its default voxel


def _rot(axis: str, deg: float) -> torch.Tensor:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {
        "x": torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis].float()


def _identity(skel, batch=1):
    return torch.eye(3).repeat(batch, skel.num_joints, 1, 1)


def _random_rotations(batch, joints, seed=0):
    g = torch.Generator().manual_seed(seed)
    q, _ = torch.linalg.qr(torch.randn(batch, joints, 3, 3, generator=g))
    return q * torch.linalg.det(q)[..., None, None]  # proper rotations (det +1)


def test_lbs_identity_at_rest(body):
    posed = pose_body(body, _identity(body.skeleton, 2))
    assert posed.shape == (2, *body.vertices.shape)
    torch.testing.assert_close(posed, body.vertices.expand(2, -1, -1), atol=1e-6, rtol=0)


def test_vertex_on_one_bone_moves_rigidly(skeleton):
    j = skeleton.index("l_arm")
    rng = torch.Generator().manual_seed(1)
    points = skeleton.rest_heads[j] + 0.3 * torch.randn(5, 3, generator=rng)
    weights = torch.zeros(5, skeleton.num_joints + 1)
    weights[:, 1 + j] = 1.0
    rot = _random_rotations(3, skeleton.num_joints)
    transforms = forward_kinematics(skeleton, rot)
    posed = linear_blend_skinning(points, weights, transforms)
    joint_posed = transforms[:, 1 + j, :3, 3] + (transforms[:, 1 + j, :3, :3] @ skeleton.rest_heads[j])
    torch.testing.assert_close(
        (posed - joint_posed[:, None]).norm(dim=-1), (points - skeleton.rest_heads[j]).norm(dim=-1).expand(3, -1)
    )
    torch.testing.assert_close(torch.cdist(posed, posed), torch.cdist(points, points).expand(3, -1, -1))


def test_fk_two_joint_chain_by_hand():
    skel = Skeleton(
        names=("a", "b"),
        parents=(-1, 0),
        rest_heads=torch.tensor([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]),
        limits_deg=torch.zeros(2, 3, 2),
    )
    ra, rb = _rot("z", 90), _rot("x", 90)
    T = forward_kinematics(skel, torch.stack([ra, rb])[None])[0]
    assert T.shape == (3, 4, 4)
    torch.testing.assert_close(T[0], torch.eye(4))
    tip = torch.tensor([0.0, 3.0, 0.0, 1.0])  # on bone b, 1 above its head
    # by hand: b turns the tip about its head (0,2,0): (0,2,1); a turns that about (0,1,0) by 90 deg about z
    torch.testing.assert_close(T[2] @ tip, torch.tensor([-1.0, 1.0, 1.0, 1.0]), atol=1e-6, rtol=0)
    torch.testing.assert_close(T[1] @ torch.tensor([0.0, 2.0, 0.0, 1.0]), torch.tensor([-1.0, 1.0, 0.0, 1.0]))


def test_arm_frame_raises_arm_with_positive_z(skeleton):
    rot = _identity(skeleton, 2)
    rot[0, skeleton.index("l_arm")] = _rot("z", 30)
    rot[1, skeleton.index("r_arm")] = _rot("z", 30)
    T = forward_kinematics(skeleton, rot)
    for b, (name, side) in enumerate((("l_arm", 1.0), ("r_arm", -1.0))):
        tip = torch.tensor([side * 0.7, 0.43, -0.02, 1.0])
        moved = T[b, 1 + skeleton.index(name)] @ tip
        assert moved[1] > 0.43 + 0.1  # up, on both sides (the right frame mirrors the left)


def test_bad_rotations_raise_clear_errors(body):
    skel = body.skeleton
    with pytest.raises(ValueError, match=r"expected shape \(B, 10, 3, 3\).*got \(2, 9, 3, 3\)"):
        forward_kinematics(skel, torch.eye(3).repeat(2, 9, 1, 1))
    rot = _identity(skel, 3)
    rot[1, 4, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"NaN.*sample 1.*neck1"):
        pose_body(body, rot)
    with pytest.raises(ValueError, match="expected shape"):
        body_sdf(body, torch.eye(3)[None], body.vertices[None])


def test_default_body_watertight_and_sized():
    import trimesh

    cfg = OmegaConf.load(BODY_CONFIG)  # the default voxel size, as the pipeline builds it
    t0 = time.perf_counter()
    body = build_mannequin(cfg)
    seconds = time.perf_counter() - t0
    mesh = trimesh.Trimesh(body.vertices.numpy(), body.faces.numpy(), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert TRIANGLES_DEFAULT[0] <= len(body.faces) <= TRIANGLES_DEFAULT[1]
    assert seconds < 30  # ~1-3 s; generous for a loaded machine


def test_coarse_body_is_watertight_and_deterministic(body, body_cfg):
    import trimesh

    again = build_mannequin(body_cfg)
    assert torch.equal(again.vertices, body.vertices) and torch.equal(again.faces, body.faces)
    assert torch.equal(again.weights, body.weights) and torch.equal(again.parts, body.parts)

    mesh = trimesh.Trimesh(body.vertices.numpy(), body.faces.numpy(), process=False)
    assert mesh.is_watertight and mesh.volume > 0
    assert body.faces.dtype == torch.long and body.vertices.dtype == torch.float32


def test_weights_are_a_partition_of_unity(body):
    w = body.weights
    assert w.shape == (len(body.vertices), body.skeleton.num_joints + 1)
    assert (w >= 0).all()
    torch.testing.assert_close(w.sum(dim=1), torch.ones(len(w)))
    # smooth, not a rigid segmentation: some vertices blend several bones (at the joints)
    assert ((w > 0.05).sum(dim=1) >= 2).sum() > 0.05 * len(w)


def test_parts_overlap_and_cover(body):
    parts = body.parts
    assert parts.shape == (3, len(body.vertices)) and parts.dtype == torch.bool
    assert parts.any(dim=0).all()
    assert (parts[0] & parts[1]).any() and (parts[0] & parts[2]).any()
    assert not (parts[1] & parts[2]).any()
    x = body.vertices[:, 0]
    shoulder = body.skeleton.rest_heads[body.skeleton.index("l_arm"), 0]
    assert parts[1][x < shoulder].any()  # the left arm part reaches into the shoulder region
    assert parts[0][x > shoulder].any()  # the torso part includes the upper-arm root
    assert not parts[0][x > shoulder + 0.15].any()  # ... but not the arm itself
    assert (x[parts[1]] > 0).all() and (x[parts[2]] < 0).all()


def test_sdf_inside_outside_and_on_surface(body, body_cfg):
    rest = _identity(body.skeleton)
    inside_chest = torch.tensor([[[0.0, 0.3, 0.0]]])
    outside = torch.tensor([[[0.0, 0.3, 0.5], [0.0, 1.2, 0.0], [0.5, 0.0, 0.0]]])
    assert body_sdf(body, rest, inside_chest).item() < -0.05
    assert (body_sdf(body, rest, outside) > 0.1).all()
    on_mesh = body_sdf(body, rest, body.vertices[None])
    assert on_mesh.abs().max() < float(body_cfg.mesh.voxel_size)
    # (N, 3) points broadcast over the batch
    assert body_sdf(body, _identity(body.skeleton, 2), body.vertices[:7]).shape == (2, 7)


def test_sdf_part_and_pose(body):
    skel = body.skeleton
    rest = _identity(skel)
    forearm = torch.tensor([[[0.6, 0.43, -0.02]]])
    assert body_sdf(body, rest, forearm).item() < 0
    assert body_sdf(body, rest, forearm, part=1).item() < 0
    assert body_sdf(body, rest, forearm, part=0).item() > 0.2
    assert body_sdf(body, rest, forearm, part=2).item() > 0.5
    # the posed primitives move with their bones: arm lowered by 90 deg, the forearm point is outside
    down = rest.clone()
    down[0, skel.index("l_arm")] = _rot("z", -90)
    assert body_sdf(body, down, forearm).item() > 0
    assert body_sdf(body, down, torch.tensor([[[0.17, 0.43 - 0.45, -0.02]]])).item() < 0
    with pytest.raises(ValueError, match="part"):
        body_sdf(body, rest, forearm, part=3)


def test_sdf_is_differentiable(body):
    points = torch.tensor([[[0.0, 0.3, 0.2], [0.3, 0.45, 0.0]]], requires_grad=True)
    body_sdf(body, _identity(body.skeleton), points).sum().backward()
    assert torch.isfinite(points.grad).all() and (points.grad.norm(dim=-1) > 0.5).all()


def test_save_load_roundtrip_and_errors(body, tmp_path):
    path = tmp_path / "sub" / "body.npz"
    save_body(body, path)
    assert path.is_file() and not list(path.parent.glob(".*tmp"))
    loaded = load_body(path)
    for name in ("vertices", "faces", "weights", "parts"):
        assert torch.equal(getattr(loaded, name), getattr(body, name))
    assert loaded.skeleton.names == body.skeleton.names and loaded.skeleton.parents == body.skeleton.parents
    rest = _identity(body.skeleton)
    pts = body.vertices[None, :50]
    torch.testing.assert_close(body_sdf(loaded, rest, pts), body_sdf(body, rest, pts))
    with pytest.raises(FileNotFoundError, match="body file not found"):
        load_body(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a valid body file"):
        load_body(bad)
