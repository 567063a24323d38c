"""Random poses (appendix D.3): Euler angles within joint limits, pruned for arm-torso overlap and, on a body
with legs whose legs move, for leg-leg and leg-torso overlap.

Euler convention (`euler_xzy_to_matrix`): angles are given per axis in (x, y, z) order, like the joint
limits, and applied in the order x, then z, then y about the joint's *moving* local axes (intrinsic):
    R = Rx(x) @ Rz(z) @ Ry(y)
(the same matrix as extrinsic rotations about the fixed axes in the order y, z, x). With the bone along
local y this makes y a pure twist, and for the arms (local x vertical) x the azimuth and z the altitude,
so x uniform and sin(z) uniform spread the arm direction uniformly over the sphere.

Sampling is deterministic: candidates are drawn in fixed-size blocks, block b from
numpy.random.default_rng([seed, b]), and kept in order, so kept sample i depends only on the seed
(not on n); the first k of sample_poses(n) equal sample_poses(k).

Modes (`sampling.modes`, beyond D.3): the postures real motion holds most, which D.3's sphere sampler
rarely draws (arms hanging: the lowest 15% of the altitude range is 6% of a uniform sphere), drawn on
purpose. A candidate falls in a mode with the mode's `fraction`; its named joint axes are then uniform in a
share of their limits (0 = the limit's min, 1 = its max, so the same share fits a re-rested body), the
other axes as D.3 draws them; pruning follows as for any candidate. Modes draw from their own stream,
default_rng([seed, b, 1]): with every fraction 0 (the default) the poses are those of D.3 alone, bit for bit.

A mode may instead (or also) draw joints in a cone (`cone`): each named joint's bone direction uniform over
the cap of `half_angle_deg` round a direction of the root frame (`around`, e.g. straight down), its twist about
the bone uniform in `twist_deg`, both in the swing-twist chart (pbc.geometry.body.skeleton.swing_twist_angles);
with `clear` an arm the cone puts inside the torso is raised out of it (`clear_arms`, as a clip's arms are)
instead of pruned, so the data holds arms along the torso's surface, where retargeted clips put them.
Why: Euler limits are boxes whose corners turn meaningless where an arm hangs (z near -90: x and y turn about
one axis), so shares of them cannot say "hanging, swung forward or back, any twist"; a walk's arms are there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch import Tensor  # noqa: E402

from pbc.core.io import save_figure  # noqa: E402
from pbc.geometry.body.base import Body, body_sdf, bones_sdf  # noqa: E402
from pbc.geometry.body.skeleton import (  # noqa: E402
    Skeleton,
    forward_kinematics,
    linear_blend_skinning,
    swing_to,
    swing_twist_to_matrix,
    xzy_angles,
)

TORSO, LEFT_ARM, RIGHT_ARM = 0, 1, 2
X, Y, Z = 0, 1, 2


@dataclass(frozen=True)
class SamplingSettings:
    """The `sampling` block of conf/body/mannequin.yaml (defaults mirror it; a test keeps them equal)."""

    halfnormal_joints: tuple[str, ...] = ("lower_back", "spine", "spine1", "neck", "neck1", "head")
    halfnormal_sigma: float = 0.5  # std as a fraction of the limit on that side
    positive_prob: float = 0.5  # mixture weight of the positive half-normal
    probes_per_arm: int = 53
    probe_min_distance: float = 0.10  # m from the arm joint
    prune_tolerance: float = 0.0  # m
    block_size: int = 1024
    max_blocks: int = 1000
    posed_joints: tuple[str, ...] = ()  # joints that are sampled; the rest stay at rest. () = all
    # legs (a body that has them, conf/body/anny.yaml): each leg's joints, hip first; () = no leg pruning.
    # Only when a leg joint is posed are poses pruned for a leg inside the other leg or inside the torso.
    left_leg: tuple[str, ...] = ()
    right_leg: tuple[str, ...] = ()
    probes_per_leg: int = 53
    leg_probe_min_distance: float = 0.15  # m from the hip joint: clear of the groin, where the legs meet
    leg_torso_joints: tuple[str, ...] = ()  # the primitives (by joint, `root` included) a leg must not enter
    # the active modes (fraction > 0): (name, fraction, ((joint, axis, low share, high share), ...), cone),
    # cone None or (joints, around (3,), half_angle_deg, (twist low, twist high), clear None or (step, max));
    # see the module docstring.
    # A mode at fraction 0 is left out, so the default equals a config with every mode off
    modes: tuple = ()


_NAME_LISTS = ("halfnormal_joints", "posed_joints", "left_leg", "right_leg", "leg_torso_joints")


def sampling_settings_from_config(cfg: Mapping) -> SamplingSettings:
    """SamplingSettings from a `sampling` config node (missing keys keep their defaults)."""
    known = {f.name for f in fields(SamplingSettings)}
    unknown = set(cfg) - known
    if unknown:
        raise ValueError(f"unknown sampling settings {sorted(unknown)}; known: {sorted(known)}")
    kw = {k: (tuple(str(n) for n in v) if k in _NAME_LISTS else v) for k, v in cfg.items()}
    kw["modes"] = _parse_modes(cfg.get("modes") or {})
    return SamplingSettings(**kw)


def _parse_modes(modes: Mapping) -> tuple:
    """`sampling.modes` ({name: {fraction, range: {joint: {axis: [low, high] shares}}, cone: {joints, around,
    half_angle_deg, twist_deg}}}) -> the active modes, checked (fractions in [0, 1] summing to at most 1, shares
    0 <= low <= high <= 1, axes x / y / z, a cone's half angle in (0, 180], its twist [low, high] degrees)."""
    out, total = [], 0.0
    for name, mode in modes.items():
        key = f"sampling.modes.{name}"
        unknown = set(mode) - {"fraction", "range", "cone"}
        if unknown:
            raise ValueError(f"{key}: unknown keys {sorted(unknown)}; a mode has a fraction, a range and a cone")
        fraction = float(mode.get("fraction", 0.0))
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"{key}.fraction={fraction}: give the share of poses drawn in this mode, in [0, 1]")
        total += fraction
        ranges = []
        for joint, axes in (mode.get("range") or {}).items():
            for axis, share in axes.items():
                ok = axis in ("x", "y", "z") and len(share) == 2 and 0.0 <= float(share[0]) <= float(share[1]) <= 1.0
                if not ok:
                    raise ValueError(f"{key}.range.{joint}.{axis}={list(share)}: give an axis x, y or z and "
                                     "[low, high] shares of the joint's limits, 0 <= low <= high <= 1")
                ranges.append((str(joint), "xyz".index(axis), float(share[0]), float(share[1])))
        cone = _parse_cone(mode.get("cone"), f"{key}.cone")
        if fraction > 0:
            out.append((str(name), fraction, tuple(ranges), cone))
    if total > 1.0 + 1e-9:
        raise ValueError(f"sampling.modes: the fractions sum to {total:g} > 1; lower them (the rest is plain D.3)")
    return tuple(out)


