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
from pbc.motion.bvh import Bvh, BvhError

MOTION_CONF = CONF_DIR / "motion"
SETTINGS = "sequence"  # conf/motion/sequence.yaml: not a joint map


def motion_settings():
    """conf/motion/sequence.yaml (units, range tolerance, video)."""
    return OmegaConf.load(MOTION_CONF / f"{SETTINGS}.yaml")


@dataclass(frozen=True)
class JointMap:
    name: str
    path: Path
    joints: dict[str, str]  # body joint -> BVH joint (null rows dropped)
    bones: tuple[str, ...]  # every bone of the dialect

    def known(self) -> set[str]:
        return set(self.bones) | set(self.joints.values())


def shipped_joint_maps() -> list[str]:
    return sorted(p.stem for p in MOTION_CONF.glob("*.yaml") if p.stem != SETTINGS)


def load_joint_map(name_or_path: str | Path) -> JointMap:
    """A shipped table by name (conf/motion/<name>.yaml) or a YAML file of the same layout."""
    p = Path(name_or_path)
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
    return JointMap(p.stem, p, joints, tuple(str(b) for b in cfg.get("bones") or ()))


def choose_joint_map(bvh: Bvh, spec: str | Path = "auto") -> JointMap:
    """`spec` ("auto": the shipped table that knows most of the clip's joint names)."""
    if str(spec) != "auto":
        return load_joint_map(spec)
    tables = [load_joint_map(n) for n in shipped_joint_maps()]
    names = set(bvh.names)
    return max(tables, key=lambda t: (len(names & t.known()), -tables.index(t)))


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


def detect_units(p: np.ndarray, h: np.ndarray, units: dict) -> tuple[str, float]:
    """(unit name, metres per file unit) nearest in log ratio to the size of rest skeleton p against h."""
    hn, pn = np.linalg.norm(h, axis=1).sum(), np.linalg.norm(p, axis=1).sum()
    if hn <= 0 or pn <= 0:
        return "unknown", 1.0
    mpu = hn / pn
    name = min(units, key=lambda u: abs(np.log(mpu / float(units[u]))))
    return name, float(units[name])


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

    def summary(self) -> dict:
        return {"joint_map": str(self.table.path), "units": self.units, "metres_per_unit": self.metres_per_unit,
                "fps": self.fps, "frames": len(self.poses), "mapped": self.mapped, "ignored": self.ignored,
                "unknown": self.unknown, "at_rest": self.missing, "source_frames": [
                    round(float(f), 4) for f in self.source_frames]}


def bvh_to_poses(bvh: Bvh, skeleton: Skeleton, table: JointMap, frames: slice = slice(None),
                 fps: float | None = None) -> Motion:
    """The body's poses (N, J, 3, 3) for the clip's `frames` (a slice of its frames), resampled at `fps`
    (None: the clip's frames as selected). Raises BvhError when no joint of the clip is in the table."""
    settings = motion_settings()
    names = list(skeleton.names)
    index = {n: i for i, n in enumerate(bvh.names)}
    mapped = {j: table.joints[j] for j in names if table.joints.get(j) in index}
    root = bvh.joints[0]
    if not mapped:
        raise BvhError(f"{bvh.path}:{root.line}: none of the clip's {len(bvh.names)} joints "
                       f"({', '.join(bvh.names[:12])}{' ...' if len(bvh.names) > 12 else ''}) drives a body joint "
                       f"in the joint map {table.path}; edit that table's rows (body joint: BVH joint name) or "
                       f"pick another with --bvh-map (shipped: {', '.join(shipped_joint_maps())})")
    used = set(mapped.values()) | {root.name}
    ignored = [n for n in bvh.names if n not in used and n in table.known()]
    unknown = [n for n in bvh.names if n not in used and n not in table.known()]
    missing = [j for j in names if j not in mapped]
    notes = []
    if unknown:
        notes.append(f"{len(unknown)} BVH joints are not in the joint map {table.path} (another dialect?): "
                     f"{', '.join(unknown)}; add them to its rows or bones, or pick another table with --bvh-map")
    if ignored:
        notes.append(f"{len(ignored)} BVH joints have no body joint and are ignored: {', '.join(ignored)}")
    if missing:
        notes.append(f"{len(missing)} body joints are not in the clip and stay at rest: {', '.join(missing)}")

    rest = bvh.rest_positions()
    heads = skeleton.rest_heads.double().numpy()
    body_frames = skeleton.frames().double().numpy()
    order = [j for j in names if j in mapped]
    p = np.stack([rest[index[mapped[j]]] for j in order])
    h = np.stack([heads[names.index(j)] for j in order])
    axes = file_axes(p, h)
    unit, mpu = detect_units(p, h, OmegaConf.to_container(settings.units))

    # rest alignment A_j: the body's rest bone direction onto the file's
    align = {}
    for j in order:
        i = names.index(j)
        child = next((c for c, par in enumerate(skeleton.parents) if par == i), None)
        d_body = heads[child] - heads[i] if child is not None else body_frames[i][:, 1]
        b = bvh.joints[index[mapped[j]]]
        if child is not None and names[child] in mapped:
            d_file = rest[index[mapped[names[child]]]] - rest[index[mapped[j]]]
        else:
            kids = [k.offset for k in bvh.joints if k.parent == index[mapped[j]]]
            d_file = kids[0] if kids else b.end
        ok = d_file is not None and np.linalg.norm(d_file) > 0 and np.linalg.norm(d_body) > 0
        align[j] = _rotation_between(d_body, axes @ d_file) if ok else np.eye(3)

    # frames: a slice of the clip, then (with fps) resampled over its span
    idx = np.arange(bvh.num_frames)[frames]
    if len(idx) == 0:
        raise ValueError(f"--frames {frames.start}:{frames.stop}:{frames.step} selects no frame of {bvh.path} "
                         f"({bvh.num_frames} frames)")
    if fps is not None:
        if not fps > 0:
            raise ValueError(f"--fps {fps}: give frames per second > 0")
        if (frames.step or 1) != 1:
            raise ValueError("give either a --frames step or --fps, not both (the step picks every n-th frame, "
                             "--fps resamples)")
        idx = np.arange(idx[0], idx[-1] + 1)
    q = bvh.root_relative_rotations(idx)  # (F, Jb, 3, 3), file axes
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
        t_new = np.arange(0.0, t_src[-1] + 1e-9, 1.0 / fps)
        if len(idx) > 1:
            out = np.stack([Slerp(t_src, Rotation.from_matrix(out[:, i]))(t_new).as_matrix()
                            for i in range(len(names))], 1)
        else:
            out = out[:1]
        src = idx[0] + t_new / dt
        rate = float(fps)
    times = (src - src[0]) * dt
    return Motion(out, times, src, rate, table, unit, mpu, axes, mapped, ignored, unknown, missing, notes)
