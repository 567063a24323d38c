"""Any motion-capture dialect drives the body (pbc.motion.dialects, retarget): clips written as Mixamo, Bandai
Namco, LAFAN1, Blender and Rokoko write them (tests/helpers/mocap.py) are matched without a table, every limb
driven, and the body's arm directions equal the file's own forward kinematics; a limb the clip cannot
drive is refused unless allowed; bad skeletons and unbounded requests are one line each."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers.cli import exit_code
from helpers.mocap import DIALECTS, clip_text, expected_map, worst_direction_error
from omegaconf import OmegaConf

from pbc.geometry.body.skeleton import skeleton_from_config
from pbc.motion.bvh import BvhError, parse_bvh, read_bvh
from pbc.motion.dialects import guess_dialect, match_joints, split_name
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, load_joint_map, poses_from_clip

ROOT = Path(__file__).resolve().parents[2]
SKEL = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
REST = {"mixamo": "T-pose", "bandai": "flat", "lafan1": "flat", "blender": "A-pose", "rokoko": "arms down"}
UNITS = {"mixamo": "cm", "bandai": "cm", "lafan1": "cm", "blender": "m", "rokoko": "cm"}


@pytest.mark.parametrize("dialect", sorted(DIALECTS))
def test_each_dialect_drives_every_limb_as_its_file_does(tmp_path, dialect):
    path = tmp_path / f"{dialect}.bvh"
    path.write_text(clip_text(dialect, n_frames=6, seed=3))
    bvh = read_bvh(path)
    m = poses_from_clip(path, SKEL)
    assert m.table.name == "auto" and m.table.path is None  # no shipped table knows these names
    want = expected_map(dialect)
    assert {j: m.mapped[j] for j in SKEL.names if j in want} == {j: want[j] for j in SKEL.names if j in want}
    assert {"lower_back", "spine1", "neck", "head"} <= set(m.mapped)  # the trunk from the structure
    assert m.rest_pose == REST[dialect] and m.units == UNITS[dialect]
    assert m.height_m == pytest.approx(1.78, abs=0.01)  # the skeleton written: toe end to head end
    assert worst_direction_error(SKEL, m, bvh) < 1e-3
    assert all(m.table.why[j] for j in m.mapped)  # every match says why


def test_blender_neck_and_head_come_from_the_structure(tmp_path):
    """Rigify names the neck spine.004-.005 and the head spine.006: no name says neck or head."""
    path = tmp_path / "rig.bvh"
    path.write_text(clip_text("blender"))
    m = poses_from_clip(path, SKEL)
    assert [m.mapped[j] for j in ("lower_back", "spine", "spine1", "neck", "neck1", "head")] == [
        "spine.001", "spine.002", "spine.003", "spine.004", "spine.005", "spine.006"]
    np.testing.assert_allclose(m.axes, [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)  # Z up
    assert "arms hang from spine.003" in m.table.why["spine1"]


def test_mixamo_namespaces_and_a_scaled_rig_give_the_same_poses(tmp_path):
    plain, scaled = tmp_path / "a.bvh", tmp_path / "b.bvh"
    plain.write_text(clip_text("mixamo", seed=5))
    scaled.write_text(clip_text("mixamo", seed=5, prefix="mixamorig7:", scale=200.0))
    a, b = poses_from_clip(plain, SKEL), poses_from_clip(scaled, SKEL)
    assert b.mapped["l_arm"] == "mixamorig7:LeftArm" and b.table.dialect == "Mixamo"
    np.testing.assert_allclose(b.poses, a.poses, atol=1e-6)
    assert b.metres_per_unit == pytest.approx(a.metres_per_unit / 2, rel=0.3)
    assert b.height_m == pytest.approx(a.height_m, rel=0.3)


def test_names_split_into_side_and_base():
    assert split_name("mixamorig7:LeftForeArm") == ("l", "forearm", "")
    assert split_name("UpperArm_L") == ("l", "upperarm", "")
    assert split_name("upper_arm.R") == ("r", "upperarm", "")
    assert split_name("Bip01 R Calf") == ("r", "calf", "")
    assert split_name("l_hip") == ("l", "hip", "")
    assert split_name("spine.004") == (None, "spine", "004")
    assert split_name("Hips") == (None, "hips", "")
    assert guess_dialect(["Hips", "UpperArm_L", "LowerLeg_R"]) == "Bandai Namco"
    assert guess_dialect(["a", "b"]) == "unknown"


def test_the_cmu_tables_still_win_for_cmu_names():
    bvh = read_bvh(ROOT / "tests/data/bvh/cmu_mb_02_01_walk.bvh")
    assert choose_joint_map(bvh).name == "cmu_mb"


@pytest.mark.parametrize(("name", "table"), [("cmu_mb_02_01_walk.bvh", "cmu_mb"), ("cmu_max_01_01.bvh", "cmu_max"),
                                             ("cmu_mb_01_01_lfingers.bvh", "cmu_mb")])
def test_the_match_without_a_table_rebuilds_the_cmu_tables(name, table):
    """Real files of both CMU releases: the names disagree (LeftShoulder is the clavicle in one release and
    the upper arm in the other; LeftHip the thigh; lowerneck / Neck against Neck / Neck1), the structure does
    not: matching by chains gives every row of the hand-checked tables."""
    matched = match_joints(read_bvh(ROOT / "tests/data/bvh" / name))
    assert matched.joints == load_joint_map(table).joints


def test_a_limb_left_at_rest_is_refused_unless_allowed(tmp_path):
    """Bandai's walk through the CMU table drove only the head and spine: the arms stayed in the T-pose for
    the whole clip with a note in the log. Now the body's undriven arms are refused in one line."""
    path = tmp_path / "walk.bvh"
    path.write_text(clip_text("bandai"))
    with pytest.raises(BvhError, match=r"the body's l_arm, r_arm, spine1 would stay at rest: "
                                       r".*UpperArm_L.*--bvh-map FILE.*--allow-rest") as e:
        poses_from_clip(path, SKEL, joint_map="cmu_mb")
    assert str(e.value).startswith(f"{path}:2: ") and "\n" not in str(e.value)
    # a clip read through another dialect's table: neither a person's height nor upright, refused for that too
    with pytest.raises(BvhError, match="does not stand as a person"):
        poses_from_clip(path, SKEL, joint_map="cmu_mb", allow_rest=True)
    m = poses_from_clip(path, SKEL, joint_map="cmu_mb", allow_rest=True, trust=True)
    np.testing.assert_allclose(m.poses[:, SKEL.index("l_arm")], np.eye(3)[None].repeat(len(m.poses), 0), atol=1e-12)
    # a table given as a file wins over the match
    table = tmp_path / "mine.yaml"
    table.write_text("joints: {l_arm: UpperArm_R, r_arm: UpperArm_L, spine1: Chest}\nbones: []\n")
    mine = poses_from_clip(path, SKEL, joint_map=str(table), trust=True)
    assert mine.mapped == {"spine1": "Chest", "l_arm": "UpperArm_R", "r_arm": "UpperArm_L"}


