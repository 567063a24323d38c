"""BVH in (pbc.motion): synthetic clips written here with known angles, several Euler orders and units,
read back as the body's poses; bad files, each with its line; the range flags; the sequence writers."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pygltflib
import pytest
import torch
from helpers.cli import exit_code
from omegaconf import OmegaConf
from scipy.spatial.transform import Rotation
from test_predict import fake_run
from test_robustness import stand_in_dataset

import pbc.core.io as pbc_io
from pbc.cli.predict import main
from pbc.data.dataset import load_dataset
from pbc.geometry.body.skeleton import skeleton_from_config, xzy_angles
from pbc.geometry.meshio import write_garment_mesh
from pbc.jobs.writers import FrameObjWriter, render_frames
from pbc.motion.bvh import BvhError, parse_bvh, read_bvh
from pbc.motion.fit import clear_clip_arms
from pbc.motion.known import nearest_known
from pbc.motion.ranges import EULER, angle_range, clamp_to_range, range_report
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, load_joint_map, motion_settings, parse_frames
from pbc.sim.poses import euler_xzy_to_matrix

ROOT = Path(__file__).resolve().parents[2]
SKEL = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
MB = load_joint_map("cmu_mb")
UNITS = {"m": 1.0, "cm": 100.0, "inch": 1 / 0.0254}
ORDERS = ("ZXY", "XYZ", "YZX", "ZYX", "YXZ", "XZY")


def random_poses(n: int, seed: int = 0) -> np.ndarray:
    """(n, J, 3, 3) float64 poses within the body's limits."""
    rng = np.random.default_rng(seed)
    lim = SKEL.limits_deg.double().numpy()
    angles = rng.uniform(lim[..., 0], lim[..., 1], (n, *lim.shape[:2]))
    return euler_xzy_to_matrix(torch.from_numpy(angles)).numpy()


def clip_text(poses: np.ndarray, scale: float = 100.0, orders=ORDERS, axes: np.ndarray | None = None,
              arm_down_deg: float = 0.0, seed: int = 1, frames_line: int | None = None) -> str:
    """A BVH of the body's skeleton in the cmu_mb dialect (+ a forearm and a leg the body lacks), whose
    frames give `poses` (N, J, 3, 3): joint j's channels are F R F^T as Euler angles in orders[j % 6];
    random root motion and ignored joints. axes (3, 3): file axes = axes @ body axes. arm_down_deg: the
    file's rest has its forearms that far below horizontal (an A-pose seen from the elbow's offset)."""
    rng = np.random.default_rng(seed)
    S = np.eye(3) if axes is None else axes
    names = [MB.joints[n] for n in SKEL.names]
    heads = SKEL.rest_heads.double().numpy()
    frames = SKEL.frames().double().numpy()
    n = len(poses)
    world = np.einsum("jab,njbc,jdc->njad", frames, poses, frames)  # F R F^T
    world = np.einsum("ab,njbc,dc->njad", S, world, S)  # in the file's axes
    cols, lines = [], ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0.5 90.0 -3.0",
                       "CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"]
    root_rot = Rotation.random(n, random_state=seed).as_euler("ZYX", degrees=True)
    cols.append(np.concatenate([rng.normal(0, 50, (n, 3)), root_rot], 1))

    def off(v):
        return " ".join(f"{x:.10f}" for x in S @ v * scale)

    def joint(j, depth):
        pad = "  " * depth
        par = SKEL.parents[j]
        order = orders[j % len(orders)]
        offset = off(heads[j] - (heads[par] if par >= 0 else 0))
        lines.extend([f"{pad}JOINT {names[j]}", f"{pad}{{", f"{pad}  OFFSET {offset}",
                      f"{pad}  CHANNELS 3 " + " ".join(f"{a}rotation" for a in order)])
        cols.append(Rotation.from_matrix(world[:, j]).as_euler(order, degrees=True))
        kids = [k for k, p in enumerate(SKEL.parents) if p == j]
        for k in kids:
            joint(k, depth + 1)
        if names[j] in ("LeftArm", "RightArm"):  # the forearm the body lacks; its offset says where the arm points
            side = 1 if names[j] == "LeftArm" else -1
            a = np.radians(arm_down_deg)
            lines.extend([f"{pad}  JOINT {names[j].replace('Arm', 'ForeArm')}", f"{pad}  {{",
                          f"{pad}    OFFSET {off(0.26 * np.array([side * np.cos(a), -np.sin(a), 0.0]))}",
                          f"{pad}    CHANNELS 3 Zrotation Xrotation Yrotation",
                          f"{pad}    End Site", f"{pad}    {{",
                          f"{pad}      OFFSET {off(np.array([0.2 * side, 0, 0]))}",
                          f"{pad}    }}", f"{pad}  }}"])
            cols.append(rng.uniform(-90, 90, (n, 3)))
        elif not kids:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {off(frames[j][:, 1] * 0.1)}",
                          f"{pad}  }}"])
        lines.append(f"{pad}}}")

    joint(0, 1)
    lines.extend(["  JOINT LeftUpLeg", "  {", f"  OFFSET {off(np.array([0.09, -0.1, 0.0]))}",
                  "  CHANNELS 3 Zrotation Xrotation Yrotation", "  End Site", "  {",
                  f"    OFFSET {off(np.array([0, -0.4, 0]))}",
                  "  }", "  }", "}"])
    cols.append(rng.uniform(-90, 90, (n, 3)))
    data = np.concatenate(cols, 1)
    lines += ["MOTION", f"Frames: {n if frames_line is None else frames_line}", "Frame Time: 0.0083333"]
    lines += [" ".join(f"{x:.10f}" for x in row) for row in data]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("unit", sorted(UNITS))
