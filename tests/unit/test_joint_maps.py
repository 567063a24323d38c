"""Joint maps that respect the skeleton's structure (pbc.motion.dialects.skeleton_structure, check_structure;
pbc.motion.retarget.load_joint_map, check_table_rows): the shape alone gives the trunk and the branches off
it; an automatic match never drives the body's spine, neck or head with an arm or a leg of the clip, nor a
body limb with the clip's trunk; a clip whose names tell nothing, or a match that would cross, is refused in
one line with the `--bvh-map` table to write; a `--bvh-map` row naming a joint that does not exist, and a
file that is not a YAML mapping, are one line each. Clips are a Mixamo skeleton (tests/helpers/mocap.py)
with its joints renamed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.mocap import clip_text, key_of
from omegaconf import OmegaConf

from pbc.geometry.body.skeleton import skeleton_from_config
from pbc.motion.bvh import BvhError, parse_bvh, read_bvh
from pbc.motion.dialects import body_joint_roles, skeleton_structure
from pbc.motion.retarget import choose_joint_map, load_joint_map, poses_from_clip

ROOT = Path(__file__).resolve().parents[2]
SKEL = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
KEYS = key_of("mixamo")  # Mixamo name -> the skeleton's key (hips, spine0, neck0, head, l_upper, r_thigh, ...)
TRUNK_KEYS = ("hips", "spine0", "spine1", "spine2", "neck0", "head")
ARM_KEYS = ("clav", "upper", "fore", "hand", "index1", "index2", "thumb1", "thumb2")
LEG_KEYS = ("thigh", "shin", "foot", "toe")
# the body joints the Mixamo skeleton drives: key -> body joint
BODY_KEY = {"spine0": "lower_back", "spine1": "spine", "spine2": "spine1", "neck0": "neck", "head": "head"}
for _s in "lr":
    BODY_KEY.update({f"{_s}_clav": f"{_s}_shoulder", f"{_s}_upper": f"{_s}_arm", f"{_s}_fore": f"{_s}_forearm",
                     f"{_s}_hand": f"{_s}_hand", f"{_s}_thigh": f"{_s}_hip", f"{_s}_shin": f"{_s}_knee",
                     f"{_s}_foot": f"{_s}_ankle"})


def renamed(rename) -> tuple[str, dict[str, str]]:
    """The Mixamo clip with each joint renamed by rename(key, mixamo name), and new name -> key."""
    text = clip_text("mixamo", n_frames=4, seed=1)
    new = {old: rename(k, old) for old, k in KEYS.items()}
    text = re.sub(r"^(\s*(?:ROOT|JOINT) )(\S+)", lambda m: m.group(1) + new[m.group(2)], text, flags=re.M)
    return text, {new[old]: k for old, k in KEYS.items()}


def kind_of(key: str) -> str:
    return "trunk" if key in TRUNK_KEYS else "arm" if key[2:] in ARM_KEYS else "leg"


def write(tmp_path, name, text) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def table_in(message: str) -> dict:
    """The `joints: {...}` table a refusal gives to write, read as YAML."""
    found = re.search(r"joints: \{[^}]*\}", message)
    assert found, message
    return yaml.safe_load(found.group(0))["joints"]


def test_the_shape_alone_gives_the_trunk_and_the_branches_off_it():
    text, key = renamed(lambda k, _: f"bone{sorted(KEYS.values()).index(k):02d}")  # names that tell nothing
    bvh = parse_bvh(text, "alien.bvh")
    st = skeleton_structure(bvh)
    assert [key[bvh.names[j]] for j in st.trunk] == list(TRUNK_KEYS)  # root ... head: the chain the limbs leave
    assert st.limbs == 2 and st.clear
    hanging = {key[bvh.names[b[0]]]: key[bvh.names[st.trunk[a]]] for b, a in zip(st.branches, st.attach, strict=True)}
    assert hanging == {"l_thigh": "hips", "r_thigh": "hips", "l_clav": "spine2", "r_clav": "spine2"}
    for b in st.branches:  # every joint of a branch is of that limb
        kinds = {kind_of(key[bvh.names[k]]) for k in b}
        assert len(kinds) == 1 and kinds < {"arm", "leg"}


def tiny(joints: list[tuple[str, str | None, tuple[float, float, float]]]) -> str:
    """A one-frame BVH text at rest: joints [(name, parent name, OFFSET in cm)], parents first."""
    kids: dict[str | None, list[int]] = {}
    for i, (_, par, _) in enumerate(joints):
        kids.setdefault(par, []).append(i)

    def emit(i, depth):
        name, par, off = joints[i]
        pad = "  " * depth
        out = [f"{pad}{'ROOT' if par is None else 'JOINT'} {name}", pad + "{",
               f"{pad}  OFFSET {off[0]} {off[1]} {off[2]}", f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation"]
        for k in kids.get(name, []):
            out += emit(k, depth + 1)
        if name not in kids:
            out += [f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0 5 0", pad + "  }"]
        return out + [pad + "}"]

    return "\n".join(["HIERARCHY", *emit(0, 0), "MOTION", "Frames: 1", "Frame Time: 0.033333",
                      " ".join(["0"] * 3 * len(joints))]) + "\n"


def person(root: str | None = None, fingers=("l",)) -> list[tuple[str, str | None, tuple[float, float, float]]]:
    """A person in a T-pose, Mixamo's names; finger joints on the hands of `fingers`; under a `root` joint with
    an unpaired helper chain beside the hips (Unreal's root > pelvis, ik_foot_root) when given."""
    out = [(root, None, (0, 0, 0)), ("ik_foot_root", root, (0, 0, 0)), ("ik_foot_l", "ik_foot_root", (10, 8, 0)),
           ("ik_foot_r", "ik_foot_root", (-10, 8, 0))] if root else []
    out += [("Hips", root, (0, 95, 0)), ("Spine", "Hips", (0, 10, 0)), ("Spine1", "Spine", (0, 15, 0)),
            ("Spine2", "Spine1", (0, 15, 0)), ("Neck", "Spine2", (0, 12, 0)), ("Head", "Neck", (0, 10, 0))]
    for s, x in (("Left", 1), ("Right", -1)):
        out += [(f"{s}Shoulder", "Spine2", (3 * x, 8, 0)), (f"{s}Arm", f"{s}Shoulder", (15 * x, 0, 0)),
                (f"{s}ForeArm", f"{s}Arm", (28 * x, 0, 0)), (f"{s}Hand", f"{s}ForeArm", (26 * x, 0, 0))]
        if s[0].lower() in fingers:
            for f, z in (("Index", 2), ("Middle", 0), ("Ring", -2)):
                out += [(f"{s}Hand{f}1", f"{s}Hand", (8 * x, 0, z)), (f"{s}Hand{f}2", f"{s}Hand{f}1", (4 * x, 0, 0)),
                        (f"{s}Hand{f}3", f"{s}Hand{f}2", (3 * x, 0, 0))]
        out += [(f"{s}UpLeg", "Hips", (9 * x, -5, 0)), (f"{s}Leg", f"{s}UpLeg", (0, -42, 0)),
                (f"{s}Foot", f"{s}Leg", (0, -42, 0)), (f"{s}ToeBase", f"{s}Foot", (0, -8, 12))]
    return out


def test_a_shape_it_cannot_tell_leaves_the_names_to_decide():
    """Fingers on one hand only: the arms are no mirrored pair, so the shape tells the trunk up to the chest
    and the legs, no more; the names match the rest, right. A root with an unpaired helper chain beside the
    pelvis (Unreal's ik_foot_root): the trunk runs on through the child that carries the limbs."""
    bvh = parse_bvh(tiny(person()), "one_hand.bvh")
    st = skeleton_structure(bvh)
    assert [bvh.names[j] for j in st.trunk] == ["Hips", "Spine", "Spine1", "Spine2"] and st.limbs == 1
    assert {bvh.names[b[0]] for b in st.branches} == {"LeftUpLeg", "RightUpLeg"}
    table = choose_joint_map(bvh)
    assert (table.joints["l_arm"], table.joints["r_hand"], table.joints["head"]) == ("LeftArm", "RightHand", "Head")
    bvh = parse_bvh(tiny(person(root="root", fingers="lr")), "unreal.bvh")
    st = skeleton_structure(bvh)
    assert [bvh.names[j] for j in st.trunk] == ["root", "Hips", "Spine", "Spine1", "Spine2", "Neck", "Head"]
    assert st.limbs == 2 and {bvh.names[st.trunk[a]] for a in st.attach} == {"Hips", "Spine2"}  # ik_foot_*: neither
    assert choose_joint_map(bvh).joints["spine1"] == "Spine2"


def test_names_that_tell_nothing_are_refused_with_the_table_to_write(tmp_path):
    """No name tells a side or the head: a match by name would drive the body's spine and head with the
    clip's left arm (the deepest joint is a finger's). Refused in one line, with --allow-rest and
    --trust-clip too, giving the table to write and the clip's joints as its skeleton chains them; the table
    filled in reads the clip right."""
    text, key = renamed(lambda k, _: f"bone{sorted(KEYS.values()).index(k):02d}")
    path = write(tmp_path, "alien.bvh", text)
    with pytest.raises(BvhError) as e:
        poses_from_clip(path, SKEL, allow_rest=True, trust=True)
    msg = str(e.value)
    assert msg.startswith(f"{path}:2: the clip's joint names tell nothing") and "\n" not in msg
    assert "--bvh-map FILE.yaml" in msg and "--allow-rest does not go on" in msg
    table = table_in(msg)
    assert list(table) == list(body_joint_roles()) and set(table.values()) == {"..."}
    name = {k: n for n, k in key.items()}
    trunk_chain = " > ".join(name[k] for k in TRUNK_KEYS)
    assert f"{trunk_chain} (the trunk" in msg  # the clip's own names, chained as its skeleton is
    assert f"{name['l_clav']} > {name['l_upper']} > {name['l_fore']} > {name['l_hand']}" in msg
    # the table written as the refusal says (neck1: null, the clip has one neck joint) reads the clip right
    rows = {j: name[k] for k, j in BODY_KEY.items()}
    mine = write(tmp_path, "alien.yaml", "joints: {" + ", ".join(
        f"{j}: {rows.get(j, 'null')}" for j in table) + "}\n")
    m = poses_from_clip(path, SKEL, joint_map=str(mine))
    assert m.mapped == {j: rows[j] for j in SKEL.names if j in rows}
    assert not m.sanity["problems"]


SWAPS = {  # the names of one chain written on another: Mixamo's names, each on the joint of another key
    "the left arm's names on the spine": {"spine0": "l_clav", "spine1": "l_upper", "spine2": "l_fore",
                                          "l_clav": "spine0", "l_upper": "spine1", "l_fore": "spine2"},
    "the head's name on a finger": {"head": "l_index2", "l_index2": "head"},
    "the arms' names on the legs": {f"{s}_{a}": f"{s}_{b}" for s in "lr" for a, b in (
        ("upper", "thigh"), ("thigh", "upper"), ("fore", "shin"), ("shin", "fore"), ("hand", "foot"),
        ("foot", "hand"))},
}


MIXAMO = {k: n for n, k in KEYS.items()}  # key -> Mixamo name


def _swapped(swap):
    return lambda k, old: MIXAMO[SWAPS[swap].get(k, k)]


@pytest.mark.parametrize("swap", sorted(SWAPS))
def test_names_of_one_chain_on_another_are_refused_naming_the_crossing(tmp_path, swap):
    text, key = renamed(_swapped(swap))
    path = write(tmp_path, "swapped.bvh", text)
    with pytest.raises(BvhError) as e:
        poses_from_clip(path, SKEL, allow_rest=True, trust=True)
    msg = str(e.value)
    assert msg.startswith(f"{path}:2: the joints matched by name cross the clip's skeleton: they drive the body's ")
    assert "\n" not in msg and "--bvh-map FILE.yaml" in msg and list(table_in(msg)) == list(body_joint_roles())
    said = {"the left arm's names on the spine": r"l_arm.* of its trunk \(mixamorig:Hips > mixamorig:LeftShoulder",
            "the head's name on a finger": r"head by .*mixamorig:Head, of a branch leaving its trunk at "
                                           r"mixamorig:Spine2 \(an arm or a leg\)",
            "the arms' names on the legs": r"l_arm, .* by mixamorig:LeftArm, .* of a branch leaving its trunk at "
                                           r"mixamorig:Hips, no higher than the legs'"}[swap]
    assert re.search(said, msg), msg


def test_a_shipped_table_chosen_for_its_names_is_held_to_the_structure_too(tmp_path):
    """CMU names all known to cmu_mb, but the left arm's written on the spine: the table's rows would drive
    the body's arm with the clip's trunk."""
    text = (ROOT / "tests/data/bvh/cmu_mb_02_01_walk.bvh").read_text()
    swap = {"LowerBack": "LeftShoulder", "Spine": "LeftArm", "Spine1": "LeftForeArm",
            "LeftShoulder": "LowerBack", "LeftArm": "Spine", "LeftForeArm": "Spine1"}
    text = re.sub(r"^(\s*(?:ROOT|JOINT) )(\S+)", lambda m: m.group(1) + swap.get(m.group(2), m.group(2)), text,
                  flags=re.M)
    path = write(tmp_path, "walk.bvh", text)
    with pytest.raises(BvhError, match=r"walk\.bvh:\d+: the joints matched by the rows of cmu_mb\.yaml cross the "
                                       r"clip's skeleton: they drive the body's lower_back, spine, spine1 by "
                                       r"LowerBack, Spine, Spine1, of a branch leaving its trunk at LeftForeArm \(an "
                                       r"arm or a leg\); l_shoulder, l_arm, l_forearm by LeftShoulder, LeftArm, "
                                       r"LeftForeArm, of its trunk \(Hips > LeftShoulder > LeftArm > LeftForeArm > "
                                       r"Neck > Neck1 > Head\)"):
        choose_joint_map(read_bvh(path))
    assert choose_joint_map(read_bvh(ROOT / "tests/data/bvh/cmu_mb_02_01_walk.bvh")).name == "cmu_mb"  # as shipped


def _unfamiliar_words(k, old):
    """The sides kept (Left / Right), every other word one no dialect uses."""
    if k[:2] not in ("l_", "r_"):
        return old.split(":")[1]
    part = ARM_KEYS.index(k[2:]) if k[2:] in ARM_KEYS else 10 + LEG_KEYS.index(k[2:])
    return f"{'Left' if k[0] == 'l' else 'Right'}Seg{part}"


RENAMINGS = {  # a skeleton renamed: each maps right or is refused, never crossed
    "a namespace and a suffix": lambda k, old: "rig_v2:" + old.split(":")[1] + "_jnt",
    "sides kept, every other word unfamiliar": _unfamiliar_words,
    "the head named, nothing else": lambda k, old: "Head" if k == "head" else f"j{sorted(KEYS.values()).index(k)}",
    "sides on the limbs, the trunk unfamiliar, no head": lambda k, old: (
        old.split(":")[1] if k[:2] in ("l_", "r_") else f"t{TRUNK_KEYS.index(k)}"),
    **{f"swapped: {s}": _swapped(s) for s in SWAPS},
}


def test_renamed_skeletons_map_right_or_are_refused_never_crossed():
    outcomes = {}
    for what, rename in RENAMINGS.items():
        text, key = renamed(rename)
        bvh = parse_bvh(text, f"{what}.bvh")
        try:
            table = choose_joint_map(bvh)
        except BvhError as e:
            assert "--bvh-map FILE.yaml" in str(e) and "\n" not in str(e), what
            outcomes[what] = "refused"
            continue
        roles = body_joint_roles()
        crossed = {j: c for j, c in table.joints.items() if j in roles and
                   kind_of(key[c]) != roles[j]}
        assert not crossed, f"{what}: {crossed}"
        right = {BODY_KEY[key[c]] == j for j, c in table.joints.items() if key[c] in BODY_KEY}
        outcomes[what] = "right" if right == {True} else "partly"
    assert outcomes["a namespace and a suffix"] == "right"
    assert outcomes["sides kept, every other word unfamiliar"] in ("right", "refused")
    assert all(v == "refused" for k, v in outcomes.items() if k.startswith("swapped"))
    assert outcomes["the head named, nothing else"] != "refused"  # its trunk is matched, its limbs left at rest


def test_rows_naming_no_joint_are_refused_naming_the_row_and_the_nearest_name(tmp_path):
    path = write(tmp_path, "walk.bvh", clip_text("bandai", n_frames=3))
    mine = write(tmp_path, "mine.yaml", "joints: {l_arn: UpperArm_L, r_arm: UpperArm_R, spine1: Chets}\n")
    with pytest.raises(BvhError) as e:
        poses_from_clip(path, SKEL, joint_map=str(mine), trust=True)
    msg = str(e.value)
    assert msg == (f"{mine}: 2 rows of the joint map name no joint: 'l_arn: UpperArm_L' (no body joint l_arn: did "
                   f"you mean l_arm?), 'spine1: Chets' ({path} has no joint Chets: did you mean Chest?); a row is "
                   "'body joint: clip joint'")
    # nothing near: the names there are
    far = write(tmp_path, "far.yaml", "joints: {l_arm: Wing_01, r_arm: UpperArm_R}\n")
    with pytest.raises(BvhError, match=r"far\.yaml: 1 row of the joint map names no joint: 'l_arm: Wing_01' "
                                       rf"\({re.escape(str(path))} has no joint Wing_01\); .*the clip's joints: "
                                       r"Hips, Spine, Chest, "):
        poses_from_clip(path, SKEL, joint_map=str(far), trust=True)
    # the rows written the wrong way round (clip joint: body joint)
    back = write(tmp_path, "back.yaml", "joints: {UpperArm_L: l_arm, UpperArm_R: r_arm, Chest: spine1}\n")
    with pytest.raises(BvhError, match=r"back\.yaml: its rows are the wrong way round .*e\.g\. 'l_arm: UpperArm_L'"):
        poses_from_clip(path, SKEL, joint_map=str(back), trust=True)
    # a row of another body's joint (Anny's forearm on the mannequin) is skipped, as in the shipped tables
    other = write(tmp_path, "other.yaml", "joints: {l_arm: UpperArm_L, r_arm: UpperArm_R, spine1: Chest, "
                                          "l_forearm: LowerArm_L}\n")
    m = poses_from_clip(path, SKEL, joint_map=str(other), trust=True)
    assert m.mapped == {"spine1": "Chest", "l_arm": "UpperArm_L", "r_arm": "UpperArm_R"}
    np.testing.assert_allclose(m.poses.shape[1:], (len(SKEL.names), 3, 3))


@pytest.mark.parametrize(("text", "said"), [
    ("joints: {l_arm: UpperArm_L\n  r_arm: : x\n", r"not YAML \(.* at line 2\)"),
    ("- l_arm: UpperArm_L\n", "holds a list"),
    ("joints: [UpperArm_L, UpperArm_R]\n", "its 'joints' is a list, not a mapping"),
    ("", "has no 'joints'"),
    ("joints: {l_arm: [UpperArm_L]}\n", r"row 'l_arm: \['UpperArm_L'\]' is not one clip joint's name"),
    ("joints: {l_arm: UpperArm_L}\nbones: UpperArm_L\n", "its 'bones' is a str, not a list"),
    (None, "not a text file"),
])
def test_a_joint_map_that_is_not_a_yaml_mapping_is_one_line_with_the_form(tmp_path, text, said):
    mine = tmp_path / "mine.yaml"
    if text is None:
        mine.write_bytes(b"\xff\xfe\x00\x89PNG\x00")
    else:
        mine.write_text(text)
    with pytest.raises(ValueError) as e:
        load_joint_map(str(mine))
    msg = str(e.value)
    assert msg.startswith(f"BVH joint map {mine}: ") and "\n" not in msg
    assert re.search(said, msg), msg
    assert "a joint map is a YAML mapping: 'joints:', one row 'body joint: clip joint' each (joints: {l_arm: " in msg