def test_an_unknown_dialect_names_the_joints_and_the_fix(tmp_path):
    text = clip_text("mixamo")
    for k, name in enumerate(sorted({w for w in text.split() if w.startswith("mixamorig:")}, key=len, reverse=True)):
        text = text.replace(name, f"joint{k:02d}")
    path = tmp_path / "alien.bvh"
    path.write_text(text)
    with pytest.raises(BvhError, match=r"would stay at rest: .*unmatched joints: joint\d\d.*--allow-rest"):
        poses_from_clip(path, SKEL)


def _tiny(joints: list[tuple[str, str]], offsets=None) -> str:
    """A BVH text: joints [(name, parent name)] in order, each 3 rotation channels, one frame."""
    kids = {}
    for name, par in joints[1:]:
        kids.setdefault(par, []).append(name)

    def emit(name, depth):
        off = (offsets or {}).get(name, "0 1 0")
        body = [f"{'ROOT' if depth == 0 else 'JOINT'} {name}", "{", f"OFFSET {off}",
                "CHANNELS 3 Zrotation Xrotation Yrotation"]
        for k in kids.get(name, []):
            body += emit(k, depth + 1)
        return body + ["}"]

    lines = ["HIERARCHY", *emit(joints[0][0], 0), "MOTION", "Frames: 1", "Frame Time: 0.033333",
             " ".join(["0"] * 3 * len(joints))]
    return "\n".join(lines) + "\n"


