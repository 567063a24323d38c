"""Per-joint limits measured from motion: the box the pose sampler draws in (conf/body `joints: ... limits`), taken
from real frames instead of set by hand (`pbc motion limits`, which reads the clips and writes the file).

Angles are the body's Euler angles x, y, z of each joint's rotation about its rest frame, R = Rx Rz Ry
(pbc.sim.poses.euler_xzy_to_matrix), degrees: the chart the sampler's limits are in. A rotation has two such
decompositions (pbc.motion.ranges.other_angles: x + 180, y + 180, 180 - z); each joint of each frame is read in the
one nearer a reference box (the body's own limits), so an arm raised past z = 90, which the hand-set box holds up to
z 110, reads as z 110 and not as x + 180.

Measured limits, per joint and axis (`measured_limits`): the low and high percentiles (`LimitSettings`) of the
frames that drive the joint (a joint a clip leaves at rest is not measured on that clip's frames), widened to hold
0 (the rest pose: the sampler's half-normals start there, as the re-rested limits do), then to at least
min_width_deg (evenly about its middle), then rounded outward to whole degrees. A joint no frame drives keeps the
reference limits. Pure: arrays in, arrays and text out; no file is read or written here.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pbc.geometry.body.skeleton import AXES, xzy_angles
from pbc.motion.ranges import other_angles

HEADER_WIDTH = 116  # characters of a header comment line
ROUND_SLACK = 1e-6  # degrees: a limit this close to a whole degree is that degree (float noise is not widened)


@dataclass(frozen=True)
class LimitSettings:
    """How limits are measured (conf/motion/sequence.yaml `limits`, held to conf/bounds.yaml)."""

    percentiles: tuple[float, float] = (0.5, 99.5)  # percent of the frames below the low / the high limit
    min_width_deg: float = 4.0  # no axis narrower than this (degrees)
    mirrored: bool = True  # measure the frames and their mirror images (the caller mirrors them)


def limit_settings(node: Mapping) -> LimitSettings:
    """`LimitSettings` of a mapping (conf/motion/sequence.yaml's `limits` block), checked (`check_limit_settings`)."""
    lo, hi = (float(v) for v in node["percentiles"])
    settings = LimitSettings((lo, hi), float(node["min_width_deg"]), bool(node["mirrored"]))
    check_limit_settings(settings)
    return settings


def check_limit_settings(settings: LimitSettings, where: str = "limits.percentiles") -> None:
    """One ValueError naming `where` and the fix unless 0 <= low < high <= 100 and min_width_deg >= 0."""
    lo, hi = settings.percentiles
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo < hi <= 100.0):
        raise ValueError(f"{where}={[lo, hi]}: give two percentiles 0 <= low < high <= 100 (e.g. 0.5 99.5: the "
                         "limits leave 0.5% of the frames out on each side)")
    if not (np.isfinite(settings.min_width_deg) and settings.min_width_deg >= 0.0):
        raise ValueError(f"limits.min_width_deg={settings.min_width_deg}: give a width in degrees >= 0")


