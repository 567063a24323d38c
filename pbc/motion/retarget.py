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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf
from scipy.spatial.transform import Rotation, Slerp

from pbc.core.paths import CONF_DIR
from pbc.geometry.body.skeleton import Skeleton
from pbc.motion.bvh import Bvh, BvhError, check_skeleton, read_bvh
from pbc.motion.dialects import JointMap, dialect_settings, match_joints

MOTION_CONF = CONF_DIR / "motion"
SETTINGS = "sequence"  # conf/motion/sequence.yaml: not a joint map
NOT_TABLES = (SETTINGS, "dialects")  # conf/motion/dialects.yaml: the matching without a table


def motion_settings():
    """conf/motion/sequence.yaml (units, range tolerance, video)."""
    return OmegaConf.load(MOTION_CONF / f"{SETTINGS}.yaml")


def shipped_joint_maps() -> list[str]:
    return sorted(p.stem for p in MOTION_CONF.glob("*.yaml") if p.stem not in NOT_TABLES)


def load_joint_map(name_or_path: str | Path) -> JointMap:
    """A shipped table by name (conf/motion/<name>.yaml) or a YAML file of the same layout."""
    p = Path(name_or_path)
    if p.suffix not in (".yaml", ".yml") and str(name_or_path) in NOT_TABLES:
        raise ValueError(f"BVH joint map {name_or_path!r}: conf/motion/{name_or_path}.yaml holds settings, not a "
                         f"joint map; give a shipped table ({', '.join(shipped_joint_maps())}), a YAML file or auto")
    if p.suffix not in (".yaml", ".yml"):
        p = MOTION_CONF / f"{name_or_path}.yaml"
    if not p.is_file():
        raise ValueError(f"BVH joint map {name_or_path!r} not found: give a YAML file (layout of "
                         f"{MOTION_CONF / 'cmu_mb.yaml'}) or a shipped table: {', '.join(shipped_joint_maps())}")
    cfg = OmegaConf.to_container(OmegaConf.load(p))
    if not isinstance(cfg, dict) or not isinstance(cfg.get("joints"), dict):
        raise ValueError(f"BVH joint map {p}: needs a 'joints' mapping (body joint: BVH joint name) and a "
                         "'bones' list, as conf/motion/cmu_mb.yaml")
    joints = {str(k): str(v) for k, v in cfg["joints"].items() if v is not None}
    why = {j: f"row of {p.name}" for j in joints}
    return JointMap(p.stem, p, joints, tuple(str(b) for b in cfg.get("bones") or ()), why,
                    dialect=f"table {p.stem}")


def choose_joint_map(bvh: Bvh, spec: str | Path = "auto") -> JointMap:
    """`spec`: a shipped table's name or a YAML file (it wins); "auto": the shipped table that knows every
    joint name of the clip (the CMU releases), else the joints matched by name and structure
    (pbc.motion.dialects.match_joints: Mixamo, Bandai Namco, LAFAN1, Blender, Rokoko, ...)."""
    if str(spec) != "auto":
        return load_joint_map(spec)
    tables = [load_joint_map(n) for n in shipped_joint_maps()]
    names = set(bvh.names)
    best = max(tables, key=lambda t: (len(names & t.known()), -tables.index(t)))
    if names <= best.known():
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


def detect_units(p: np.ndarray, h: np.ndarray, units: dict, tolerance: float = 1.6) -> tuple[str, float]:
    """(unit name, metres per file unit) from the size of skeleton p (n, 3) against the body's h (n, 3): the
    nearest unit in log ratio when within `tolerance` of it, else a scaled rig ("cm x2.00", its measured
    metres per unit: a Mixamo character exported at twice the size)."""
    hn, pn = np.linalg.norm(h, axis=1).sum(), np.linalg.norm(p, axis=1).sum()
    if hn <= 0 or pn <= 0:
        return "unknown", 1.0
    mpu = hn / pn
    name = min(units, key=lambda u: abs(np.log(mpu / float(units[u]))))
    ratio = mpu / float(units[name])
    if max(ratio, 1 / ratio) <= tolerance:
        return name, float(units[name])
    return f"{name} x{1 / ratio:.2f}", float(mpu)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two vectors (nan when one is zero)."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0))))