def test_bad_skeletons_are_one_line_each(tmp_path):
    dup = _tiny([("Hips", ""), ("Spine", "Hips"), ("Chest", "Spine")]).replace("JOINT Chest", "JOINT Spine")
    with pytest.raises(BvhError, match=r"dup.bvh:\d+: joint name 'Spine' is used twice \(also line \d+\); rename"):
        parse_bvh(dup, "dup.bvh")
    one = tmp_path / "one.bvh"
    one.write_text(_tiny([("Hips", "")]))
    with pytest.raises(BvhError, match=r"one.bvh:2: the clip has one joint \(Hips\).*give a clip of a whole"):
        poses_from_clip(one, SKEL)
    flat = tmp_path / "zero.bvh"
    zero = {n: "0 0 0" for n in ("Hips", "Spine", "Neck")}
    flat.write_text(_tiny([("Hips", ""), ("Spine", "Hips"), ("Neck", "Spine")], zero))
    with pytest.raises(BvhError, match=r"zero.bvh:\d+: every OFFSET of the 3 joints .* is zero.*export the clip"):
        poses_from_clip(flat, SKEL)


def test_a_request_of_too_many_frames_is_refused_with_the_count(tmp_path):
    path = tmp_path / "short.bvh"
    path.write_text(clip_text("mixamo", n_frames=4, frame_time=0.5))  # 1.5 s
    with pytest.raises(ValueError, match=r"--fps 1e\+06 over 1.50 s of the clip would make 1,500,001 frames, more "
                                         r"than the limit of 100,000 .*--max-frames 1500001"):
        poses_from_clip(path, SKEL, fps=1e6)
    with pytest.raises(ValueError, match=r"would make 16 frames, more than the limit of 15"):
        poses_from_clip(path, SKEL, fps=10.0, max_frames=15)
    assert len(poses_from_clip(path, SKEL, fps=10.0, max_frames=16).poses) == 16
    with pytest.raises(ValueError, match=r"the selected 4 frames would make 4 frames, more than the limit of 3"):
        bvh_to_poses(read_bvh(path), SKEL, choose_joint_map(read_bvh(path)), max_frames=3)


def test_settings_files_are_not_tables():
    with pytest.raises(ValueError, match="holds settings, not a joint map"):
        load_joint_map("dialects")


def test_pbc_motion_inspect_prints_the_match_and_draws_the_figure(tmp_path, capsys):
    from PIL import Image

    from pbc.cli.motion import main

    clip = tmp_path / "walk.bvh"
    clip.write_text(clip_text("bandai", n_frames=3, max_deg=20.0))
    out = tmp_path / "walk.png"
    coarse = "body.mesh.voxel_size=0.04"
    assert exit_code(main, ["inspect", str(clip), coarse, "--out", str(out), "--frame", "1"]) == 0
    printed = capsys.readouterr().out
    assert "dialect: Bandai Namco; units: cm" in printed and "rest pose: flat" in printed
    row = next(line for line in printed.splitlines() if line.startswith("l_arm "))
    assert row.split()[1] == "UpperArm_L" and "named forearm" in row
    assert f"figure: {out} (frame 1)" in printed
    img = np.asarray(Image.open(out).convert("L"), dtype=float)
    assert img.shape[1] > img.shape[0] > 400 and img.std() > 10  # two panels, something drawn
    # a clip the body's arms cannot follow with the CMU table: shown, and said to be refused elsewhere
    assert exit_code(main, ["inspect", str(clip), coarse, "--bvh-map", "cmu_mb", "--no-figure"]) == 0
    assert "refused by pbc predict / view / data.poses: the body's l_arm, r_arm" in capsys.readouterr().out
    # a bad file: one line, exit 2, nothing written
    bad = tmp_path / "bad.bvh"
    bad.write_text(clip.read_text().replace("JOINT Chest", "JOINT Spine"))
    assert exit_code(main, ["inspect", str(bad), coarse, "--out", str(tmp_path / "bad.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pbc motion: error: {bad}:") and "used twice" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.png").exists()
