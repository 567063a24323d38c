"""A BVH clip -> the body's poses (N, J, 3, 3): joint map, axes, units, rest-pose alignment, frames, fps.

The joint map (conf/motion/<table>.yaml) is keyed by the body's joint names: each row names the BVH joint
that drives that body joint. The model works in the root frame, so the BVH root's translation and rotation
are dropped: every joint's global rotation is taken relative to the root's.

Rest alignment. The file's rest pose is its OFFSETs' layout (a T-pose, an A-pose, ...), the body's its
rest pose (conf/body). For each mapped body joint j, A_j is the smallest rotation taking the body's rest bone
direction onto the file's (towards the joint driving j's first child, else the file joint's first child /
End Site). The body joint's global rotation at a frame is then M_j = C Q_j C^T A_j, with Q_j the file
joint's root-relative global rotation and C the file's axes -> the body's (y up, x left, z forward; found
from the rest skeletons, snapped to an axis permutation). Its pose entry is the rotation relative to its
parent's, in its rest frame F_j: R_j = F_j^T M_parent^T M_j F_j. A body joint the file lacks keeps M_parent
(stays at rest); a clip at its own rest pose gives the body the file's rest posture (arms down for an A-pose).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import yaml
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from scipy.spatial.transform import Rotation, Slerp

from pbc.core.paths import CONF_DIR
from pbc.core.validate import check_motion_settings
from pbc.geometry.body.skeleton import Skeleton, forward_kinematics
from pbc.motion.bvh import Bvh, BvhError, check_skeleton, read_bvh
from pbc.motion.dialects import (
    JointMap,
    ancestors,
    body_joint_roles,
    check_structure,
    dialect_settings,
    lowest_common_ancestor,
    match_joints,
)

MOTION_CONF = CONF_DIR / "motion"
SETTINGS = "sequence"  # conf/motion/sequence.yaml: not a joint map
SETTINGS_FILE = MOTION_CONF / f"{SETTINGS}.yaml"
NOT_TABLES = (SETTINGS, "dialects")  # conf/motion/dialects.yaml: the matching without a table


def motion_settings():
    """conf/motion/sequence.yaml (units, range tolerance, video), its numbers held to conf/bounds.yaml: a value
    out of its range is one ValueError naming the file, the key and the range."""
    cfg = OmegaConf.load(SETTINGS_FILE)
    check_motion_settings("motion", cfg, SETTINGS_FILE)
    return cfg


def check_motion_files() -> None:
    """Both motion settings files read and held to conf/bounds.yaml, as every reader of them is
    (`motion_settings`, `dialect_settings`): for a door to refuse them before it writes anything."""
    motion_settings()
    dialect_settings()


def shipped_joint_maps() -> list[str]:
    return sorted(p.stem for p in MOTION_CONF.glob("*.yaml") if p.stem not in NOT_TABLES)


TABLE_FORM = ("a joint map is a YAML mapping: 'joints:', one row 'body joint: clip joint' each (joints: {l_arm: "
              "LeftArm, l_forearm: LeftForeArm, spine1: Spine2, ...}), and optionally 'bones:', a list of the "
              "dialect's joints, as conf/motion/cmu_mb.yaml")


def load_joint_map(name_or_path: str | Path) -> JointMap:
    """A shipped table by name (conf/motion/<name>.yaml) or a YAML file of the same layout. Raises ValueError
    in one line naming the file and the form (`TABLE_FORM`) for a file that is not YAML, not a mapping, or
    whose 'joints' is not a mapping of names."""
    p = Path(name_or_path)
    if p.suffix not in (".yaml", ".yml") and str(name_or_path) in NOT_TABLES:
        raise ValueError(f"BVH joint map {name_or_path!r}: conf/motion/{name_or_path}.yaml holds settings, not a "
                         f"joint map; give a shipped table ({', '.join(shipped_joint_maps())}), a YAML file or auto")
    if p.suffix not in (".yaml", ".yml"):
        p = MOTION_CONF / f"{name_or_path}.yaml"
    if not p.is_file():
        raise ValueError(f"BVH joint map {name_or_path!r} not found: give a YAML file (layout of "
                         f"{MOTION_CONF / 'cmu_mb.yaml'}) or a shipped table: {', '.join(shipped_joint_maps())}")
    try:
        cfg = OmegaConf.to_container(OmegaConf.load(p))
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ValueError(f"BVH joint map {p}: not YAML ({problem}{where}); {TABLE_FORM}") from None
    except UnicodeDecodeError:
        raise ValueError(f"BVH joint map {p}: not a text file; {TABLE_FORM}") from None
    except OSError as e:
        raise ValueError(f"BVH joint map {p} cannot be read: {e.strerror}") from None
    except OmegaConfBaseException as e:
        raise ValueError(f"BVH joint map {p}: {str(e).splitlines()[0]}; {TABLE_FORM}") from None
    if isinstance(cfg, list):
        raise ValueError(f"BVH joint map {p}: holds a list; {TABLE_FORM}")
    if not isinstance(cfg, dict) or cfg.get("joints") is None:
        raise ValueError(f"BVH joint map {p}: has no 'joints'; {TABLE_FORM}")
    if not isinstance(cfg["joints"], dict):
        raise ValueError(f"BVH joint map {p}: its 'joints' is a {type(cfg['joints']).__name__}, not a mapping; "
                         f"{TABLE_FORM}")
    odd = [f"'{k}: {v}'" for k, v in cfg["joints"].items() if isinstance(v, (dict, list))]
    if odd:
        raise ValueError(f"BVH joint map {p}: row {', '.join(odd)} is not one clip joint's name; {TABLE_FORM}")
    bones = cfg.get("bones") or []
    if not isinstance(bones, list):
        raise ValueError(f"BVH joint map {p}: its 'bones' is a {type(bones).__name__}, not a list; {TABLE_FORM}")
    joints = {str(k): str(v) for k, v in cfg["joints"].items() if v is not None}
    why = {j: f"row of {p.name}" for j in joints}
    ft = cfg.get("frame_time")
    return JointMap(p.stem, p, joints, tuple(str(b) for b in bones), why,
                    dialect=f"table {p.stem}",
                    frame_time=(float(ft["header"]), float(ft["capture"])) if isinstance(ft, dict) else None,
                    units=str(cfg["units"]) if cfg.get("units") else None)


def is_shipped(table: JointMap) -> bool:
    """A table of conf/motion (its rows name the whole dialect: a clip may lack some, a body some)."""
    return table.path is not None and table.path.resolve().parent == MOTION_CONF.resolve()


def _did_you_mean(name: str, choices) -> str:
    """': did you mean X?' for the closest of `choices` (case, a namespace, then spelling), else ''."""
    choices = list(choices)
    low = {c.lower(): c for c in choices}
    bare = {c.rsplit(":", 1)[-1].lower(): c for c in choices}
    hit = (low.get(name.lower()) or bare.get(name.rsplit(":", 1)[-1].lower())
           or next(iter(difflib.get_close_matches(name.lower(), list(low), n=1, cutoff=0.6)), None))
    hit = low.get(hit, hit)
    return f": did you mean {hit}?" if hit else ""


def check_table_rows(bvh: Bvh, skeleton: Skeleton, table: JointMap) -> None:
    """A joint map given as a file (not shipped): every row names a pbc body joint (this body's, or another
    body's, whose rows this body skips) and a joint of the clip. Raises BvhError in one line naming each bad
    row and the nearest name (difflib), or saying the rows are the wrong way round (clip joint: body joint)."""
    if table.path is None or is_shipped(table):
        return
    body = set(skeleton.names) | set(body_joint_roles())
    clip = set(bvh.names)
    bad = [(j, c) for j, c in table.joints.items() if j not in body or c not in clip]
    if not bad:
        return
    if sum(j in clip and c in body for j, c in table.joints.items()) > len(table.joints) / 2:
        raise BvhError(f"{table.path}: its rows are the wrong way round ('{bad[0][0]}: {bad[0][1]}' names a clip "
                       f"joint, then a body joint): a row is 'body joint: clip joint', e.g. "
                       f"'{bad[0][1]}: {bad[0][0]}'; {TABLE_FORM}")
    body_hint = {j: _did_you_mean(j, sorted(body)) for j, _ in bad if j not in body}
    clip_hint = {c: _did_you_mean(c, bvh.names) for _, c in bad if c not in clip}
    said = []
    for j, c in bad:
        problems = ([f"no body joint {j}{body_hint[j]}"] if j in body_hint else []) + (
            [f"{bvh.path} has no joint {c}{clip_hint[c]}"] if c in clip_hint else [])
        said.append(f"'{j}: {c}' ({'; '.join(problems)})")
    known = []
    if not all(body_hint.values()):
        known.append(f"the body joints: {', '.join([*body_joint_roles(), *sorted(body - set(body_joint_roles()))])}")
    if not all(clip_hint.values()):
        known.append(f"the clip's joints: {', '.join(bvh.names[:40])}{' ...' if len(bvh.names) > 40 else ''}")
    rows = "1 row of the joint map names" if len(bad) == 1 else f"{len(bad)} rows of the joint map name"
    raise BvhError(f"{table.path}: {rows} no joint: {', '.join(said)}; a row is 'body joint: clip joint'"
                   + "".join(f"; {k}" for k in known))


def capture_rate(bvh: Bvh, table: JointMap) -> tuple[Bvh, str | None]:
    """The clip at its capture's rate: a header carrying its converter's default frame time (the table's
    `frame_time.header`, e.g. amc2bvh's 30 fps for CMU's 120 fps captures) gets the capture's, with a note."""
    if table.frame_time is None or abs(bvh.frame_time - table.frame_time[0]) > 1e-5:
        return bvh, None
    header, capture = table.frame_time
    return replace(bvh, frame_time=capture), (
        f"the header's {1 / header:g} fps is {table.name}'s converter default: played at the capture's "
        f"{1 / capture:g} fps (conf/motion/{table.name}.yaml frame_time)")


def choose_joint_map(bvh: Bvh, spec: str | Path = "auto") -> JointMap:
    """`spec`: a shipped table's name or a YAML file (it wins); "auto": the shipped table that knows every
    joint name of the clip (the CMU releases), else the joints matched by name and structure
    (pbc.motion.dialects.match_joints: Mixamo, Bandai Namco, LAFAN1, Blender, Rokoko, ...). Either automatic
    choice drives the body's trunk with the clip's trunk and its limbs with the branches off it, or raises
    BvhError with the table to write (pbc.motion.dialects.check_structure)."""
    if str(spec) != "auto":
        return load_joint_map(spec)
    tables = [load_joint_map(n) for n in shipped_joint_maps()]
    names = set(bvh.names)
    best = max(tables, key=lambda t: (len(names & t.known()), -tables.index(t)))
    if names <= best.known():
        check_structure(bvh, best)
        return best
    return match_joints(bvh)


def parse_frames(spec: str | None) -> slice:
    """'--frames START:STOP:STEP' (Python slice of the clip's frames, each part optional) -> slice."""
    if spec is None or str(spec).strip() == "":
        return slice(None)
    parts = str(spec).split(":")
    try:
        if len(parts) > 3:
            raise ValueError
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise ValueError(f"--frames {spec!r}: give START:STOP:STEP (integers, each optional, as a Python slice), "
                         "e.g. 0:300:4") from None
    if len(vals) == 1:
        return slice(vals[0], None if vals[0] is None else (vals[0] + 1 or None))
    if len(vals) == 3 and vals[2] is not None and vals[2] < 1:
        raise ValueError(f"--frames {spec!r}: the step must be >= 1")
    return slice(*vals)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3): the smallest rotation taking direction a onto direction b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def file_axes(p: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(3, 3) C taking the file's axes to the body's: the rotation best fitting the mapped joints' rest
    positions p (n, 3) (root-relative) onto the body's h (n, 3), snapped to a signed axis permutation
    (files differ by a swap like z-up, not by a few degrees). Identity when they cannot tell (< 3 joints)."""
    if len(p) < 3 or np.linalg.matrix_rank(p, tol=1e-9 * max(1.0, np.abs(p).max())) < 2:
        return np.eye(3)
    u, _, vt = np.linalg.svd(h.T @ p)
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    snap = np.zeros((3, 3))
    cols = np.argmax(np.abs(r), axis=1)
    snap[np.arange(3), cols] = np.sign(r[np.arange(3), cols])
    if len(set(cols.tolist())) < 3 or np.linalg.det(snap) < 0.5:
        return np.eye(3)
    return snap


def detect_units(p: np.ndarray, h: np.ndarray, units: dict, tolerance: float = 1.6,
                 expected: str | None = None) -> tuple[str, float]:
    """(unit name, metres per file unit) from the size of skeleton p (n, 3) against the body's h (n, 3): the
    `expected` unit (the dialect's) when within `tolerance` of it, else the nearest unit in log ratio when
    within `tolerance` of it, else a scaled rig ("cm x2.00", its measured metres per unit: a Mixamo character
    exported at twice the size)."""
    hn, pn = np.linalg.norm(h, axis=1).sum(), np.linalg.norm(p, axis=1).sum()
    if hn <= 0 or pn <= 0:
        return "unknown", 1.0
    mpu = hn / pn
    if expected in units and max(mpu / float(units[expected]), float(units[expected]) / mpu) <= tolerance:
        return expected, float(units[expected])
    name = min(units, key=lambda u: abs(np.log(mpu / float(units[u]))))
    ratio = mpu / float(units[name])
    if max(ratio, 1 / ratio) <= tolerance:
        return name, float(units[name])
    return f"{name} x{1 / ratio:.2f}", float(mpu)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) degrees between vectors a and b (..., 3); nan where one is zero."""
    na, nb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.einsum("...i,...i->...", a, b) / (na * nb)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def rest_pose_kind(rest: np.ndarray, index: dict, table: JointMap, cfg, bvh_joints=(), pelvis: int = 0) -> str:
    """The clip's rest pose (positions rest (J, 3)): "T-pose", "A-pose", "arms down", "arms up", "standing"
    (no arms matched) or "flat" (the skeleton lies along one direction at zero rotation, its orientation in
    the channels: Bandai Namco), from the angles between the spine (from joint `pelvis` up) and the upper arm
    and the thigh. bvh_joints: the clip's joints (an upper arm without a `toward` points at its first child)."""
    body = dialect_settings().body
    m = table.joints

    def pos(body_joint):
        return rest[index[m[body_joint]]] if m.get(body_joint) in index else None

    def bone(body_joint):  # towards the next joint of its chain (a table's: its first child in the file)
        name = m.get(body_joint)
        if name not in index:
            return None
        nxt = table.toward.get(name) or next((k.name for k in bvh_joints if k.parent == index[name]), None)
        return None if nxt is None else rest[index[nxt]] - rest[index[name]]

    top = next((pos(j) for j in [body.head, *reversed(list(body.neck)), *reversed(list(body.spine))]
                if pos(j) is not None), None)
    if top is None or not np.linalg.norm(top - rest[pelvis]) > 0:
        return "unknown"
    up = top - rest[pelvis]
    arms = [float(_angles(b, up)) for b in (bone(body.limbs.l.upper_arm), bone(body.limbs.r.upper_arm))
            if b is not None]
    legs = [float(_angles(pos(body.limbs[s].shin) - pos(body.limbs[s].thigh), up)) for s in "lr"
            if pos(body.limbs[s].shin) is not None and pos(body.limbs[s].thigh) is not None]
    arms = [a for a in arms if np.isfinite(a)]
    legs = [a for a in legs if np.isfinite(a)]
    if (arms and min(arms) < cfg.flat_arm_deg) or (legs and min(legs) < cfg.flat_leg_deg):
        return "flat"
    if not arms:
        return "standing"
    a = float(np.mean(arms))
    lo, hi = cfg.t_pose_deg
    if a < lo:
        return "arms up"
    if a <= hi:
        return "T-pose"
    return "A-pose" if a < cfg.arms_down_deg else "arms down"


def posture_angles(pos: np.ndarray, index: dict, table: JointMap) -> dict[str, np.ndarray]:
    """How far each frame stands from a rest pose, from the clip's joint positions pos (F, J, 3) in its
    pelvis's frame (degrees, (F,) each; nan where the clip lacks the joints): `knee_bend` the larger angle
    between a thigh and its shin, `leg_from_spine` the smaller angle between a thigh and the spine (180:
    standing), `spine_bend` between the lower and the upper trunk, `arm_from_spine` the smaller angle between
    an upper arm and the spine (90: a T-pose, 180: arms down)."""
    body = dialect_settings().body
    m = table.joints
    nan = np.full(len(pos), np.nan)

    def at(body_joint):
        return pos[:, index[m[body_joint]]] if m.get(body_joint) in index else None

    trunk = [at(j) for j in [*body.spine, *body.neck, body.head]]
    trunk = [t for t in trunk if t is not None]
    if not trunk:
        return {k: nan for k in ("knee_bend", "leg_from_spine", "spine_bend", "arm_from_spine")}
    top, mid = trunk[-1], at(body.spine[-1])
    up = top  # the pelvis is the origin
    knees, legs, arms = [], [], []
    for side in "lr":
        limb = body.limbs[side]
        hip, knee, foot = at(limb.thigh), at(limb.shin), at(limb.foot)
        if hip is not None and knee is not None and foot is not None:
            knees.append(_angles(knee - hip, foot - knee))
            legs.append(_angles(knee - hip, up))
        arm, fore = at(limb.upper_arm), at(limb.forearm)
        if arm is not None and fore is not None:
            arms.append(_angles(fore - arm, up))
    out = {"knee_bend": np.max(knees, 0) if knees else nan, "leg_from_spine": np.min(legs, 0) if legs else nan,
           "spine_bend": _angles(mid, top - mid) if mid is not None and mid is not top else nan,
           "arm_from_spine": np.min(arms, 0) if arms else nan}
    return out


def rest_problems(angles: dict[str, np.ndarray], cfg) -> list[list[str]]:
    """Per frame, what keeps it from standing as a rest pose (conf/motion/dialects.yaml rest.frame); [] for a
    frame that stands as one. angles: `posture_angles`."""
    lim = cfg.frame
    tests = [("knee_bend", lambda a: a > lim.max_knee_bend_deg, "knees bent {:.0f} degrees"),
             ("leg_from_spine", lambda a: a < lim.min_leg_from_spine_deg, "legs {:.0f} degrees from the spine "
                                                                          "(not standing)"),
             ("spine_bend", lambda a: a > lim.max_spine_bend_deg, "trunk bent {:.0f} degrees"),
             ("arm_from_spine", lambda a: a < lim.min_arm_from_spine_deg, "arms {:.0f} degrees from the spine "
                                                                          "(raised)")]
    n = len(next(iter(angles.values())))
    out: list[list[str]] = [[] for _ in range(n)]
    for key, bad, text in tests:
        a = angles[key]
        known = np.isfinite(a)  # a clip without the joints says nothing against a frame
        for f in np.flatnonzero(known & bad(np.where(known, a, 0.0))):
            out[f].append(text.format(float(a[f])))
    return out


def choose_rest_frame(bvh: Bvh, pelvis: int, index: dict, table: JointMap, cfg) -> tuple[int, str]:
    """(frame, why) of the clip's frame to stand in for a rest its OFFSETs do not give: frame 0 when it stands
    as a rest pose (`rest_problems`), else the frame nearest a neutral stance among those that do. Raises
    BvhError naming frame 0's problems and --rest-frame when no frame stands as one."""
    pos, _ = bvh.pelvis_relative(pelvis)
    angles = posture_angles(pos, index, table)
    problems = rest_problems(angles, cfg)
    if not problems[0]:
        return 0, "frame 0 stands as a rest pose"
    good = np.flatnonzero([not p for p in problems])
    if len(good) == 0:
        raise BvhError(f"{bvh.path}: its rest skeleton lies flat and no frame stands as a rest pose (frame 0: "
                       f"{', '.join(problems[0])}); give the frame of a rest pose (standing, arms out or down) with "
                       "--rest-frame K (`pbc motion inspect CLIP --frame K` shows a frame)")
    lean = (np.nan_to_num(angles["knee_bend"]) + np.nan_to_num(180.0 - angles["leg_from_spine"])
            + np.nan_to_num(angles["spine_bend"]))
    best = int(good[np.argmin(lean[good])])
    return best, f"frame 0 does not stand as a rest: {', '.join(problems[0])}; --rest-frame K picks another"


def posed_heads(skeleton: Skeleton, poses: np.ndarray) -> np.ndarray:
    """(F, J, 3) the body's joint heads posed by poses (F, J, 3, 3), in the body's root frame."""
    t = forward_kinematics(skeleton, torch.from_numpy(np.ascontiguousarray(poses)).double()).numpy()
    heads = skeleton.rest_heads.double().numpy()
    return np.einsum("fjab,jb->fja", t[:, 1:, :3, :3], heads) + t[:, 1:, :3, 3]


def sanity_report(poses: np.ndarray, skeleton: Skeleton, height_m: float, cfg) -> dict:
    """Whether retargeted poses (N, J, 3, 3) show a person as a person stands: the trunk upright over the
    pelvis (median tilt of the body's head from straight above its lower back), the feet under the hips (the
    share of frames with both ankles below both hips) and the clip's skeleton height (metres) in range
    (conf/motion/sequence.yaml sanity). Returns the measures and `problems` (empty: sane). Up to
    cfg.max_frames frames, spread over the clip, are looked at."""
    pick = np.unique(np.linspace(0, len(poses) - 1, min(len(poses), int(cfg.max_frames))).round().astype(int))
    pos = posed_heads(skeleton, poses[pick])  # (F, J, 3)
    names = list(skeleton.names)
    body = dialect_settings().body
    out: dict = {"frames_checked": int(len(pick)), "height_m": round(float(height_m), 3), "problems": []}
    lo_h, hi_h = cfg.height_m
    if not lo_h <= height_m <= hi_h:
        out["problems"].append(f"the skeleton is {height_m:.2f} m tall, outside {lo_h:g}-{hi_h:g} m (its unit or "
                               "its rest misread)")
    top = next((j for j in [body.head, *reversed(list(body.neck)), *reversed(list(body.spine))] if j in names), None)
    base = next((j for j in body.spine if j in names), None)
    if top is not None and base is not None and top != base:
        tilt = _angles(pos[:, names.index(top)] - pos[:, names.index(base)], np.array([0.0, 1.0, 0.0]))
        out["trunk_tilt_deg"] = round(float(np.median(tilt)), 1)
        if out["trunk_tilt_deg"] > cfg.max_trunk_tilt_deg:
            out["problems"].append(f"the trunk leans {out['trunk_tilt_deg']:.0f} degrees from upright over the "
                                   f"pelvis in the median frame (at most {cfg.max_trunk_tilt_deg:g}: the body lies "
                                   "down or stands on its head)")
    legs = [(body.limbs[s].thigh, body.limbs[s].foot) for s in "lr"]
    if all(h in names and f in names for h, f in legs):
        hip_y = np.min([pos[:, names.index(h), 1] for h, _ in legs], 0)
        foot_y = np.max([pos[:, names.index(f), 1] for _, f in legs], 0)
        out["feet_under_hips"] = round(float(np.mean(foot_y < hip_y)), 3)
        if out["feet_under_hips"] < cfg.min_feet_under_hips:
            out["problems"].append(f"the feet are below the hips in {out['feet_under_hips']:.0%} of the frames "
                                   f"(at least {cfg.min_feet_under_hips:.0%} expected)")
    return out


@dataclass
class Motion:
    """Body poses from a clip and what the mapping did."""

    poses: np.ndarray  # (N, J, 3, 3) float64, the body's joint order (conf/body)
    times: np.ndarray  # (N,) seconds from the clip's first frame
    source_frames: np.ndarray  # (N,) the clip frame each pose sits at (fractional when resampled)
    fps: float
    table: JointMap
    units: str
    metres_per_unit: float
    axes: np.ndarray  # (3, 3) file axes -> body axes
    mapped: dict[str, str]  # body joint -> BVH joint
    ignored: list[str]  # the clip's joints the body has no joint for (mapped to nothing)
    unknown: list[str]  # the clip's joints the table's dialect does not list (another dialect?)
    missing: list[str]  # body joints the clip lacks: they stay at rest
    notes: list[str] = field(default_factory=list)
    rest_pose: str = ""  # the file's rest: T-pose, A-pose, arms down, flat (then frame 0 stands in for it), ...
    height_m: float = 0.0  # the clip's skeleton, head to lowest joint at its rest (or frame 0), metres
    rest_frame: int | None = None  # the clip frame standing in for its rest (None: its OFFSETs' layout)
    pelvis: int = 0  # the clip joint whose frame is the body's root frame (index into the clip's joints)
    sanity: dict = field(default_factory=dict)  # `sanity_report`: the measures and the problems found

    def summary(self) -> dict:
        return {"joint_map": str(self.table.path or self.table.name), "dialect": self.table.dialect,
                "units": self.units, "metres_per_unit": self.metres_per_unit, "rest_pose": self.rest_pose,
                "height_m": round(self.height_m, 4), "rest_frame": self.rest_frame, "sanity": self.sanity,
                "fps": self.fps, "frames": len(self.poses), "mapped": self.mapped, "ignored": self.ignored,
                "unknown": self.unknown, "at_rest": self.missing, "source_frames": [
                    round(float(f), 4) for f in self.source_frames]}


def output_frames(bvh: Bvh, frames: slice, fps: float | None) -> np.ndarray:
    """The clip frames (a slice of its frames) a request reads: (n,) indices; checks --frames / --fps."""
    idx = np.arange(bvh.num_frames)[frames]
    if len(idx) == 0:
        raise ValueError(f"--frames {frames.start}:{frames.stop}:{frames.step} selects no frame of {bvh.path} "
                         f"({bvh.num_frames} frames)")
    if fps is not None:
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"--fps {fps}: give frames per second > 0")
        if (frames.step or 1) != 1:
            raise ValueError("give either a --frames step or --fps, not both (the step picks every n-th frame, "
                             "--fps resamples)")
        idx = np.arange(idx[0], idx[-1] + 1)
    return idx


def count_frames(bvh: Bvh, idx: np.ndarray, fps: float | None) -> int:
    """How many poses the frames idx make, resampled at fps (None: as they are)."""
    if fps is None:
        return len(idx)
    return int(np.floor((idx[-1] - idx[0]) * bvh.frame_time * fps + 1e-9)) + 1


def check_frame_count(bvh: Bvh, idx: np.ndarray, fps: float | None, max_frames: int) -> None:
    """Refuse a request making more than max_frames poses (--fps 1e6 on a short clip), before any work."""
    n = count_frames(bvh, idx, fps)
    if n > max_frames:
        span = (idx[-1] - idx[0]) * bvh.frame_time
        how = (f"--fps {fps:g} over {span:.2f} s of the clip" if fps is not None
               else f"the selected {len(idx):,} frames")
        raise ValueError(f"{bvh.path}: {how} would make {n:,} frames, more than the limit of {max_frames:,} "
                         "(max_frames, conf/motion/sequence.yaml); lower --fps or pick fewer --frames, or raise "
                         f"the limit with --max-frames {n}")


def must_drive(skeleton: Skeleton, mapped: dict) -> list[str]:
    """The body joints of its arms, legs and spine (dialects.yaml's must_drive) that no clip joint drives."""
    names = set(skeleton.names)
    return [j for j in dialect_settings().body.must_drive if j in names and j not in mapped]


def bvh_to_poses(bvh: Bvh, skeleton: Skeleton, table: JointMap, frames: slice = slice(None),
                 fps: float | None = None, allow_rest: bool = False, max_frames: int | None = None,
                 rest_frame: int | None = None, trust: bool = False) -> Motion:
    """The body's poses (N, J, 3, 3) for the clip's `frames` (a slice of its frames), resampled at `fps`
    (None: the clip's frames as selected). `rest_frame`: the clip frame whose posture is its rest (None: the
    OFFSETs' layout, or for a skeleton lying flat a frame standing as a rest, `choose_rest_frame`). Raises
    BvhError when no joint of the clip is in the table, when the body's arms, legs or spine would stay at rest
    (`allow_rest` goes on with them at rest), when no frame stands as a rest, or when the retargeted clip fails
    `sanity_report` (`trust` goes on, the problems in Motion.sanity), or when a row of a table given as a
    file names no body joint or no joint of the clip (`check_table_rows`); ValueError for a request of more than
    `max_frames` poses (None: conf/motion/sequence.yaml's) or a rest_frame outside the clip."""
    settings = motion_settings()
    check_skeleton(bvh)
    check_table_rows(bvh, skeleton, table)
    bvh, rate_note = capture_rate(bvh, table)
    names = list(skeleton.names)
    index = {n: i for i, n in enumerate(bvh.names)}
    mapped = {j: table.joints[j] for j in names if table.joints.get(j) in index}
    root = bvh.joints[0]
    where = table.path or f"the joints matched by name and structure ({table.dialect} names)"
    if not mapped:
        raise BvhError(f"{bvh.path}:{root.line}: none of the clip's {len(bvh.names)} joints "
                       f"({', '.join(bvh.names[:12])}{' ...' if len(bvh.names) > 12 else ''}) drives a body joint "
                       f"in the joint map {where}; edit that table's rows (body joint: BVH joint name) or "
                       f"pick another with --bvh-map (shipped: {', '.join(shipped_joint_maps())}, or a YAML file "
                       "of that layout)")
    used = set(mapped.values()) | {root.name}
    ignored = [n for n in bvh.names if n not in used and n in table.known()]
    unknown = [n for n in bvh.names if n not in used and n not in table.known()]
    missing = [j for j in names if j not in mapped]
    undriven = must_drive(skeleton, mapped)
    if undriven and not allow_rest:
        free = [n for n in bvh.names if n not in used]
        raise BvhError(f"{bvh.path}:{root.line}: the body's {', '.join(undriven)} would stay at rest: no joint of "
                       f"the clip is matched to them by {where} (the clip's unmatched joints: "
                       f"{', '.join(free[:20]) or 'none'}{' ...' if len(free) > 20 else ''}); map them in a joint "
                       "map (--bvh-map FILE.yaml, rows 'body joint: clip joint' as conf/motion/cmu_mb.yaml; "
                       "`pbc motion inspect` shows the match), or go on with them at rest with --allow-rest")
    notes = [rate_note] if rate_note else []
    if unknown:
        notes.append(f"{len(unknown)} BVH joints are not in the joint map {table.path} (another dialect?): "
                     f"{', '.join(unknown)}; add them to its rows or bones, or pick another table with --bvh-map")
    if ignored:
        notes.append(f"{len(ignored)} BVH joints have no body joint and are ignored: {', '.join(ignored)}")
    if missing:
        notes.append(f"{len(missing)} body joints are not in the clip and stay at rest: {', '.join(missing)}")

    limit = settings.max_frames if max_frames is None else max_frames
    if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
        raise ValueError(f"--max-frames {limit!r}: give the most frames a request may make, an integer >= 1")
    idx = output_frames(bvh, frames, fps)
    check_frame_count(bvh, idx, fps, limit)

    # the model's root frame is the clip's pelvis: where the joints driving the body's roots (its lower back
    # and hips) meet; each rotation and position below is taken in its frame
    roots = [index[mapped[j]] for j, par in zip(names, skeleton.parents, strict=True) if par < 0 and j in mapped]
    pelvis = lowest_common_ancestor(bvh, roots) if len(roots) > 1 else 0
    # the rest: the OFFSETs' layout; a skeleton lying flat (its orientation in the channels) takes a frame's
    # posture as its rest instead (`rest_frame`, else frame 0 when it stands as a rest, else the clip's most
    # rest-like frame), each joint's rotation then taken relative to that frame's
    rest_cfg = dialect_settings().rest
    rest = bvh.rest_positions()
    rest = rest - rest[pelvis]
    kind = rest_pose_kind(rest, index, table, rest_cfg, bvh.joints, pelvis)
    ref = np.tile(np.eye(3), (len(bvh.joints), 1, 1))
    rest_at = None
    if rest_frame is not None:
        if isinstance(rest_frame, bool) or not isinstance(rest_frame, int) or not (
                -bvh.num_frames <= rest_frame < bvh.num_frames):
            raise ValueError(f"--rest-frame {rest_frame!r}: {bvh.path} has frames 0 to {bvh.num_frames - 1}; give "
                             "the frame of a rest pose (standing, arms out or down)")
        rest_at = rest_frame % bvh.num_frames
        why_rest = "given by --rest-frame"
    elif kind == "flat":
        rest_at, why_rest = choose_rest_frame(bvh, pelvis, index, table, rest_cfg)
    if rest_at is not None:
        pos_k, rot_k = bvh.pelvis_relative(pelvis, slice(rest_at, rest_at + 1))
        ref, rest = rot_k[0], pos_k[0]
        kind_at = rest_pose_kind(rest, index, table, rest_cfg, bvh.joints, pelvis)
        notes.append(f"frame {rest_at} ({kind_at}) stands in for the clip's rest ({why_rest}"
                     + ("; the rest skeleton lies flat, its orientation in the channels)" if kind == "flat" else ")"))
    heads = skeleton.rest_heads.double().numpy()
    body_frames = skeleton.frames().double().numpy()
    order = [j for j in names if j in mapped]
    p = np.stack([rest[index[mapped[j]]] for j in order])
    h = np.stack([heads[names.index(j)] for j in order])
    # the axes from the trunk (spine, neck, head, clavicles, shoulders, hips), whose rest places do not
    # depend on where the arms hang (T-pose, A-pose or a walk's frame 0)
    body_cfg = dialect_settings().body
    trunk_roles = {*body_cfg.spine, *body_cfg.neck, body_cfg.head, *(
        body_cfg.limbs[s][r] for s in "lr" for r in ("clavicle", "upper_arm", "thigh"))}
    trunk = [k for k, j in enumerate(order) if j in trunk_roles]
    axes = file_axes(p[trunk], h[trunk]) if len(trunk) >= 3 else file_axes(p, h)
    unit, mpu = detect_units(p, h, OmegaConf.to_container(settings.units), float(settings.units_tolerance),
                             table.units)
    up = axes.T @ np.array([0.0, 1.0, 0.0])
    below = [k for k in range(len(bvh.joints)) if pelvis in ancestors(bvh, k)]  # the body: joints above the
    # pelvis (a joint_Root on the floor) are not part of it
    every = np.concatenate([rest[below], np.stack([rest[k] + ref[k] @ bvh.joints[k].end for k in below
                                                   if bvh.joints[k].end is not None] or [rest[below[:1]]])])
    height = float((every @ up).max() - (every @ up).min()) * mpu

    # rest alignment A_j: the body's rest bone direction onto the file's
    align = {}
    for j in order:
        i = names.index(j)
        child = next((c for c, par in enumerate(skeleton.parents) if par == i), None)
        d_body = heads[child] - heads[i] if child is not None else body_frames[i][:, 1]
        f = index[mapped[j]]
        b = bvh.joints[f]
        if child is not None and names[child] in mapped:
            d_file = rest[index[mapped[names[child]]]] - rest[f]
        elif table.toward.get(b.name) in index:
            d_file = rest[index[table.toward[b.name]]] - rest[f]
        else:
            kids = [k.offset for k in bvh.joints if k.parent == f]
            d_file = ref[f] @ kids[0] if kids else None if b.end is None else ref[f] @ b.end
        ok = d_file is not None and np.linalg.norm(d_file) > 0 and np.linalg.norm(d_body) > 0
        align[j] = _rotation_between(d_body, axes @ d_file) if ok else np.eye(3)
    # a foot that ends the body's chain has no bone to match: its frame's y is the shin's line (down), the
    # file's foot points forward to the toes, and matching the two turned the ankle 70 degrees at the clip's
    # own rest (the CMU calibration frame). A foot stands the same way in every rest pose (flat, across the
    # shin), so it is aligned as its shin is.
    for side in body_cfg.limbs.values():
        foot, shin = side.get("foot"), side.get("shin")
        if foot in align and shin in align and not any(p == names.index(foot) for p in skeleton.parents):
            align[foot] = align[shin]

    q = bvh.pelvis_relative(pelvis, idx)[1] @ np.swapaxes(ref, -1, -2)  # (F, Jb, 3, 3), file axes, from the rest
    out = np.tile(np.eye(3), (len(idx), len(names), 1, 1))
    glob = [None] * len(names)
    for i, j in enumerate(names):
        par = skeleton.parents[i]
        m_par = np.eye(3) if par < 0 else glob[par]
        if j in mapped:
            glob[i] = axes @ q[:, index[mapped[j]]] @ axes.T @ align[j]
        else:
            glob[i] = np.broadcast_to(m_par, (len(idx), 3, 3))
        w = np.swapaxes(m_par, -1, -2) @ glob[i]
        out[:, i] = body_frames[i].T @ w @ body_frames[i]
    dt = bvh.frame_time
    if fps is None:
        src = idx.astype(np.float64)
        rate = 1.0 / (dt * (frames.step or 1))
    else:
        t_src = (idx - idx[0]) * dt
        t_new = np.arange(count_frames(bvh, idx, fps)) / fps
        if len(idx) > 1:
            out = np.stack([Slerp(t_src, Rotation.from_matrix(out[:, i]))(np.minimum(t_new, t_src[-1])).as_matrix()
                            for i in range(len(names))], 1)
        else:
            out = out[:1]
        src = idx[0] + t_new[:len(out)] / dt
        rate = float(fps)
    times = (src - src[0]) * dt
    sanity = sanity_report(out, skeleton, height, settings.sanity)
    if sanity["problems"] and not trust:
        raise BvhError(f"{bvh.path}: the clip retargeted onto the body does not stand as a person: "
                       f"{'; '.join(sanity['problems'])}; see what pbc made of it with `pbc motion inspect "
                       f"{bvh.path}` and fix its rest (--rest-frame K) or its joint map (--bvh-map FILE.yaml), or "
                       "go on as it is with --trust-clip")
    return Motion(out, times, src, rate, table, unit, mpu, axes, mapped, ignored, unknown, missing, notes, kind,
                  height, rest_at, pelvis, sanity)


def poses_from_clip(path: str | Path, skeleton: Skeleton, joint_map: str | Path = "auto",
                    frames: str | slice | None = None, fps: float | None = None, allow_rest: bool = False,
                    max_frames: int | None = None, rest_frame: int | None = None, trust: bool = False) -> Motion:
    """The one door from a motion clip to the body's poses (Motion.poses (N, J, 3, 3)): read the .bvh, match
    its joints (`joint_map`: "auto" = a shipped table knowing every joint, else by name and structure; a
    table's name or a YAML file wins), `frames` a START:STOP:STEP string or a slice of its frames, resampled
    at `fps` (None: as selected). Bad files and requests: one ValueError naming the file and the fix."""
    bvh = read_bvh(path)
    check_skeleton(bvh)
    chosen = frames if isinstance(frames, slice) else parse_frames(frames)
    return bvh_to_poses(bvh, skeleton, choose_joint_map(bvh, joint_map), chosen, fps, allow_rest, max_frames,
                        rest_frame, trust)