@pytest.mark.parametrize("orders", [ORDERS, ("ZXY",), ("XYZ", "ZYX")])
def test_bvh_angles_read_back_as_the_poses(tmp_path, unit, orders):
    poses = random_poses(6)
    path = tmp_path / "clip.bvh"
    path.write_text(clip_text(poses, UNITS[unit], orders))
    bvh = read_bvh(path)
    assert {j.rotation_order for j in bvh.joints[1:]} >= set(orders)  # each joint its own CHANNELS order
    m = bvh_to_poses(bvh, SKEL, choose_joint_map(bvh))
    assert m.table.name == "cmu_mb" and m.units == unit
    np.testing.assert_allclose(m.poses, poses, atol=1e-6)  # root rotation and translation removed
    assert m.ignored == ["LeftForeArm", "RightForeArm", "LeftUpLeg"] and m.missing == [] and m.unknown == []
    assert np.allclose(m.axes, np.eye(3)) and m.fps == pytest.approx(120, rel=1e-4)


def test_a_z_up_file_reads_the_same_poses(tmp_path):
    poses = random_poses(4, seed=3)
    z_up = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # file z = body y (up), file y = -body z
    m = bvh_to_poses(parse_bvh(clip_text(poses, 100.0, axes=z_up)), SKEL, MB)
    np.testing.assert_allclose(m.axes, z_up.T, atol=1e-12)
    np.testing.assert_allclose(m.poses, poses, atol=1e-6)