def _parse_cone(cone: Mapping | None, key: str) -> tuple | None:
    """A mode's `cone` node -> (joints, around (3,) unit, half_angle_deg, (twist low, twist high)), or None."""
    if not cone:
        return None
    unknown = set(cone) - {"joints", "around", "half_angle_deg", "twist_deg", "clear"}
    if unknown:
        raise ValueError(f"{key}: unknown keys {sorted(unknown)}; a cone has joints, around, half_angle_deg, "
                         "twist_deg and clear")
    around = np.asarray(cone.get("around", ()), dtype=np.float64)
    half = float(cone.get("half_angle_deg", 0.0))
    twist = [float(t) for t in cone.get("twist_deg", ())]
    joints = tuple(str(j) for j in cone.get("joints", ()))
    if not joints:
        raise ValueError(f"{key}.joints: name the joints drawn in the cone (e.g. [l_arm, r_arm])")
    if around.shape != (3,) or not np.linalg.norm(around) > 0:
        raise ValueError(f"{key}.around={around.tolist()}: give the cone's axis as a direction [x, y, z] of the "
                         "root frame (straight down: [0, -1, 0])")
    if not 0.0 < half <= 180.0:
        raise ValueError(f"{key}.half_angle_deg={half}: give the cone's half angle in (0, 180] degrees")
    if len(twist) != 2 or not -180.0 <= twist[0] <= twist[1] <= 180.0:
        raise ValueError(f"{key}.twist_deg={twist}: give [low, high] degrees of twist about the bone, "
                         "-180 <= low <= high <= 180")
    clear = cone.get("clear")
    if clear:
        step, most = float(clear.get("step_deg", 0.0)), float(clear.get("max_deg", 0.0))
        if set(clear) - {"step_deg", "max_deg"} or not 0.0 < step <= most:
            raise ValueError(f"{key}.clear={dict(clear)}: give step_deg and max_deg, 0 < step_deg <= max_deg "
                             "(as conf/motion/sequence.yaml's clear_arms), or null to prune such arms")
        clear = (step, most)
    return joints, tuple(around / np.linalg.norm(around)), half, (twist[0], twist[1]), clear or None