def rest_pose_kind(rest: np.ndarray, index: dict, table: JointMap, cfg, bvh_joints=()) -> str:
    """The clip's rest pose (positions rest (J, 3)): "T-pose", "A-pose", "arms down", "arms up", "standing"
    (no arms matched) or "flat" (the skeleton lies along one direction at zero rotation, its orientation in
    the channels: Bandai Namco), from the angles between the spine and the upper arm and the thigh. bvh_joints:
    the clip's joints (an upper arm without a `toward` points at its first child)."""
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
    if top is None or not np.linalg.norm(top - rest[0]) > 0:
        return "unknown"
    up = top - rest[0]
    arms = [_angle(b, up) for b in (bone(body.limbs.l.upper_arm), bone(body.limbs.r.upper_arm)) if b is not None]
    legs = [_angle(pos(body.limbs[s].shin) - pos(body.limbs[s].thigh), up) for s in "lr"
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

    def summary(self) -> dict:
        return {"joint_map": str(self.table.path or self.table.name), "dialect": self.table.dialect,
                "units": self.units, "metres_per_unit": self.metres_per_unit, "rest_pose": self.rest_pose,
                "height_m": round(self.height_m, 4),
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
                 fps: float | None = None, allow_rest: bool = False, max_frames: int | None = None) -> Motion:
    """The body's poses (N, J, 3, 3) for the clip's `frames` (a slice of its frames), resampled at `fps`
    (None: the clip's frames as selected). Raises BvhError when no joint of the clip is in the table, or
    when the body's arms, legs or spine would stay at rest (`allow_rest` goes on with them at rest), and
    ValueError for a request of more than `max_frames` poses (None: conf/motion/sequence.yaml's)."""
    settings = motion_settings()
    check_skeleton(bvh)
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
    notes = []
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

    # the rest: the OFFSETs' layout; a skeleton lying flat (its orientation in the channels) takes frame 0's
    # posture as its rest instead, each joint's rotation then taken relative to frame 0's
    rest = bvh.rest_positions()
    kind = rest_pose_kind(rest, index, table, dialect_settings().rest, bvh.joints)
    ref = np.tile(np.eye(3), (len(bvh.joints), 1, 1))
    if kind == "flat":
        ref = bvh.root_relative_rotations(slice(0, 1))[0]
        rest = bvh.root_relative_positions(slice(0, 1))[0]
        frame0 = rest_pose_kind(rest, index, table, dialect_settings().rest, bvh.joints)
        notes.append(f"the clip's rest skeleton lies flat (its orientation is in the channels): frame 0 ({frame0}) "
                     "stands in for its rest")
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
    unit, mpu = detect_units(p, h, OmegaConf.to_container(settings.units), float(settings.units_tolerance))
    up = axes.T @ np.array([0.0, 1.0, 0.0])
    every = np.concatenate([rest, np.stack([rest[k] + ref[k] @ jt.end for k, jt in enumerate(bvh.joints)
                                            if jt.end is not None] or [rest[:1]])])
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

    q = bvh.root_relative_rotations(idx) @ np.swapaxes(ref, -1, -2)  # (F, Jb, 3, 3), file axes, from the rest
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
    return Motion(out, times, src, rate, table, unit, mpu, axes, mapped, ignored, unknown, missing, notes, kind,
                  height)


def poses_from_clip(path: str | Path, skeleton: Skeleton, joint_map: str | Path = "auto",
                    frames: str | slice | None = None, fps: float | None = None, allow_rest: bool = False,
                    max_frames: int | None = None) -> Motion:
    """The one door from a motion clip to the body's poses (Motion.poses (N, J, 3, 3)): read the .bvh, match
    its joints (`joint_map`: "auto" = a shipped table knowing every joint, else by name and structure; a
    table's name or a YAML file wins), `frames` a START:STOP:STEP string or a slice of its frames, resampled
    at `fps` (None: as selected). Bad files and requests: one ValueError naming the file and the fix."""
    bvh = read_bvh(path)
    check_skeleton(bvh)
    chosen = frames if isinstance(frames, slice) else parse_frames(frames)
    return bvh_to_poses(bvh, skeleton, choose_joint_map(bvh, joint_map), chosen, fps, allow_rest, max_frames)