def test_an_a_pose_rest_is_aligned_to_the_body_t_pose():
    """The file's rest has its arms 45 degrees down: its zero frame lowers the body's arms 45 degrees (the
    body's z axis raises an arm), and a frame raising the file's arms to horizontal is the body's rest."""
    rest = np.tile(np.eye(3), (2, SKEL.num_joints, 1, 1))
    text = clip_text(rest, 100.0, arm_down_deg=45.0)
    m = bvh_to_poses(parse_bvh(text), SKEL, MB)
    ang = xzy_angles(m.poses[0])
    arms = [SKEL.index("l_arm"), SKEL.index("r_arm")]
    np.testing.assert_allclose(ang[arms], [[0, 0, -45], [0, 0, -45]], atol=1e-6)
    others = [j for j in range(SKEL.num_joints) if j not in arms]
    np.testing.assert_allclose(m.poses[0][others], np.eye(3)[None].repeat(len(others), 0), atol=1e-9)
    # raise the file's arms by 45 degrees about its z (left arm: +z raises it; right: -z) -> the body's T-pose
    lifted = rest.copy()
    for j, sign in zip(arms, (1, -1), strict=True):
        lifted[:, j] = SKEL.frames()[j].double().numpy().T @ Rotation.from_euler("z", sign * 45, degrees=True) \
            .as_matrix() @ SKEL.frames()[j].double().numpy()
    m2 = bvh_to_poses(parse_bvh(clip_text(lifted, 100.0, arm_down_deg=45.0)), SKEL, MB)
    np.testing.assert_allclose(m2.poses[0], np.eye(3)[None].repeat(SKEL.num_joints, 0), atol=1e-6)


def test_frames_step_and_resampling():
    poses = random_poses(9, seed=5)
    bvh = parse_bvh(clip_text(poses))
    m = bvh_to_poses(bvh, SKEL, MB, parse_frames("2:8:3"))
    np.testing.assert_allclose(m.poses, poses[2:8:3], atol=1e-6)
    assert m.source_frames.tolist() == [2, 5] and m.fps == pytest.approx(40, rel=1e-4)
    # 120 fps -> 60 fps: every other frame exactly (slerp at the keys), over the selected span
    r = bvh_to_poses(bvh, SKEL, MB, parse_frames("1:"), fps=1 / (2 * bvh.frame_time))
    np.testing.assert_allclose(r.poses, poses[1::2], atol=1e-6)
    # a time between two frames: the halfway rotation of each joint
    half = bvh_to_poses(bvh, SKEL, MB, parse_frames("0:2"), fps=2 / bvh.frame_time)
    mid = Rotation.from_matrix(half.poses[1, 7]).as_matrix()
    want = Rotation.from_matrix(poses[:2, 7]).mean().as_matrix()
    np.testing.assert_allclose(mid, want, atol=1e-4)
    for bad, msg in (("a:b", "START:STOP:STEP"), ("0:4:0", "step must be >= 1")):
        with pytest.raises(ValueError, match=msg):
            parse_frames(bad)
    with pytest.raises(ValueError, match="not both"):
        bvh_to_poses(bvh, SKEL, MB, parse_frames("0:8:2"), fps=30.0)
    with pytest.raises(ValueError, match="selects no frame"):
        bvh_to_poses(bvh, SKEL, MB, parse_frames("20:30"))


def _line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


def test_bad_files_name_the_line_and_the_fix(tmp_path):
    good = clip_text(random_poses(3))
    lines = good.splitlines()
    motion = _line_of(good, "MOTION")
    cases = {
        "truncated hierarchy": ("\n".join(lines[:20]) + "\n", 20, "truncated"),
        "truncated frame": (good[:good.rstrip().rfind(" ")] + "\n", len(lines), "truncated"),
        "nan channel": (good.replace(lines[-1], lines[-1].replace(lines[-1].split()[10], "nan", 1)), len(lines),
                        r"Spine \w+rotation is nan"),
        "unknown channel": (good.replace("Zrotation Yrotation Xrotation", "Zrotation Yrotation Wrotation"),
                            _line_of(good, "CHANNELS 6"), "unknown channel name 'Wrotation'"),
        "frame count": (clip_text(random_poses(3), frames_line=5), motion + 1, "'Frames: 5' but the file holds 3"),
    }
    for name, (text, line, msg) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.bvh"
        path.write_text(text)
        with pytest.raises(BvhError, match=msg) as e:
            read_bvh(path)
        assert str(e.value).startswith(f"{path}:{line}: "), (name, str(e.value))
        assert ";" in str(e.value) and "\n" not in str(e.value), name  # the problem; the fix, one line
    # a hierarchy without any mapped joint: the ROOT line, the joint names and the table to edit
    alien = re.sub(r"JOINT (\w+)", r"JOINT x_\1", good)
    with pytest.raises(BvhError, match=r":2: none of the clip's .* joint map .*cmu_mb.yaml; edit") as e:
        bvh_to_poses(parse_bvh(alien, "alien.bvh"), SKEL, MB)
    assert "x_LowerBack" in str(e.value)