def modes_record(settings: SamplingSettings) -> dict:
    """The active modes as plain data (a dataset's fingerprint): {name: {fraction, range: [[joint, axis,
    low, high], ...]}} and, for a mode with a cone, its cone; empty when every mode is off."""
    out = {}
    for name, f, ranges, cone in settings.modes:
        out[name] = {"fraction": f, "range": [[j, "xyz"[a], lo, hi] for j, a, lo, hi in ranges]}
        if cone is not None:
            joints, around, half, twist, clear = cone
            out[name]["cone"] = {"joints": list(joints), "around": list(around), "half_angle_deg": half,
                                 "twist_deg": list(twist)}
            if clear is not None:
                out[name]["cone"]["clear"] = {"step_deg": clear[0], "max_deg": clear[1]}
    return out


def cone_rotations(u: np.ndarray, around_local: np.ndarray, half_angle_deg: float,
                   twist_deg: tuple[float, float]) -> np.ndarray:
    """(n, 3, 3) joint rotations whose bone (local y) points uniformly over the cap of half_angle_deg round
    around_local (3,) (a unit direction in the joint's rest frame), twisted uniformly in twist_deg about the
    bone (swing-twist chart). u (n, 3) uniform [0, 1) numbers: cap height, azimuth, twist."""
    cos_t = 1.0 - u[:, 0] * (1.0 - np.cos(np.radians(half_angle_deg)))  # uniform over the cap's area
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    phi = 2.0 * np.pi * u[:, 1]
    a = np.asarray(around_local, np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    d = cos_t[:, None] * a + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    angles = swing_to(d)  # the swing-twist chart's (x, 0, z), then its twist
    angles[:, 1] = twist_deg[0] + u[:, 2] * (twist_deg[1] - twist_deg[0])
    return swing_twist_to_matrix(torch.from_numpy(angles)).numpy()


def apply_modes(angles: np.ndarray, skel: Skeleton, rng: np.random.Generator,
                settings: SamplingSettings) -> list[tuple[np.ndarray, float, float]]:
    """Put candidates (n, J, 3) degrees, in place, into the modes: candidate i falls in mode k with its
    fraction, and that mode's joint axes are redrawn uniformly in their share of the limits, its cone joints
    in their cone (`cone_rotations`, written back as Euler angles). Joints the sampler keeps at rest
    (`posed_joints`) stay there. Returns, per cone that clears arms out of the torso, its candidates (n,) bool
    and its (step, max) degrees (`sample_poses` raises them out; `clear_arms`)."""
    if not settings.modes:
        return []
    n = len(angles)
    lim = skel.limits_deg.double().numpy()
    pick = rng.random(n)
    u = rng.random((n, sum(len(r) for _, _, r, _ in settings.modes)))  # every stream drawn: counts never shift it
    cones = [c for *_, c in settings.modes if c is not None]
    # drawn only when a mode has a cone, after the rest: data sets without one keep their poses bit for bit
    u_cone = rng.random((n, sum(len(c[0]) for c in cones), 3)) if cones else None
    posed = set(settings.posed_joints)
    frames = skel.frames().double().numpy()
    start, col, ccol, clearing = 0.0, 0, 0, []
    for name, fraction, ranges, cone in settings.modes:
        rows = (pick >= start) & (pick < start + fraction)
        start += fraction
        for joint, axis, lo, hi in ranges:
            j = skel.indices([joint], f"sampling.modes.{name}.range")[0]
            if not posed or joint in posed:
                a, b = lim[j, axis]
                low, high = a + lo * (b - a), a + hi * (b - a)
                angles[rows, j, axis] = low + u[rows, col] * (high - low)
            col += 1
        if cone is None:
            continue
        joints, around, half, twist, clear = cone
        for joint, j in zip(joints, skel.indices(joints, f"sampling.modes.{name}.cone.joints"), strict=True):
            if (not posed or joint in posed) and rows.any():
                local = frames[j].T @ np.asarray(around)  # the root-frame direction in the joint's rest frame
                angles[rows, j] = xzy_angles(cone_rotations(u_cone[rows, ccol], local, half, twist))
            ccol += 1
        if clear is not None:
            clearing.append((rows, *clear))
    return clearing


def _axis_rotation(angles_rad: Tensor, axis: int) -> Tensor:
    """(...,) angles -> (..., 3, 3) right-handed rotations about one coordinate axis."""
    c, s = torch.cos(angles_rad), torch.sin(angles_rad)
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    if axis == X:
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == Y:
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def euler_xzy_to_matrix(angles_deg) -> Tensor:
    """Euler angles (..., 3) in degrees, per axis (x, y, z) -> rotations (..., 3, 3) = Rx Rz Ry.

    Applied x then z then y about the moving axes (see the module docstring).
    """
    a = torch.as_tensor(angles_deg)
    if not a.is_floating_point():
        a = a.to(torch.float32)
    if a.shape[-1:] != (3,):
        raise ValueError(f"angles_deg: expected shape (..., 3) per axis (x, y, z), got {tuple(a.shape)}")
    r = torch.deg2rad(a)
    return _axis_rotation(r[..., X], X) @ _axis_rotation(r[..., Z], Z) @ _axis_rotation(r[..., Y], Y)


def sample_angles(skel: Skeleton, n: int, rng: np.random.Generator, settings: SamplingSettings) -> np.ndarray:
    """(n, J, 3) Euler angles in degrees within the joint limits (no pruning).

    Centre-line joints: per axis a mixture of two half-normals (one per direction, std = sigma x that
    side's limit), clipped to the limits. Other joints (shoulders, arms): x uniform, sin(z) uniform,
    y uniform, within limits.
    """
    lim = skel.limits_deg.double().numpy()  # (J, 3, 2)
    lo, hi = lim[..., 0], lim[..., 1]
    J = skel.num_joints
    unknown = [name for name in settings.halfnormal_joints if name not in skel.names]
    if unknown:
        raise ValueError(f"sampling.halfnormal_joints: unknown joints {unknown}; joints: {list(skel.names)}")
    centre = np.array([name in settings.halfnormal_joints for name in skel.names])
    # draw every stream for every joint so the random sequence does not depend on which joints are which
    mag = np.abs(rng.standard_normal((n, J, 3))) * settings.halfnormal_sigma
    positive = rng.random((n, J, 3)) < settings.positive_prob
    u = rng.random((n, J, 3))
    half = np.clip(np.where(positive, mag * np.maximum(hi, 0.0), -mag * np.maximum(-lo, 0.0)), lo, hi)
    uniform = lo + u * (hi - lo)
    s_lo, s_hi = np.sin(np.deg2rad(lo[:, Z])), np.sin(np.deg2rad(hi[:, Z]))
    altitude = np.rad2deg(np.arcsin(s_lo + u[..., Z] * (s_hi - s_lo)))
    sphere = uniform.copy()
    sphere[..., Z] = np.clip(altitude, lo[:, Z], hi[:, Z])  # arcsin round-off must not leave the limits
    out = np.where(centre[None, :, None], half, sphere)
    if settings.posed_joints:  # a garment's own joint set (the necktie: 4 centre-line joints)
        posed = set(skel.indices(settings.posed_joints, "sampling.posed_joints"))
        out[:, [j not in posed for j in range(skel.num_joints)]] = 0.0
    return out


def _probe_candidates(body: Body, part: int, joint: str, settings: SamplingSettings) -> tuple[Tensor, Tensor]:
    """Arm-part vertex ids outside the torso part and at least probe_min_distance from the arm joint, and every
    body vertex's distance to that joint."""
    skel = body.skeleton
    dist = (body.vertices - skel.rest_heads[skel.index(joint)]).norm(dim=1)
    return (body.parts[part] & ~body.parts[TORSO] & (dist >= settings.probe_min_distance)).nonzero()[:, 0], dist


def arm_probe_indices(body: Body, settings: SamplingSettings) -> Tensor:
    """(2 * probes_per_arm,) long body-vertex ids on the arm parts, fixed and deterministic.

    Candidates: arm-part vertices outside the torso part and at least probe_min_distance from their arm
    joint; chosen by farthest-point sampling (started at the vertex farthest from the joint) so they
    spread over the whole arm. A body without enough of them on an arm is a ValueError saying what to change.
    """
    probes, why = _arm_probes(body, settings)
    if probes is None:
        raise ValueError(why)
    return probes


def arm_probes_if_any(body: Body, settings: SamplingSettings) -> Tensor | None:
    """`arm_probe_indices`, or None for a body without both arm joints or without enough arm vertices to
    probe (a stand-in body): callers that only correct poses leave them as they are then."""
    if not {"l_arm", "r_arm"} <= set(body.skeleton.names):
        return None
    return _arm_probes(body, settings)[0]


def _arm_probes(body: Body, settings: SamplingSettings) -> tuple[Tensor | None, str]:
    out = []
    for part, joint in ((LEFT_ARM, "l_arm"), (RIGHT_ARM, "r_arm")):
        cand, dist = _probe_candidates(body, part, joint, settings)
        if len(cand) < settings.probes_per_arm:
            return None, (f"only {len(cand)} probe candidates on part {part} ({joint}); "
                          f"need {settings.probes_per_arm}: lower sampling.probe_min_distance or use a finer body mesh")
        out.append(cand[_farthest_points(body.vertices[cand].double(), int(dist[cand].argmax()),
                                         settings.probes_per_arm)])
    return torch.cat(out), ""


def _farthest_points(pts: Tensor, first: int, count: int) -> Tensor:
    """(count,) long indices into pts (n, 3): farthest-point sampling started at `first`."""
    chosen = [first]
    gap = (pts - pts[first]).norm(dim=1)
    for _ in range(count - 1):
        k = int(gap.argmax())
        chosen.append(k)
        gap = torch.minimum(gap, (pts - pts[k]).norm(dim=1))
    return torch.tensor(chosen)


def legs_pruned(skel: Skeleton, settings: SamplingSettings) -> bool:
    """Whether poses are pruned for the legs: the settings name both legs and a leg joint is posed (a body
    whose legs stay at rest, as every upper-body garment keeps them, samples exactly as without legs)."""
    if not (settings.left_leg and settings.right_leg):
        return False
    legs = [*settings.left_leg, *settings.right_leg]
    skel.indices(legs, "sampling.left_leg / right_leg")  # unknown names: one error naming them
    skel.indices([j for j in settings.leg_torso_joints if j != "root"], "sampling.leg_torso_joints")
    return not settings.posed_joints or any(j in settings.posed_joints for j in legs)


def _leg_columns(skel: Skeleton, joints) -> list[int]:
    """Weight / primitive columns (0 root, 1 + j joint j) of joint names (`root` allowed)."""
    return [0 if j == "root" else skel.index(j) + 1 for j in joints]


def leg_probe_indices(body: Body, settings: SamplingSettings) -> tuple[Tensor, Tensor]:
    """(probes_per_leg,) long body-vertex ids on the left leg and on the right leg, fixed and deterministic.

    Candidates: vertices carried mostly by the leg's joints (their weights sum to more than a half) at
    least leg_probe_min_distance from its hip; farthest-point sampling from the vertex farthest from the
    hip (the toes), so they cover thigh, shin and foot.
    """
    skel = body.skeleton
    out = []
    for name, joints in (("left_leg", settings.left_leg), ("right_leg", settings.right_leg)):
        hip = skel.rest_heads[skel.index(joints[0])]
        dist = (body.vertices - hip).norm(dim=1)
        carried = body.weights[:, _leg_columns(skel, joints)].sum(1)
        cand = ((carried > 0.5) & (dist >= settings.leg_probe_min_distance)).nonzero()[:, 0]
        if len(cand) < settings.probes_per_leg:
            raise ValueError(
                f"only {len(cand)} probe candidates on the {name.replace('_', ' ')} ({', '.join(joints)}); need "
                f"{settings.probes_per_leg}: lower sampling.leg_probe_min_distance or sampling.probes_per_leg"
            )
        out.append(cand[_farthest_points(body.vertices[cand].double(), int(dist[cand].argmax()),
                                         settings.probes_per_leg)])
    return out[0], out[1]


def legs_collide(body: Body, rotations: Tensor, probes: tuple[Tensor, Tensor], settings: SamplingSettings) -> Tensor:
    """(B,) bool: a probe of one leg lies inside the other leg's primitives, or a leg probe inside the
    `leg_torso_joints` primitives, in the posed body. rotations (B, J, 3, 3); probes from leg_probe_indices."""
    skel = body.skeleton
    transforms = forward_kinematics(skel, rotations)
    left, right = probes
    ids = torch.cat([left, right])
    posed = linear_blend_skinning(body.vertices[ids], body.weights[ids], transforms)  # (B, 2P, 3)
    n = len(left)
    tol = -settings.prune_tolerance
    bad = (bones_sdf(body, rotations, posed[:, :n], _leg_columns(skel, settings.right_leg)) < tol).any(1)
    bad |= (bones_sdf(body, rotations, posed[:, n:], _leg_columns(skel, settings.left_leg)) < tol).any(1)
    if settings.leg_torso_joints:
        bad |= (bones_sdf(body, rotations, posed, _leg_columns(skel, settings.leg_torso_joints)) < tol).any(1)
    return bad


def probes_inside_torso(body: Body, rotations: Tensor, probes: Tensor, settings: SamplingSettings) -> Tensor:
    """(B,) bool: some arm probe of the posed body lies inside the posed torso. rotations (B, J, 3, 3)."""
    return (arm_depth_in_torso(body, rotations, probes) > settings.prune_tolerance).any(dim=1)


def sample_poses(
    skel: Skeleton, n: int, seed: int, body: Body | None = None, settings: SamplingSettings | None = None
) -> tuple[Tensor, dict]:
    """Sample n poses (appendix D.3); with a body, prune poses whose arm probes enter the torso, and, when
    the legs move (`legs_pruned`), poses with a leg inside the other leg or inside the torso.

    Returns poses (n, J, 3, 3) float32 and stats: requested, kept, candidates (drawn), pruned,
    probes (arm probes, count), leg_probes (count; only when the legs are pruned), angles_deg (n, J, 3)
    float32 Euler angles of the kept poses.
    (`settings`: addition to docs/interfaces.md; None = the defaults, equal to conf/body/mannequin.yaml.)
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    settings = settings or SamplingSettings()
    probes = arm_probe_indices(body, settings) if body is not None else None
    legs = leg_probe_indices(body, settings) if body is not None and legs_pruned(skel, settings) else None
    kept: list[np.ndarray] = []
    num_kept = drawn = pruned = 0
    block = 0
    while num_kept < n:
        if block >= settings.max_blocks:
            raise RuntimeError(
                f"pose sampling kept only {num_kept} of {n} after {drawn} candidates "
                f"({pruned} pruned); the limits or pruning are too strict"
            )
        angles = sample_angles(skel, settings.block_size, np.random.default_rng([seed, block]), settings)
        clearing = apply_modes(angles, skel, np.random.default_rng([seed, block, 1]), settings)
        block += 1
        if probes is not None:
            for rows, step, most in clearing:  # arms the cone put inside the torso: raised out, as a clip's are
                if rows.any():
                    with torch.no_grad():
                        raised, _ = clear_arms(body, euler_xzy_to_matrix(torch.from_numpy(angles[rows])), settings,
                                               step, most, probes)
                    angles[rows] = xzy_angles(raised.numpy())
            with torch.no_grad():
                rot = euler_xzy_to_matrix(torch.from_numpy(angles))
                bad = probes_inside_torso(body, rot, probes, settings)
                if legs is not None:
                    bad |= legs_collide(body, rot, legs, settings)
            ok = np.flatnonzero(~bad.numpy())
        else:
            ok = np.arange(len(angles))
        take = ok[: n - num_kept]
        # the last block is only looked at up to its last kept candidate
        looked = int(take[-1]) + 1 if num_kept + len(take) == n and len(take) else len(angles)
        drawn += looked
        pruned += looked - len(take)
        kept.append(angles[take])
        num_kept += len(take)
    angles = np.concatenate(kept) if kept else np.zeros((0, skel.num_joints, 3))
    angles_t = torch.from_numpy(angles).to(torch.float32)
    poses = euler_xzy_to_matrix(torch.from_numpy(angles)).to(torch.float32)
    stats = {
        "requested": n,
        "kept": int(num_kept),
        "candidates": int(drawn),
        "pruned": int(pruned),
        "probes": 0 if probes is None else len(probes),
        "angles_deg": angles_t,
    }
    if legs is not None:  # only then: the stats of a dataset whose legs stay at rest are as before
        stats["leg_probes"] = len(legs[0]) + len(legs[1])
    return poses, stats


def plot_angle_histograms(angles, skel: Skeleton, path, bins: int = 40) -> None:
    """Write a PNG of per-joint, per-axis angle histograms with the limits marked (like Fig. 12).

    angles (n, J, 3) degrees. Written atomically (pbc.core.io.save_figure).
    """
    a = np.asarray(torch.as_tensor(angles).detach().cpu())
    J = skel.num_joints
    if a.ndim != 3 or a.shape[1:] != (J, 3):
        raise ValueError(f"angles: expected shape (n, {J}, 3), got {a.shape}")
    lim = skel.limits_deg.numpy()
    fig, axes = plt.subplots(J, 3, figsize=(9, 1.6 * J), squeeze=False)
    for j in range(J):
        for k, axis in enumerate("xyz"):
            ax = axes[j, k]
            ax.hist(a[:, j, k], bins=bins, range=tuple(lim[j, k]), color="tab:blue")
            ax.axvline(lim[j, k, 0], color="tab:red", lw=0.8)
            ax.axvline(lim[j, k, 1], color="tab:red", lw=0.8)
            ax.set_title(f"{skel.names[j]} {axis}", fontsize=8)
            ax.tick_params(labelsize=6)
            ax.set_yticks([])
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


__all__ = [
    "SamplingSettings",
    "apply_modes",
    "arm_probe_indices",
    "euler_xzy_to_matrix",
    "leg_probe_indices",
    "legs_collide",
    "legs_pruned",
    "modes_record",
    "plot_angle_histograms",
    "probes_inside_torso",
    "sample_angles",
    "sample_poses",
    "sampling_settings_from_config",
]


def arm_depth_in_torso(body: Body, rotations: Tensor, probes: Tensor) -> Tensor:
    """(B, 2) how deep (m, >= 0) each arm's probes (left, right: `arm_probe_indices`) reach inside the posed
    torso. rotations (B, J, 3, 3)."""
    transforms = forward_kinematics(body.skeleton, rotations)
    posed = linear_blend_skinning(body.vertices[probes], body.weights[probes], transforms)  # (B, 2P, 3)
    sdf = body_sdf(body, rotations, posed, part=TORSO).view(len(rotations), 2, -1)
    return (-sdf.min(dim=2).values).clamp_min(0.0)


def clear_arms(body: Body, rotations: Tensor, settings: SamplingSettings, step_deg: float = 2.0,
               max_deg: float = 40.0, probes: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Poses with each arm that lies inside the torso raised sideways, about its rest frame's z axis (the axis
    the sampler's limits call raising), by the smallest multiple of `step_deg` that takes its probes out of the
    torso (the sampler's prune test, made corrective); at most `max_deg`.

    Why: a clip recorded on one person and retargeted onto a broader body (Anny is broader than most mocap
    actors) hangs the arms through the torso: every frame of the CMU walk in tests/data/bvh has an arm probe
    38-60 mm inside Anny's torso. The sampler never draws such a pose; the drape of one pulls the cloth
    between the overlapping arm and torso apart (faces 2-4x their pattern at the shoulder), so it is
    discarded. A retargeting tool would keep the arm on the body's surface; this does that with one turn.

    rotations (B, J, 3, 3) -> (cleared (B, J, 3, 3), turned (B, 2) degrees per arm, left then right; an arm
    still inside after `max_deg` keeps that turn, so `turned == max_deg` marks it). probes: the body's
    `arm_probe_indices` when the caller has them (None: found here).
    """
    skel = body.skeleton
    probes = arm_probe_indices(body, settings) if probes is None else probes
    out = rotations.clone()
    turned = torch.zeros(len(rotations), 2, dtype=rotations.dtype)
    joints = [skel.index("l_arm"), skel.index("r_arm")]
    inside = arm_depth_in_torso(body, out, probes) > settings.prune_tolerance
    steps = int(round(max_deg / step_deg))
    for _ in range(steps):
        if not inside.any():
            break
        for side, j in enumerate(joints):
            rows = inside[:, side]
            if rows.any():
                turned[rows, side] += step_deg
                raise_by = _axis_rotation(torch.deg2rad(torch.tensor(step_deg, dtype=out.dtype)), Z)
                out[rows, j] = raise_by @ out[rows, j]
        inside &= arm_depth_in_torso(body, out, probes) > settings.prune_tolerance
    return out, turned
