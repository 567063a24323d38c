"""Motion clips written as the tools that make them write them (Mixamo, Bandai Namco, LAFAN1, Blender, Rokoko):
their joint names, namespaces, units, up axis, rest pose and channel layout, over one human skeleton with
random joint rotations. The file's own forward kinematics is the truth a retargeted body is checked against.

Dialect facts written here (from the tools' exports): Mixamo names every joint `mixamorig:` (or a numbered
namespace, `mixamorig7:`), centimetres, a T-pose rest, 6 channels on the root and 3 on the rest, fingers
and `HeadTop_End`/`LeftToe_End` joints. Bandai Namco's research set: `Hips`, `Spine`, `Chest`, `Shoulder_L`,
`UpperArm_L`, `LowerArm_L`, `UpperLeg_L`, six channels on every joint, each chain's OFFSETs along +X (the
joints' orientation lives in the channels), centimetres. LAFAN1: Mixamo-like names without a namespace,
offsets along +X like Bandai's, 3 rotation channels. Blender's exporter: the armature's bone names
(Rigify's metarig: `spine` at the hips, `spine.001`-`.003`, the neck `spine.004`-`.005`, the head `spine.006`,
`upper_arm.L`, `shin.L`), Z up, metres, XYZ order. Rokoko: `Spine1`-`Spine4`, `LeftThigh`, `LeftShin`.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from pbc.geometry.body.skeleton import forward_kinematics
from pbc.motion.dialects import split_name

# (key, parent key, T-pose head in metres: x left, y up, z forward); the spine and neck are filled per dialect
LIMBS = [
    ("l_clav", "top", [0.03, 1.42, 0.0]), ("l_upper", "l_clav", [0.18, 1.42, 0.0]),
    ("l_fore", "l_upper", [0.46, 1.42, 0.0]), ("l_hand", "l_fore", [0.72, 1.42, 0.0]),
    ("l_index1", "l_hand", [0.80, 1.42, 0.02]), ("l_index2", "l_index1", [0.84, 1.42, 0.02]),
    ("l_thumb1", "l_hand", [0.75, 1.41, 0.05]), ("l_thumb2", "l_thumb1", [0.78, 1.41, 0.08]),
    ("l_thigh", "hips", [0.09, 0.90, 0.0]), ("l_shin", "l_thigh", [0.09, 0.50, 0.0]),
    ("l_foot", "l_shin", [0.09, 0.08, 0.0]), ("l_toe", "l_foot", [0.09, 0.0, 0.12]),
]
ENDS = {"head": [0.0, 0.18, 0.0], "l_index2": [0.03, 0.0, 0.0], "l_thumb2": [0.02, 0.0, 0.02],
        "l_toe": [0.0, 0.0, 0.06]}

DIALECTS = {
    "mixamo": dict(names={"hips": "Hips", "spine": ["Spine", "Spine1", "Spine2"], "neck": ["Neck"], "head": "Head",
                          "clav": "{S}Shoulder", "upper": "{S}Arm", "fore": "{S}ForeArm", "hand": "{S}Hand",
                          "index1": "{S}HandIndex1", "index2": "{S}HandIndex2", "thumb1": "{S}HandThumb1",
                          "thumb2": "{S}HandThumb2", "thigh": "{S}UpLeg", "shin": "{S}Leg", "foot": "{S}Foot",
                          "toe": "{S}ToeBase"},
                   sides={"l": "Left", "r": "Right"}, prefix="mixamorig:", scale=100.0, rest="T", up="y",
                   channels=3, order="ZXY"),
    "bandai": dict(names={"hips": "Hips", "spine": ["Spine", "Chest"], "neck": ["Neck"], "head": "Head",
                          "clav": "Shoulder_{S}", "upper": "UpperArm_{S}", "fore": "LowerArm_{S}",
                          "hand": "Hand_{S}", "index1": "Index1_{S}", "index2": "Index2_{S}",
                          "thumb1": "Thumb1_{S}", "thumb2": "Thumb2_{S}",
                          "thigh": "UpperLeg_{S}", "shin": "LowerLeg_{S}", "foot": "Foot_{S}", "toe": "Toes_{S}"},
                   sides={"l": "L", "r": "R"}, prefix="", scale=100.0, rest="flat", up="y", channels=6, order="ZYX"),
    "lafan1": dict(names={"hips": "Hips", "spine": ["Spine", "Spine1", "Spine2"], "neck": ["Neck"], "head": "Head",
                          "clav": "{S}Shoulder", "upper": "{S}Arm", "fore": "{S}ForeArm", "hand": "{S}Hand",
                          "index1": "{S}HandIndex1", "index2": "{S}HandIndex2", "thumb1": "{S}HandThumb1",
                          "thumb2": "{S}HandThumb2", "thigh": "{S}UpLeg", "shin": "{S}Leg", "foot": "{S}Foot",
                          "toe": "{S}Toe"},
                   sides={"l": "Left", "r": "Right"}, prefix="", scale=100.0, rest="flat", up="y", channels=3,
                   order="ZYX"),
    "blender": dict(names={"hips": "spine", "spine": ["spine.001", "spine.002", "spine.003"],
                           "neck": ["spine.004", "spine.005"], "head": "spine.006", "clav": "shoulder.{S}",
                           "upper": "upper_arm.{S}", "fore": "forearm.{S}", "hand": "hand.{S}",
                           "index1": "f_index.01.{S}", "index2": "f_index.02.{S}", "thumb1": "thumb.01.{S}",
                           "thumb2": "thumb.02.{S}", "thigh": "thigh.{S}", "shin": "shin.{S}", "foot": "foot.{S}",
                           "toe": "toe.{S}"},
                    sides={"l": "L", "r": "R"}, prefix="", scale=1.0, rest="A", up="z", channels=3, order="XYZ"),
    "rokoko": dict(names={"hips": "Hips", "spine": ["Spine1", "Spine2", "Spine3", "Spine4"], "neck": ["Neck"],
                          "head": "Head", "clav": "{S}Shoulder", "upper": "{S}Arm", "fore": "{S}ForeArm",
                          "hand": "{S}Hand", "index1": "{S}IndexProximal", "index2": "{S}IndexMedial",
                          "thumb1": "{S}ThumbProximal", "thumb2": "{S}ThumbMedial", "thigh": "{S}Thigh",
                          "shin": "{S}Shin", "foot": "{S}Foot", "toe": "{S}Toe"},
                   sides={"l": "Left", "r": "Right"}, prefix="", scale=100.0, rest="down", up="y", channels=3,
                   order="ZXY"),
}
# what each key drives on pbc's body
BODY_OF = {"l_clav": "l_shoulder", "l_upper": "l_arm", "l_fore": "l_forearm", "l_hand": "l_hand", "l_thigh": "l_hip",
           "l_shin": "l_knee", "l_foot": "l_ankle"}
BODY_OF.update({"r" + k[1:]: "r" + v[1:] for k, v in BODY_OF.items()})


def skeleton(dialect: str, prefix: str | None = None):
    """[(name, parent index, key, T-pose head (3,) m)], in file order (parents first), and End Site offsets."""
    d = DIALECTS[dialect]
    pre = d["prefix"] if prefix is None else prefix
    n = d["names"]
    spine = [(f"spine{i}", np.array([0.0, 1.02 + 0.30 * i / max(len(n["spine"]) - 1, 1), 0.0]))
             for i in range(len(n["spine"]))]
    neck = [(f"neck{i}", np.array([0.0, 1.47 + 0.08 * i / max(len(n["neck"]), 1), 0.0])) for i in range(len(n["neck"]))]
    rows = [("hips", None, np.array([0.0, 0.95, 0.0]))]
    chain = ["hips"] + [k for k, _ in spine] + [k for k, _ in neck] + ["head"]
    heads = dict(spine + neck + [("hips", rows[0][2]), ("head", np.array([0.0, 1.60, 0.02]))])
    for k in chain[1:]:
        rows.append((k, chain[chain.index(k) - 1], heads[k]))
    top = spine[-1][0]
    for side, sx in (("l", 1.0), ("r", -1.0)):
        for key, par, pos in LIMBS:
            p = np.array(pos) * [sx, 1, 1]
            rows.append((side + key[1:], top if par == "top" else side + par[1:] if par != "hips" else "hips", p))

    def name(key):
        if key.startswith(("spine", "neck")):
            kind = "spine" if key.startswith("spine") else "neck"
            return pre + n[kind][int(key[len(kind):])]
        if key in ("hips", "head"):
            return pre + n[key]
        return pre + n[key[2:]].format(S=d["sides"][key[0]])

    keys = [r[0] for r in rows]
    out = [(name(k), -1 if p is None else keys.index(p), k, h) for k, p, h in rows]
    ends = {}
    for k, off in ENDS.items():
        for side, sx in (("l", 1.0), ("r", -1.0)):
            kk = k if k == "head" else side + k[1:]
            ends[keys.index(kk)] = np.array(off) * [sx, 1, 1]
    return out, ends


def rest_layout(joints, ends, style: str):
    """Rest heads (J, 3) in the style: T (as given), A (arms 45 degrees down), down (arms 80 degrees down)."""
    heads = np.stack([j[3] for j in joints])
    if style not in ("A", "down"):
        return heads, dict(ends)
    deg = 45.0 if style == "A" else 80.0
    out, new_ends = heads.copy(), dict(ends)
    for side, sign in (("l", -1.0), ("r", 1.0)):
        rot = Rotation.from_euler("z", sign * deg, degrees=True).as_matrix()
        pivot = heads[[j[2] for j in joints].index(side + "_upper")]
        for i, j in enumerate(joints):
            if j[2][0] == side and j[2][2:] not in ("clav", "thigh", "shin", "foot", "toe"):
                out[i] = pivot + rot @ (heads[i] - pivot)
                if i in ends:
                    new_ends[i] = rot @ ends[i]
    return out, new_ends


def clip_text(dialect: str, n_frames: int = 5, seed: int = 0, prefix: str | None = None, scale: float | None = None,
              max_deg: float = 50.0, frame_time: float = 1 / 30, trunk_deg: float = 8.0) -> str:
    """A BVH clip of `dialect` with random joint rotations (up to max_deg about each axis of a limb's joint,
    trunk_deg of the spine's and the neck's: a person stays upright over the pelvis) and root motion."""
    d = DIALECTS[dialect]
    scale = d["scale"] if scale is None else scale
    joints, ends = skeleton(dialect, prefix)
    rest, ends = rest_layout(joints, ends, d["rest"])
    up = np.eye(3) if d["up"] == "y" else np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # z up: y_file = -z
    rng = np.random.default_rng(seed)
    J = len(joints)
    kids = {i: [k for k in range(J) if joints[k][1] == i] for i in range(J)}
    # the world pose W (F, J, 3, 3): the root random, each joint a random turn of its parent's
    limit = np.array([max_deg if split_name(name)[0] is not None or par < 0 else trunk_deg
                      for name, par, *_ in joints])
    local = Rotation.from_euler("xyz", (rng.uniform(-1.0, 1.0, (n_frames, J, 3)) * limit[:, None]).reshape(-1, 3),
                                degrees=True).as_matrix().reshape(n_frames, J, 3, 3)
    local[0, 1:] = np.eye(3)  # frame 0 stands at the file's rest posture (a converter's calibration frame)
    world = np.empty_like(local)
    for j, (_, par, _, _) in enumerate(joints):
        world[:, j] = local[:, j] if par < 0 else world[:, par] @ local[:, j]
    world = np.einsum("ab,fjbc,dc->fjad", up, world, up)
    rest = rest @ up.T
    # flat: each joint oriented with its local +X along the bone to its first child (its End Site at a leaf);
    # the OFFSETs are then the true offsets in the parent's orientation (chains lie along +X at zero)
    orient = np.tile(np.eye(3), (J, 1, 1))
    if d["rest"] == "flat":
        for j in range(J):
            b = rest[kids[j][0]] - rest[j] if kids[j] else up @ ends[j]
            x = b / np.linalg.norm(b)
            helper = np.array([0.0, 0, 1]) if abs(x[2]) < 0.9 else np.array([1.0, 0, 0])
            y = np.cross(helper, x)
            y /= np.linalg.norm(y)
            orient[j] = np.stack([x, y, np.cross(x, y)], 1)
    glob = world @ orient  # (F, J, 3, 3) the file's global rotation per joint
    lines, cols = ["HIERARCHY"], []
    rot_names = " ".join(f"{a}rotation" for a in d["order"])
    pos_names = "Xposition Yposition Zposition"

    def offset_of(j):
        par = joints[j][1]
        if par < 0:
            return rest[j] * scale
        return orient[par].T @ (rest[j] - rest[par]) * scale

    def emit(j, depth):
        pad = "\t" * depth
        name, par = joints[j][0], joints[j][1]
        lines.append(f"{pad}{'ROOT' if par < 0 else 'JOINT'} {name}")
        lines.append(pad + "{")
        off = offset_of(j)
        lines.append(f"{pad}\tOFFSET {off[0]:.8f} {off[1]:.8f} {off[2]:.8f}")
        six = par < 0 or d["channels"] == 6
        lines.append(f"{pad}\tCHANNELS {6 if six else 3} " + (pos_names + " " if six else "") + rot_names)
        loc = glob[:, j] if par < 0 else np.swapaxes(glob[:, par], -1, -2) @ glob[:, j]
        pos = (rng.normal(0, 0.3, (n_frames, 3)) * scale + rest[j] * scale) if par < 0 else np.tile(off, (n_frames, 1))
        if six:
            cols.append(pos)
        cols.append(Rotation.from_matrix(loc).as_euler(d["order"], degrees=True))
        for k in kids[j]:
            emit(k, depth + 1)
        if j in ends:
            e = orient[j].T @ (up @ ends[j]) * scale
            lines.extend([f"{pad}\tEnd Site", pad + "\t{", f"{pad}\t\tOFFSET {e[0]:.8f} {e[1]:.8f} {e[2]:.8f}",
                          pad + "\t}"])
        lines.append(pad + "}")

    emit(0, 0)
    data = np.concatenate(cols, 1)
    lines += ["MOTION", f"Frames: {n_frames}", f"Frame Time: {frame_time:.7f}"]
    lines += [" ".join(f"{x:.8f}" for x in row) for row in data]
    return "\n".join(lines) + "\n"


def expected_map(dialect: str, prefix: str | None = None) -> dict[str, str]:
    """body joint -> the clip joint that must drive it (the limbs)."""
    joints, _ = skeleton(dialect, prefix)
    return {BODY_OF[k]: name for name, _, k, _ in joints if k in BODY_OF}


def key_of(dialect: str, prefix: str | None = None) -> dict[str, str]:
    """clip joint name -> the skeleton key (l_upper, spine0, ...)."""
    joints, _ = skeleton(dialect, prefix)
    return {name: k for name, _, k, _ in joints}


LIMB_JOINTS = ("l_arm", "r_arm", "l_forearm", "r_forearm", "l_hip", "r_hip", "l_knee", "r_knee")


def worst_direction_error(skel, m, bvh) -> float:
    """Degrees: the largest angle over frames and limb joints between the body's bone (posed by m.poses) and
    the same bone by the file's forward kinematics (root removed, in body axes). A body joint with a child
    points at it (the file: at the joint driving that child); one without (the mannequin's arm) along its
    rest frame's y (the file: at the next joint of its chain)."""
    t = forward_kinematics(skel, torch.from_numpy(m.poses)).numpy()
    heads, frames = skel.rest_heads.double().numpy(), skel.frames().double().numpy()
    file_pos = bvh.root_relative_positions() @ m.axes.T
    index = {n: i for i, n in enumerate(bvh.names)}
    worst, checked = 0.0, 0
    for j in LIMB_JOINTS:
        if j not in skel.names:
            continue
        i = skel.index(j)
        child = next((c for c, p in enumerate(skel.parents) if p == i), None)
        if child is not None:
            def posed(k):
                return t[:, 1 + k, :3, :3] @ heads[k] + t[:, 1 + k, :3, 3]
            body = posed(child) - posed(i)
            file_child = m.mapped[skel.names[child]]
        else:
            body = t[:, 1 + i, :3, :3] @ frames[i][:, 1]
            file_child = m.table.toward[m.mapped[j]]
        f = file_pos[:, index[file_child]] - file_pos[:, index[m.mapped[j]]]
        cos = (body * f).sum(1) / np.linalg.norm(body, axis=1) / np.linalg.norm(f, axis=1)
        worst = max(worst, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max()))
        checked += 1
    assert checked >= 2
    return worst