def test_another_dialect_lists_the_unmapped_names_with_the_table():
    text = clip_text(random_poses(2)).replace("JOINT Head", "JOINT Skull").replace("LeftUpLeg", "LThigh")
    m = bvh_to_poses(parse_bvh(text), SKEL, MB)
    assert m.unknown == ["Skull", "LThigh"] and m.missing == ["head"]
    note = next(n for n in m.notes if "not in the joint map" in n)
    assert str(MB.path) in note and "Skull, LThigh" in note
    assert any(n.endswith("stay at rest: head") for n in m.notes)
    np.testing.assert_allclose(m.poses[:, SKEL.index("head")], np.eye(3)[None].repeat(2, 0), atol=1e-12)


def test_auto_picks_the_dialect_by_the_whole_name_set():
    max_names = " ".join(load_joint_map("cmu_max").bones)
    bvh = parse_bvh("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
                    + "".join(f"JOINT {n}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n}}\n"
                              for n in max_names.split()[1:]) + "}\nMOTION\nFrames: 1\nFrame Time: 0.01\n"
                    + " ".join(["0"] * 3 * len(max_names.split())) + "\n")
    assert choose_joint_map(bvh).name == "cmu_max"  # although LeftShoulder is a cmu_mb bone too


def test_range_flags_and_clamps():
    train = random_poses(50, seed=7)
    rng = angle_range(train, chart=EULER)
    a = xzy_angles(train)
    np.testing.assert_allclose(euler_xzy_to_matrix(torch.from_numpy(a)).numpy(), train, atol=1e-9)
    names = list(SKEL.names)
    poses = train[:3].copy()
    j = SKEL.index("l_arm")
    beyond = a[2].copy()
    beyond[j, 2] = rng.deg[j, 2, 1] + 10.0  # l_arm raised 10 degrees past anything seen
    poses[2] = euler_xzy_to_matrix(torch.from_numpy(beyond)).numpy()
    rep = range_report(poses, rng, names, 1e-3)
    assert rep["frames_outside"] == [2] and list(rep["outside"]["2"]) == ["l_arm.z"]
    assert rep["outside"]["2"]["l_arm.z"] == pytest.approx(rng.deg[j, 2, 1] + 10.0, abs=1e-3)
    c = clamp_to_range(poses, rng, 1e-3)
    np.testing.assert_allclose(c[:2], poses[:2], atol=0)  # inside: untouched
    assert xzy_angles(c[2])[j, 2] == pytest.approx(rng.deg[j, 2, 1], abs=1e-6)
    assert range_report(c, rng, names, 1e-3)["frames_outside"] == []


def test_frame_obj_writer_matches_meshio(setup_motion, tmp_path):
    from pbc.data.dataset import load_dataset

    ds = load_dataset(setup_motion[0])
    v = ds.garment.vertices + 0.01 * torch.randn(len(ds.garment.vertices), 3)
    w = FrameObjWriter(ds.garment, tmp_path / "first.obj", ds.garment.vertices, header=["a"])
    w.write(tmp_path / "fast.obj", v, header=["frame 1"])
    write_garment_mesh(tmp_path / "meshio.obj", ds.garment, v, header=["frame 1"])
    assert (tmp_path / "fast.obj").read_bytes() == (tmp_path / "meshio.obj").read_bytes()