def box_excess(angles: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(N, J) degrees: how far angles (N, J, 3) lie outside box (J, 3, 2) [min, max], summed over the axes
    (0 inside)."""
    below = np.maximum(box[..., 0] - angles, 0.0)
    above = np.maximum(angles - box[..., 1], 0.0)
    return (below + above).sum(-1)


def box_angles(poses, box: np.ndarray) -> np.ndarray:
    """(N, J, 3) degrees: the Euler angles (x, y, z) of poses (N, J, 3, 3), per joint the decomposition nearer
    box (J, 3, 2) (`box_excess`; a tie keeps `xzy_angles`' own, |z| <= 90)."""
    a = xzy_angles(poses)
    b = other_angles(a)
    box = np.asarray(box, np.float64)
    return np.where((box_excess(b, box) < box_excess(a, box))[..., None], b, a)


def measured_limits(poses, reference: np.ndarray, settings: LimitSettings,
                    driven: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Limits measured from poses (N, J, 3, 3) (the module docstring's rule): (limits (J, 3, 2) whole degrees
    [min, max], measured (J,) bool: whether any frame drives the joint; one that none drives keeps `reference`'s).

    reference (J, 3, 2): the box whose nearer decomposition each joint is read in (the body's limits).
    driven (N, J) bool: the frames that drive each joint (None: every frame drives every joint)."""
    check_limit_settings(settings)
    ref = np.asarray(reference, np.float64)
    angles = box_angles(poses, ref)
    n, j = angles.shape[:2]
    use = np.ones((n, j), bool) if driven is None else np.asarray(driven, bool)
    if use.shape != (n, j):
        raise ValueError(f"driven: expected shape ({n}, {j}) (frames, joints), got {use.shape}")
    out = ref.copy()
    measured = use.any(0)
    lo_pct, hi_pct = settings.percentiles
    for k in np.flatnonzero(measured):
        a = angles[use[:, k], k]  # (M, 3)
        lo = np.minimum(np.percentile(a, lo_pct, axis=0), 0.0)
        hi = np.maximum(np.percentile(a, hi_pct, axis=0), 0.0)
        short = np.maximum(settings.min_width_deg - (hi - lo), 0.0) / 2.0
        out[k, :, 0] = np.floor(lo - short + ROUND_SLACK)
        out[k, :, 1] = np.ceil(hi + short - ROUND_SLACK)
    return out + 0.0, measured  # + 0.0: a limit at 0 is 0, not -0


def outside_box(poses, box: np.ndarray, tol: float = ROUND_SLACK) -> tuple[np.ndarray, np.ndarray]:
    """Frames of poses (N, J, 3, 3) outside box (J, 3, 2): (per axis (N, J, 3) bool: the joint's angle in its
    decomposition nearer the box lies past that axis's limits by more than tol degrees; per frame (N,) bool: some
    joint's rotation is held by neither decomposition)."""
    box = np.asarray(box, np.float64)
    a = box_angles(poses, box)
    axes = (a < box[..., 0] - tol) | (a > box[..., 1] + tol)
    return axes, axes.any((1, 2))


@dataclass(frozen=True)
class LimitRow:
    """One joint axis of the report: the body's limits, the measured ones, and the share of frames outside each."""

    joint: str
    axis: str
    hand_set: tuple[float, float]
    measured: tuple[float, float]
    outside_hand_set: float  # fraction of the frames
    outside_measured: float
    driven: bool  # some frame drives the joint (else `measured` is `hand_set`)
    given: tuple[float, float] | None = None  # the limits of a file compared against (None: none)
    outside_given: float | None = None


def limits_rows(names: Sequence[str], poses, hand_set: np.ndarray, measured: np.ndarray, driven: np.ndarray,
                given: np.ndarray | None = None) -> list[LimitRow]:
    """The report per joint and axis (J x 3 rows, joints in `names` order) of poses (N, J, 3, 3): the share of the
    frames outside hand_set, measured and (when given) given, each (J, 3, 2); driven (J,) as `measured_limits`'."""
    boxes = [hand_set, measured] + ([given] if given is not None else [])
    shares = [outside_box(poses, b)[0].mean(0) for b in boxes]  # (J, 3) each
    rows = []
    for j, name in enumerate(names):
        for k, axis in enumerate(AXES):
            rows.append(LimitRow(
                name, axis, (float(hand_set[j, k, 0]), float(hand_set[j, k, 1])),
                (float(measured[j, k, 0]), float(measured[j, k, 1])), float(shares[0][j, k]), float(shares[1][j, k]),
                bool(driven[j]),
                None if given is None else (float(given[j, k, 0]), float(given[j, k, 1])),
                None if given is None else float(shares[2][j, k])))
    return rows


def _pair(p: tuple[float, float]) -> str:
    return f"[{p[0]:g}, {p[1]:g}]"


def limits_table(rows: Sequence[LimitRow]) -> str:
    """The report as aligned text, one line per joint axis (a joint no frame drives is marked)."""
    given = any(r.given is not None for r in rows)
    head = ["joint", "axis", "hand-set", "measured", "% out hand-set", "% out measured"]
    if given:
        head += ["given", "% out given"]
    body = []
    for r in rows:
        line = [r.joint, r.axis, _pair(r.hand_set), _pair(r.measured) + ("" if r.driven else " (not driven)"),
                f"{100 * r.outside_hand_set:.1f}", f"{100 * r.outside_measured:.1f}"]
        if given:
            line += [_pair(r.given), f"{100 * r.outside_given:.1f}"]
        body.append(line)
    width = [max(len(str(c)) for c in col) for col in zip(head, *body, strict=True)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, width, strict=True)).rstrip()
                     for line in [head, *body])


def limits_yaml(names: Sequence[str], limits: np.ndarray, measured: np.ndarray, header: Sequence[str] = ()) -> str:
    """The YAML text of measured limits in the layout of conf/body's `joints` (one row per measured joint:
    `- {name: l_arm, limits: {x: [lo, hi], y: [lo, hi], z: [lo, hi]}}`, whole degrees); a joint no frame drives
    is left out (the body's own limits hold for it). `header`: comment lines written first."""
    lines = [f"# {w}" for h in header for w in (textwrap.wrap(h, HEADER_WIDTH, subsequent_indent="  ") or [""])]
    lines.append("joints:")
    for j, name in enumerate(names):
        if measured[j]:
            axes = ", ".join(f"{a}: [{int(limits[j, k, 0])}, {int(limits[j, k, 1])}]" for k, a in enumerate(AXES))
            lines.append(f"  - {{name: {name}, limits: {{{axes}}}}}")
    return "\n".join(lines) + "\n"