def test_render_draws_the_nearest_face():
    # two squares facing the camera, the red one nearer: it covers the blue one where they overlap
    sq = torch.tensor([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    near, far = (sq * 0.5 + torch.tensor([0.25, 0.25, 0.1]))[None], sq[None]
    cam = (0.0, 1.0, 1 / 16, 16, 16)
    img = render_frames([(far, faces, [0, 0, 1], 0.0, False), (near, faces, [1, 0, 0], 0.0, False)], cam,
                        [0, 0, 1], [1, 1, 1])
    assert img.shape == (1, 16, 16, 3)
    assert tuple(img[0, 8, 8]) == (255, 0, 0) and tuple(img[0, 1, 1]) == (0, 0, 255)
    lifted = render_frames([(far, faces, [0, 0, 1], 0.2, False), (near, faces, [1, 0, 0], 0.0, False)], cam,
                           [0, 0, 1], [1, 1, 1])
    assert tuple(lifted[0, 8, 8]) == (0, 0, 255)  # a depth lift puts a layer in front


@pytest.fixture(scope="module")
def setup_motion(tmp_path_factory, body):
    root = tmp_path_factory.mktemp("motion")
    data = stand_in_dataset(root / "data", body)
    return data, fake_run(root / "whole", data)


def test_cli_bvh_writes_meshes_video_glb_and_flags(setup_motion, tmp_path, capsys):
    data, whole = setup_motion
    poses = random_poses(12, seed=11)
    clip = tmp_path / "walk.bvh"
    clip.write_text(clip_text(poses, 1 / 0.0254))
    out = tmp_path / "out"
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out), "--frames", "0:12:2",
                            "--video", "gif", "--guard", "none", "--obj"]) == 0
    printed = capsys.readouterr().out
    res = json.loads((out / "predict.json").read_text())
    assert res["num_poses"] == 6 and res["motion"]["units"] == "inch" and res["motion"]["ignored"] == [
        "LeftForeArm", "RightForeArm", "LeftUpLeg"]
    # the clip's frames, each arm a random pose hangs inside the torso raised out of it (pbc.motion.fit)
    fitted, raised = clear_clip_arms(poses[0:12:2], load_dataset(data).body, motion_settings().clear_arms)
    np.testing.assert_allclose(np.load(out / "poses.npy"), fitted, atol=1e-6)
    n = int((raised > 0).any(1).sum())
    said = [x for x in res["notes"] if x.startswith("arms raised out of the torso")]
    assert said[0].startswith(f"arms raised out of the torso in {n} of 6 frames") if n else not said
    verts = np.load(out / "vertices.npy")
    assert sorted(p.name for p in (out / "meshes").iterdir()) == [f"frame_{k:05d}.obj" for k in range(6)]
    # the stand-in data's poses are small turns: limit-wide random poses are past them, flagged and printed
    rep = res["pose_range"]
    assert rep["num_outside"] == len(rep["frames_outside"]) > 0
    known = rep["known"]
    assert known["num_flagged"] == len(known["flagged"]) > 0 and rep["guard"] == "none"
    assert f"{known['num_flagged']} of 6 frames are past the model's data" in printed
    assert all((d > known["limit_deg"]) == (k in known["flagged"]) for k, d in enumerate(known["distance_deg"]))
    assert "ignored: LeftForeArm, RightForeArm, LeftUpLeg" in printed
    from PIL import Image

    gif = Image.open(out / "motion.gif")  # the clip's 60 fps (120 / step 2) shown at 30: every other frame
    assert gif.n_frames == 3
    assert res["files"]["video_frames"] == {"count": 3, "every": 2, "fps": pytest.approx(30, 1e-3), "height": 512,
                                            "width": gif.width}
    g = pygltflib.GLTF2().load(str(out / "garment.glb"))
    prim = g.meshes[0].primitives[0]
    assert len(prim.targets) == 6 and prim.attributes.TEXCOORD_0 is not None
    assert g.animations[0].channels[0].target.path == "weights"
    blob = g.binary_blob()
    acc = g.accessors[prim.targets[3]["POSITION"]]
    view = g.bufferViews[acc.bufferView]
    delta = np.frombuffer(blob[view.byteOffset:view.byteOffset + view.byteLength], np.float32).reshape(-1, 3)
    base_acc = g.accessors[prim.attributes.POSITION]
    bv = g.bufferViews[base_acc.bufferView]
    base = np.frombuffer(blob[bv.byteOffset:bv.byteOffset + bv.byteLength], np.float32).reshape(-1, 3)
    # every garment vertex appears (split at the UV seams) and base + target k = frame k
    assert {tuple(np.round(p, 5)) for p in base + delta} == {tuple(np.round(p, 5)) for p in verts[3]}
    # the default guard: the flags stay, each flagged frame turned towards its nearest training pose to the limit
    out3 = tmp_path / "guarded"
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out3), "--frames", "0:12:2",
                            "--video", "none", "--no-glb"]) == 0
    res3 = json.loads((out3 / "predict.json").read_text())
    assert res3["pose_range"]["guard"] == "nearest" and res3["pose_range"]["known"]["flagged"] == known["flagged"]
    ds = load_dataset(data)
    train = np.asarray(ds.poses)[np.asarray(ds.split("train"))]
    joints = list(range(len(SKEL.names)))
    guarded = nearest_known(np.load(out3 / "poses.npy"), train, joints).distance_deg
    assert (guarded <= known["limit_deg"] + 0.05).all()
    moved = np.abs(np.load(out3 / "poses.npy") - np.load(out / "poses.npy")).max((1, 2, 3)) > 1e-4
    assert moved.tolist() == [k in known["flagged"] for k in range(6)]
    # clamped: the flags stay, the poses move into the range
    out2 = tmp_path / "clamped"
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out2), "--clamp-to-range",
                            "--video", "none", "--no-glb", "--fps", "60"]) == 0
    res2 = json.loads((out2 / "predict.json").read_text())
    assert res2["pose_range"]["clamped"] and res2["num_poses"] == 6 and not (out2 / "garment.glb").exists()
    ranges = res2["pose_range"]["range_deg"]  # {joint: {axis: [min, max]}}
    rng = np.array([[ranges[j][ax] for ax in "xyz"] for j in SKEL.names])
    a = xzy_angles(np.load(out2 / "poses.npy").astype(np.float64))
    assert ((a >= rng[..., 0] - 1e-2) & (a <= rng[..., 1] + 1e-2)).all()


def test_cli_bad_bvh_is_one_line_exit_2_nothing_written(setup_motion, tmp_path, capsys):
    _, whole = setup_motion
    text = clip_text(random_poses(3))
    bad = tmp_path / "bad.bvh"
    bad.write_text(text.replace("Zrotation Yrotation Xrotation", "Zrotation Yrotation Qrotation"))
    out = tmp_path / "out"
    capsys.readouterr()
    assert exit_code(main, [str(whole), "--poses", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pbc predict: error: {bad}:5: ") and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_cli_refuses_unbounded_frames_and_limbs_at_rest_before_writing(setup_motion, tmp_path, capsys):
    """A 16-frame clip at --fps 1e6 would make 1.25 million frames (it ran for hours); a Bandai Namco walk read
    through the CMU table left the arms at rest. Both: one line, exit 2, nothing written; the flags go on."""
    from helpers.mocap import clip_text as dialect_clip

    _, whole = setup_motion
    clip = tmp_path / "short.bvh"
    clip.write_text(clip_text(random_poses(16), frames_line=None))  # 16 frames at 120 fps: 0.125 s
    out = tmp_path / "out"
    capsys.readouterr()
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out), "--fps", "1e7"]) == 2
    err = capsys.readouterr().err
    n = int(15 * 0.0083333 * 1e7 + 1e-9) + 1  # the span of 16 frames at the file's frame time, at 1e7 fps
    assert f"would make {n:,} frames, more than the limit of 100,000" in err and f"--max-frames {n}" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out), "--fps", "240", "--max-frames",
                            "29", "--video", "none", "--no-glb"]) == 2
    assert "would make 30 frames, more than the limit of 29" in capsys.readouterr().err and not out.exists()
    walk = tmp_path / "bandai.bvh"
    walk.write_text(dialect_clip("bandai", n_frames=3))
    assert exit_code(main, [str(whole), "--poses", str(walk), "--out", str(out), "--bvh-map", "cmu_mb"]) == 2
    err = capsys.readouterr().err
    assert "the body's l_arm, r_arm, spine1 would stay at rest" in err and "--allow-rest" in err and not out.exists()
    assert exit_code(main, [str(whole), "--poses", str(walk), "--out", str(out), "--video", "none", "--no-glb"]) == 0
    res = json.loads((out / "predict.json").read_text())
    assert res["motion"]["dialect"] == "Bandai Namco" and res["motion"]["rest_pose"] == "flat"
    assert res["motion"]["mapped"]["l_arm"] == "UpperArm_L"


def test_a_clip_writes_its_video_glb_and_contact_sheet_and_meshes_only_when_asked(setup_motion, tmp_path, capsys,
                                                                                  monkeypatch):
    import imageio.v3 as iio
    from PIL import Image

    import pbc.jobs.predict as job

    _, whole = setup_motion
    clip = tmp_path / "walk.bvh"
    clip.write_text(clip_text(random_poses(30, seed=4), 1 / 0.0254))
    out = tmp_path / "out"
    # the unit tier starts no process: a GIF (Pillow) for the video, not ffmpeg's MP4
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(out), "--guard", "none",
                            "--video", "gif"]) == 0
    printed = capsys.readouterr().out
    assert not (out / "meshes").exists() and "a mesh per frame with --obj" in printed
    res = json.loads((out / "predict.json").read_text())
    assert {"video", "glb", "contact_sheet"} <= set(res["files"]) and "meshes" not in res["files"]
    frames = res["files"]["contact_sheet_frames"]
    assert frames[0] == 0 and frames[-1] == 29 and len(frames) == 12  # 12 of 30, spread over the clip
    sheet = Image.open(out / "contact_sheet.png")
    assert sheet.width > sheet.height  # 3 rows of 4 tiles: wider than tall for a standing figure's tiles
    video = iio.imread(out / "motion.gif", index=0)
    assert video.shape[0] >= 512 == int(motion_settings().video.height)
    assert "this writes about" not in printed  # a small clip: no size warning
    # --obj: a mesh per frame too; a tiny warn_bytes: the size is said first, with how to write less
    tiny = OmegaConf.merge(motion_settings(), {"outputs": {"warn_bytes": 1}})
    monkeypatch.setattr(job, "motion_settings", lambda: tiny)
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(tmp_path / "obj"), "--obj",
                            "--video", "none", "--no-glb", "--sheet", "0"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "obj" / "meshes").iterdir()) == [f"frame_{k:05d}.obj" for k in range(30)]
    assert not (tmp_path / "obj" / "contact_sheet.png").exists()
    warning = next(line for line in printed.splitlines() if line.startswith("this writes about"))
    assert f"in all to {tmp_path / 'obj'} (meshes/" in warning and "drop --obj" in warning
    assert "outputs.warn_bytes of conf/motion/sequence.yaml" in warning
    # an out dir without room for the outputs: one line naming it, before anything is written
    monkeypatch.setattr(pbc_io.shutil, "disk_usage", lambda p: SimpleNamespace(free=10_000))
    assert exit_code(main, [str(whole), "--poses", str(clip), "--out", str(tmp_path / "full"), "--video", "gif"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]  # the progress bar aside
    assert len(errors) == 1 and f"prediction output directory {tmp_path / 'full'}:" in errors[0]
    err = errors[0]
    assert "needed" in err and "--out DIR" in err and not list((tmp_path / "full").glob("*"))
