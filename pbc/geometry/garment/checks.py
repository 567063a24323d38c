"""How a garment sits on the rest body, measured before any drape: the UV unit against the 3D
areas, each part's distance to the body and the body region there, the sleeves' angle against the body's
rest arms, and the shrink-wrap's stretch per chart, per cage patch and per face.

One job: measure, and turn a measurement past its threshold into one ValueError naming the chart or part,
the number, the setting and the fix. The thresholds live in conf/ (``garment.uv_unit_tolerance``,
``garment.shrinkwrap.max_start_distance`` / ``max_sleeve_angle_deg`` / ``max_patch_stretch`` /
``max_face_stretch`` / ``limb_cloth``); the import (`obj_import`) and the shrink-wrap (`shrinkwrap`) call these
checks, `inspect` reports the same numbers.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from pbc.geometry.body.base import Body
from pbc.geometry.body.skeleton import MIDPLANE_TOL, limb_segments
from pbc.geometry.meshops import encircled_degrees, mesh_pieces

# the mannequin's part rows (pbc.geometry.body.Body.parts): 0 torso, 1 left arm, 2 right arm
PART_NAMES = ("torso", "left arm", "right arm")
# a sleeve this many degrees off the body's rest arm is named as a stretch's cause (it is refused past
# garment.shrinkwrap.max_sleeve_angle_deg)
SLEEVE_OFF_DEG = 10.0




def chart_names_from_cage(cage, face_chart: np.ndarray, faces: np.ndarray) -> list[str]:
    """A name per chart when only the cage is at hand: the common prefix of the names of the cage patches
    holding its vertices, less a trailing patch number (auto cage ``sleeve_03`` -> ``sleeve``; the shirt's
    ``front_chest_left`` ... -> ``front``); ``chart k`` when nothing is shared."""
    f = np.asarray(faces)
    nv = int(f.max()) + 1
    owner = cage.vertex_patch(nv)
    # a vertex on a seam belongs to two charts and to one patch: only the chart's own vertices count
    charts_of = np.zeros((nv, int(face_chart.max()) + 1), bool)
    charts_of[f.ravel(), np.repeat(face_chart, 3)] = True
    own = charts_of.sum(1) == 1
    names = []
    for c in range(charts_of.shape[1]):
        mine = charts_of[:, c] & own
        ids = np.unique(owner[mine if mine.any() else charts_of[:, c]])
        patch_names = [cage.patches[i].name for i in ids if i >= 0]
        prefix = os.path.commonprefix(patch_names) if patch_names else ""
        if len(patch_names) == 1:
            prefix = re.sub(r"_\d+$", "", prefix)
        prefix = re.sub(r"_\d*$", "", prefix).rstrip("_")
        names.append(prefix or f"chart {c}")
    return names


def _joint_heads(body) -> tuple[list[str], np.ndarray]:
    """Joint names and rest heads, the fixed root (origin) first."""
    heads = body.skeleton.rest_heads.double().cpu().numpy()
    return ["root", *body.skeleton.names], np.vstack([np.zeros(3), heads])


def body_region(body, point) -> str:
    """Where on the rest body a point is, in words: the nearest body part and joint, and, below the body's
    lowest point, that the body has no legs there."""
    p = np.asarray(point, np.float64)
    bv = body.vertices.double().cpu().numpy()
    k = int(np.linalg.norm(bv - p, axis=1).argmin())
    parts = body.parts.cpu().numpy()[:, k]
    part = " / ".join(PART_NAMES[i] if i < len(PART_NAMES) else f"part {i}" for i in np.flatnonzero(parts))
    names, heads = _joint_heads(body)
    j = int(np.linalg.norm(heads - p, axis=1).argmin())
    where = f"nearest body part: {part or 'none'}, nearest joint: {names[j]}"
    low = float(bv[:, 1].min())
    if p[1] < low:
        lowest = names[int(np.linalg.norm(heads - bv[bv[:, 1].argmin()], axis=1).argmin())]
        return (f"below the body, which ends at y = {low:.2f} m (near its joint {lowest}): this body has no "
                f"legs there; {where}")
    return where


def rest_arm_directions(body) -> dict[str, np.ndarray]:
    """{'left': (3,), 'right': (3,)} unit directions of the body's rest arms, from the skeleton's rest heads:
    the chain from the centre line out to the outermost joint of each side (shoulder -> arm -> forearm ...);
    with three joints or more, from the second (the arm) to the tip, else along the last bone."""
    names, heads = _joint_heads(body)
    parents = [-1] + [p + 1 for p in body.skeleton.parents]  # into names/heads (root first)
    out = {}
    for sgn, side in ((1.0, "left"), (-1.0, "right")):
        tip = int(np.argmax(sgn * heads[:, 0]))
        chain = [tip]
        while parents[chain[-1]] >= 0 and abs(heads[parents[chain[-1]], 0]) > MIDPLANE_TOL:
            chain.append(parents[chain[-1]])
        chain = chain[::-1]  # centre -> tip
        start = chain[1] if len(chain) >= 3 else max(parents[tip], 0)
        d = heads[tip] - heads[start]
        out[side] = d / max(np.linalg.norm(d), 1e-12)
        out[f"{side}_joint"] = heads[chain[0]]
        out[f"{side}_arm_x"] = float(abs(heads[chain[1] if len(chain) >= 2 else tip, 0]))
    return out


def droop_deg(direction: np.ndarray) -> float:
    """Degrees of an outward direction below the horizontal (positive: down, as an A-pose)."""
    d = np.asarray(direction, np.float64)
    return float(np.degrees(np.arcsin(np.clip(-d[1] / max(np.linalg.norm(d), 1e-12), -1.0, 1.0)))) + 0.0  # no -0


def tube_axis(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The axis of a tube-like surface (points (V, 3), faces (F, 3)): the direction its surface normals are
    perpendicular to, the least eigenvector of sum area n n^T (exact for any tube, however short or wide), and
    how tube-like it is (least / middle eigenvalue: 0 for a tube). None for fewer than 8 faces."""
    if len(faces) < 8:
        return None
    t = np.asarray(points, np.float64)[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])  # length = 2 x area
    unit_n = n / np.maximum(np.linalg.norm(n, axis=1), 1e-30)[:, None]
    w, v = np.linalg.eigh((n[:, :, None] * unit_n[:, None, :]).sum(0))
    return v[:, 0], float(w[0] / max(w[1], 1e-30))


@dataclass(frozen=True)
class LimbCloth:
    """What the checks and the placement count as a limb's cloth (conf: garment.shrinkwrap.limb_cloth).

    tube_limit: `tube_axis`'s least / middle eigenvalue past which faces are no tube (a flap, a cape);
    elbow_clearance: m sideways past the elbow joint: cloth there is a long sleeve's, not the torso's;
    flap_reach: m from a forearm's bones: cloth this near it past the elbow lies along the forearm."""

    tube_limit: float
    elbow_clearance: float
    flap_reach: float

    @classmethod
    def from_config(cls, shrinkwrap) -> LimbCloth:
        """From the garment's ``shrinkwrap`` node."""
        c = shrinkwrap.limb_cloth
        return cls(float(c.tube_limit), float(c.elbow_clearance), float(c.flap_reach))


def sleeve_axes(positions: np.ndarray, faces: np.ndarray, body, limb: LimbCloth) -> dict[str, dict]:
    """The axis of each sleeve of a garment at its rest positions (V, 3), against the body's rest arm.

    A sleeve is the garment's surface above the root beyond its side's arm joint, the outer half of that
    reach (so a shirt's side panels next to the torso, and a dress's skirt below, are left out); its axis is
    `tube_axis`'s. It is
    compared like with like: with the axis of the body's arm skin in the same band of reach (`tube_axis` of
    the arm part's faces there), not with the arm's bones, whose line a short sleeve round a real shoulder does
    not follow (MakeHuman T-shirts fitted to Anny read 18-22 degrees off Anny's arm bones, 1-7 off its skin).
    Where the band holds no arm tube (a sleeve past the hand), the bone line from the arm joint to the tip
    (`rest_arm_directions`) stands in. Returns {'left'/'right': {axis, arm, angle_deg (between them),
    droop_deg, arm_droop_deg, faces}} for the sides that have a tube there.
    """
    p = np.asarray(positions, np.float64)
    f = np.asarray(faces)
    centre = p[f].mean(1)
    arms = rest_arm_directions(body)
    bv = body.vertices.double().cpu().numpy()
    bf = body.faces.cpu().numpy()
    body_centre = bv[bf].mean(1)
    out = {}
    for sgn, side, row in ((1.0, "left", 1), (-1.0, "right", 2)):
        x0 = arms[f"{side}_arm_x"]
        reach = sgn * centre[:, 0]
        above = centre[:, 1] > 0.0  # above the root: a dress's or a coat's skirt flaring wider is no sleeve
        if not above.any() or reach[above].max() <= x0:
            continue
        lo, hi = x0 + 0.5 * (reach[above].max() - x0), reach[above].max()
        sel = (reach > lo) & above
        sleeve = tube_axis(p, f[sel])
        if sleeve is None or sleeve[1] > limb.tube_limit:  # not a tube (a flat flap, a cape): no axis to compare
            continue
        axis = sleeve[0] * (1.0 if sgn * sleeve[0][0] >= 0 else -1.0)  # pointing away from the body
        body_reach = sgn * body_centre[:, 0]
        skin = tube_axis(bv, bf[body.parts[row].cpu().numpy()[bf].all(1) & (body_reach > lo) & (body_reach <= hi)
                                & (body_centre[:, 1] > 0.0)])
        arm = (arms[side] if skin is None or skin[1] > limb.tube_limit
               else skin[0] * (1.0 if sgn * skin[0][0] >= 0 else -1.0))
        angle = float(np.degrees(np.arccos(np.clip(abs(axis @ arm), 0.0, 1.0))))
        out[side] = {"axis": axis, "arm": arm, "angle_deg": angle, "droop_deg": droop_deg(axis),
                     "arm_droop_deg": droop_deg(arm), "faces": int(sel.sum()), "centre": centre[sel].mean(0)}
    return out


def check_sleeves(positions: np.ndarray, faces: np.ndarray, body, max_angle_deg: float, limb: LimbCloth
                  ) -> dict[str, dict]:
    """`sleeve_axes`, refused when a sleeve's axis is more than ``max_angle_deg`` off the body's rest arm:
    the shrink-wrap pulls the sleeve onto the rest arm and stretches it (an A-posed sleeve on the T-posed
    mannequin: 7x), and every drape is then discarded minutes later."""
    axes = sleeve_axes(positions, faces, body, limb)
    bad = {s: a for s, a in axes.items() if a["angle_deg"] > max_angle_deg}
    if bad:
        side, a = max(bad.items(), key=lambda kv: kv[1]["angle_deg"])
        turn = a["droop_deg"] - a["arm_droop_deg"]
        if abs(turn) >= 0.5 * a["angle_deg"]:
            why, fix = ("(an A-pose?)", f"rotate the sleeves {abs(turn):.0f} degrees {'up' if turn > 0 else 'down'} "
                                        "about the shoulders in your modelling tool")
        else:  # off forward or back, not up or down
            why, fix = ("(bent at the elbow?)", "turn the sleeves onto the rest arms in your modelling tool")
        raise ValueError(
            f"the garment's {side} sleeve is {a['angle_deg']:.0f} degrees off the body's rest arm (the sleeve "
            f"points {a['droop_deg']:.0f} degrees below the horizontal, the rest arm {a['arm_droop_deg']:.0f}): "
            f"it was modelled on another rest pose {why} and the shrink-wrap would stretch it onto the rest arm. "
            f"Fix: {fix} (or use a body whose rest arms match, body=...; on Anny, `pbc garment inspect` names the "
            "rest to make it on: garment.made_on_rest); the limit is "
            f"garment.shrinkwrap.max_sleeve_angle_deg = {max_angle_deg:g}")
    return axes


def check_far(gap: np.ndarray, positions: np.ndarray, faces: np.ndarray, body, limit: float,
              chart_names: list[str] | None = None, face_chart: np.ndarray | None = None) -> None:
    """Refuse a garment with a vertex more than ``limit`` m from the rest body (gap (V,): the body SDF at
    the garment's vertices), naming the part (its chart, and its connected piece when the mesh has several),
    the distance and the body region there."""
    if gap.max() <= limit:
        return
    p = np.asarray(positions, np.float64)
    f = np.asarray(faces)
    k = int(gap.argmax())
    piece = mesh_pieces(f, len(p))
    n_pieces = int(piece.max()) + 1
    far = gap > limit
    what = []
    if chart_names is not None and face_chart is not None:
        charts = sorted({int(c) for c in face_chart[far[f].any(1)]})
        what.append("chart" + ("s " if len(charts) > 1 else " ") + ", ".join(f"'{chart_names[c]}'" for c in charts))
    if n_pieces > 1:
        mine = piece == piece[k]
        what.append(f"piece {int(piece[k])} of the {n_pieces} separate pieces in this mesh "
                    f"({int(mine.sum())} vertices, centre {np.round(p[mine].mean(0), 2).tolist()})")
    part = "; ".join(what) or "the garment"
    cut = (" Several pieces in one mesh: `pbc garment split` cuts them into one OBJ each." if n_pieces > 1 else "")
    raise ValueError(
        f"{part} is {gap[k]:.2f} m from the body at vertex {k} {np.round(p[k], 3).tolist()} "
        f"({int(far.sum())} vertices beyond garment.shrinkwrap.max_start_distance = {limit:g} m); there: "
        f"{body_region(body, p[k])}. Place the garment on the rest body (metres, y up, root at the waist, x to "
        "the body's left: garment.position_unit / garment.position_offset), or drape only the parts this body "
        f"has.{cut}")


def face_patches(cage, faces: np.ndarray) -> np.ndarray:
    """(F,) the cage patch holding most of each face's corners (-1 when none does)."""
    f = np.asarray(faces)
    owner = cage.vertex_patch(int(f.max()) + 1)[f]  # (F, 3)
    out = owner[:, 0].copy()
    out[(owner[:, 1] == owner[:, 2]) & (owner[:, 1] >= 0)] = owner[(owner[:, 1] == owner[:, 2]) & (owner[:, 1] >= 0), 1]
    return out


def patch_stretch(wrapped_area: np.ndarray, pattern_area: np.ndarray, face_patch: np.ndarray,
                  num_patches: int) -> np.ndarray:
    """(P,) the shrink-wrap's stretch per cage patch: its wrapped area over its pattern area. A patch, not a
    face (a sliver at a seam does not decide) nor a chart (a sleeve pulled onto the wrong arm is a small
    part of a panel that holds it)."""
    ok = face_patch >= 0
    a3 = np.bincount(face_patch[ok], wrapped_area[ok], num_patches)
    a2 = np.bincount(face_patch[ok], pattern_area[ok], num_patches)
    return a3 / np.maximum(a2, 1e-30)


def check_stretch(stretch: np.ndarray, patch_names: list[str], patch_charts: list[str], limit: float,
                  sleeves: dict | None = None, patch_regions: list[str] | None = None,
                  patch_nearest: list[str] | None = None, overall: float | None = None,
                  given: float | None = None) -> None:
    """Refuse a shrink-wrap that stretches a cage patch past ``limit`` x its pattern area, naming the chart,
    the patch, the stretch, the body part it was wrapped on (``patch_regions``), and the likely cause with its
    fix, first that applies: a sleeve off the rest arm (the rest pose), the whole garment stretched by the wrap though
    its cloth as given matches its pattern (``given``, its 3D over its pattern area: the wrap, not the unit), the
    whole garment stretched (the UV unit),
    a patch wrapped on another body part than the one it lies nearest (``patch_nearest``: it does not surround
    that limb), else the placement there. The whole garment is stretched when ``overall``, its wrapped over its
    pattern area, is past 3/4 of the limit; without the regions (an older caller) the UV unit is named."""
    bad = np.flatnonzero(stretch > limit)
    if not len(bad):
        return
    k = int(bad[np.argmax(stretch[bad])])
    listed = ", ".join(f"{patch_names[i]} {stretch[i]:.1f}x" for i in bad[np.argsort(-stretch[bad])][:6])
    on = f", wrapped on the {patch_regions[k]}" if patch_regions is not None else ""
    off = {s: a for s, a in (sleeves or {}).items() if a["angle_deg"] > SLEEVE_OFF_DEG}
    uv_unit = ("the pattern is smaller than the garment: check garment.uv_unit (`pbc garment inspect` names the "
               "one that fits)")
    if off:
        side, a = max(off.items(), key=lambda kv: kv[1]["angle_deg"])
        why = (f"the {side} sleeve is {a['angle_deg']:.0f} degrees off the body's rest arm: match the rest pose "
               "(rotate the sleeves onto the rest arms)")
    elif overall is not None and overall > 0.75 * limit and given is not None and 1.0 / limit < given < limit:
        why = (f"the wrap stretched the whole garment {overall:.1f}x though its cloth as given is {given:.2f}x its "
               "pattern (the UV unit is right): the wrap pulled its cloth onto body parts it does not lie on (`pbc "
               "garment inspect --out DIR`: its face column and on_body.png show where)")
    elif overall is not None and overall > 0.75 * limit:
        why = f"the whole garment is stretched {overall:.1f}x: {uv_unit}"
    elif patch_regions is not None and patch_nearest is not None and patch_regions[k] != patch_nearest[k]:
        why = (f"the patch lies nearest the {patch_nearest[k]} but the garment there does not surround it, so it "
               f"was wrapped on the {patch_regions[k]}: place the garment so its part round the "
               f"{patch_nearest[k]} closes round it (a sleeve, a trouser leg), or cut off what hangs beside it")
    elif patch_regions is not None:
        why = (f"it lies too far from the {patch_regions[k]} or is caught between body parts: place the garment "
               f"closer to the {patch_regions[k]} there (`pbc garment inspect --out DIR` shows it on the body)")
    else:
        why = uv_unit
    raise ValueError(
        f"the shrink-wrap stretches chart '{patch_charts[k]}' (patch {patch_names[k]}{on}) to {stretch[k]:.1f}x its "
        f"pattern area (patches past garment.shrinkwrap.max_patch_stretch = {limit:g}: {listed}); its drapes "
        f"would all be discarded (area_stretched). Likely cause: {why}")


def face_stretch(positions: np.ndarray, faces: np.ndarray, pattern: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stretch of each face from its flat pattern triangle to its triangle at ``positions`` (V, 3) m, from the
    2x2 deformation gradient between the two: the area ratio (F,) (its area over its pattern area: the drape's
    discard measure, pbc.sim.drape.triangle_area_ratios) and the principal stretches (F, 2), largest first, whose
    product it is. faces (F, 3); pattern (F, 3, 2): each face's corners on the flat pattern, m. A pattern triangle
    of no area reads inf."""
    x = np.asarray(positions, np.float64)[np.asarray(faces)]
    d1, d2 = x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]
    l1 = np.linalg.norm(d1, axis=1)
    e1 = d1 / np.maximum(l1, 1e-30)[:, None]
    n = np.cross(d1, d2)
    e2 = np.cross(n / np.maximum(np.linalg.norm(n, axis=1), 1e-30)[:, None], e1)
    ds = np.zeros((len(x), 2, 2))  # the wrapped edges in the triangle's own plane, as columns
    ds[:, 0, 0], ds[:, 0, 1], ds[:, 1, 1] = l1, np.einsum("fk,fk->f", d2, e1), np.einsum("fk,fk->f", d2, e2)
    u = np.asarray(pattern, np.float64)
    m1, m2 = u[:, 1] - u[:, 0], u[:, 2] - u[:, 0]
    det = m1[:, 0] * m2[:, 1] - m1[:, 1] * m2[:, 0]
    flat = np.abs(det) > 1e-300
    inv = np.stack([np.stack([m2[:, 1], -m2[:, 0]], 1), np.stack([-m1[:, 1], m1[:, 0]], 1)], 1)
    inv = inv / np.where(flat, det, 1.0)[:, None, None]
    principal = np.linalg.svd(ds @ inv, compute_uv=False)
    ratio = np.abs(ds[:, 0, 0] * ds[:, 1, 1]) / np.where(flat, np.abs(det), 1.0)
    ratio[~flat], principal[~flat] = np.inf, np.inf
    return ratio, principal


@dataclass(frozen=True)
class FaceLimits:
    """How one face of the wrap is judged and its cause named (conf: garment.shrinkwrap's ``max_face_stretch``,
    ``face_sliver_area``, ``face_far_start``).

    limit: a face whose wrapped area passes this x its pattern area is refused (None: not checked);
    sliver: a pattern triangle smaller than this x the garment's median pattern triangle is a sliver;
    far: m, a face whose corner started this far from the body was pulled onto it from afar."""

    limit: float | None
    sliver: float
    far: float

    @classmethod
    def from_config(cls, shrinkwrap) -> FaceLimits:
        """From the garment's ``shrinkwrap`` node."""
        limit = shrinkwrap.get("max_face_stretch")
        return cls(None if limit is None else float(limit), float(shrinkwrap.get("face_sliver_area", 0.05)),
                   float(shrinkwrap.get("face_far_start", 0.1)))


def face_cause(k: int, faces: np.ndarray, vertex_region: list[str] | None, pattern_area: np.ndarray,
               start_gap: np.ndarray | None, limits: FaceLimits) -> str:
    """Why the wrap stretched face k, from what was measured, first that applies: its corners wrapped on different
    body parts (``vertex_region`` (V,) names: the face spans the gap between them), a corner that started more than
    limits.far from the body (``start_gap`` (V,) m), a sliver in the pattern (its pattern area under limits.sliver x
    the median of ``pattern_area`` (F,)), else the placement there. One clause with its fix."""
    f = np.asarray(faces)[k]
    ids = ", ".join(str(int(v) + 1) for v in f)
    on = [] if vertex_region is None else [vertex_region[int(v)] for v in f]
    if len(set(on)) > 1:
        parts = " and the ".join(dict.fromkeys(on))
        return (f"its corners were wrapped on different body parts (vertices {ids} on the "
                + ", ".join(on) + f"), so it spans the gap between the {parts}: the garment's seam between them "
                f"(a crotch, an armpit) lies off the body's; place the garment so that seam sits where the body's "
                f"{parts} meet, or cut the face off there")
    if start_gap is not None and float(np.max(start_gap[f])) > limits.far:
        v = int(f[int(np.argmax(start_gap[f]))])
        return (f"it started {float(start_gap[v]):.2f} m from the body (vertex {v + 1}; more than "
                f"garment.shrinkwrap.face_far_start = {limits.far:g} m) and the wrap pulled it onto the body: place "
                "the garment closer to the body there")
    median = float(np.median(pattern_area[np.isfinite(pattern_area)]))
    if pattern_area[k] < limits.sliver * median:
        return (f"it is a sliver in the pattern ({pattern_area[k]:.2g} m^2, {pattern_area[k] / median:.2g}x the "
                f"median pattern triangle; garment.shrinkwrap.face_sliver_area = {limits.sliver:g}): re-unwrap the "
                f"UVs there so the triangle of vertices {ids} is not squashed flat")
    return ("the garment lies too far from the body there or is caught between body parts: place the garment "
            "closer to the body there (`pbc garment inspect --out DIR` shows it on the body)")


def faces_past(ratio: np.ndarray, limit: float) -> np.ndarray:
    """(N,) ids of the faces whose area ratio (F,) passes ``limit``, worst first."""
    bad = np.flatnonzero(~(ratio <= limit))
    return bad[np.argsort(-np.nan_to_num(ratio[bad], nan=np.inf), kind="stable")]


def check_face_stretch(ratio: np.ndarray, principal: np.ndarray, faces: np.ndarray, limits: FaceLimits,
                       wrapped: np.ndarray, body, chart_names: list[str], face_chart: np.ndarray,
                       patch_names: list[str], face_patch: np.ndarray, vertex_region: list[str] | None,
                       pattern_area: np.ndarray, start_gap: np.ndarray | None) -> None:
    """Refuse a shrink-wrap with a face whose wrapped area passes limits.limit x its pattern area (ratio (F,),
    principal (F, 2): `face_stretch` at the wrapped positions (V, 3)): the drape discards a sample on one face past
    its own limit (pbc.sim.drape.check_sample), so one face the drape cannot pull back discards them all. One
    ValueError naming how many faces pass, the worst one's stretch, its chart (chart_names[face_chart (F,)]), cage
    patch (patch_names[face_patch (F,)], -1: none), where it is on the body (`body_region`), its vertex ids (1-based,
    as in the OBJ) and the cause measured (`face_cause`)."""
    if limits.limit is None:
        return
    bad = faces_past(ratio, limits.limit)
    if not len(bad):
        return
    k = int(bad[0])
    f = np.asarray(faces)
    ids = ", ".join(str(int(v) + 1) for v in f[k])
    patch = patch_names[int(face_patch[k])] if face_patch[k] >= 0 else "none"
    others = ", ".join(f"{int(i)} {ratio[i]:.1f}x" for i in bad[1:6])
    where = body_region(body, np.asarray(wrapped, np.float64)[f[k]].mean(0))
    raise ValueError(
        f"the shrink-wrap stretches {len(bad)} face{'s' if len(bad) > 1 else ''} past "
        f"garment.shrinkwrap.max_face_stretch = {limits.limit:g}x its pattern area, the worst face {k} (vertices "
        f"{ids}) to {ratio[k]:.1f}x (principal stretches {principal[k, 0]:.1f} and {principal[k, 1]:.2f}), chart "
        f"'{chart_names[int(face_chart[k])]}', patch {patch}, on the body ({where})"
        + (f" (next: face {others})" if others else "") + "; every drape would be discarded (area_stretched). "
        f"Likely cause: {face_cause(k, f, vertex_region, pattern_area, start_gap, limits)}")


ARM_JOINTS = {"left": "l_arm", "right": "r_arm"}
def along_forearm(points: np.ndarray, segs: np.ndarray, limb: LimbCloth) -> np.ndarray:
    """(P,) bool: points (P, 3) past the elbow by limb.elbow_clearance along the line from the elbow to the limb's
    end and within limb.flap_reach of that segment. segs (S, 2, 3): the arm's bone segments (`limb_segments`,
    S >= 2)."""
    a, b = segs[1, 0], segs[-1, 1]  # elbow -> the limb's end
    ab = b - a
    t = (points - a) @ ab / max(float(ab @ ab), 1e-12)
    q = a + np.clip(t, 0.0, 1.0)[:, None] * ab
    return (t * np.linalg.norm(ab) > limb.elbow_clearance) & (np.linalg.norm(points - q, axis=1) < limb.flap_reach)


def cloth_encircled_degrees(points: np.ndarray, faces: np.ndarray, segs: np.ndarray) -> float:
    """How far round a limb's bones segs (S, 2, 3) the cloth of faces (F, 3) at points (V, 3) reaches, in degrees:
    `encircled_degrees` of the faces' centres. A coarse sleeve's ring of vertices, skewed to the bone, falls partly
    in each of the measure's slices and reads as cloth on one side; the centres of the faces between two rings fill
    the slices between them. The one measure of the sleeve check (`sleeves_inside`) and of the shrink-wrap's
    regions (pbc.geometry.shrinkwrap)."""
    return encircled_degrees(np.asarray(points, np.float64)[np.asarray(faces)].mean(1), segs)


def sleeves_inside(points: np.ndarray, faces: np.ndarray, body: Body, min_deg: float, kind: str, limb: LimbCloth
                   ) -> str | None:
    """None unless the garment is a top with long sleeves (cloth reaching sideways past the elbow, or past it along
    the forearm within limb.flap_reach of its bones) on a body with forearms, and a sleeve there does not surround the
    forearm: then which, in words (`cloth_encircled_degrees` of the faces past the elbow about the forearm's
    bones; a sleeve that passes the elbow nowhere near the forearm reaches a few degrees round it, or too few faces
    to say: refused too). A short sleeve is not
    measured: round a real shoulder it lies off the arm's bone (180-230 degrees round it on Anny) and wraps well."""
    if kind != "top":
        return None
    p = np.asarray(points, np.float64)
    centre = p[np.asarray(faces)].mean(1)
    for side, joint in ARM_JOINTS.items():
        segs = limb_segments(body.skeleton, joint)
        if len(segs) < 2:
            continue
        sgn = 1.0 if side == "left" else -1.0
        # past the elbow: sideways (a sleeve modelled on another arm, in the air) or along the forearm's bones
        # near them (an A-posed forearm points forward and down: a sideways bound cuts its sleeve's inner half)
        past = (sgn * centre[:, 0] > abs(segs[1, 0, 0]) + limb.elbow_clearance) | along_forearm(centre, segs, limb)
        if past.sum() < 8:
            continue
        deg = cloth_encircled_degrees(p, np.asarray(faces)[past], segs[1:])
        if not deg >= min_deg:  # NaN: cloth past the elbow in no slice round the forearm
            reach = ("too little of it lies round it to measure" if np.isnan(deg)
                     else f"it reaches {deg:.0f} degrees round it")
            return (f"its {side} sleeve passes the elbow but does not surround the body's {side} forearm ({reach}; "
                    f"garment.shrinkwrap.min_encircled_deg = {min_deg:g}): a sleeve modelled on another arm, or a "
                    "cape's or poncho's flap")
    return None


def check_arm_flaps(points: np.ndarray, on_torso: np.ndarray, body: Body, min_deg: float, limb: LimbCloth) -> None:
    """Refuse cloth wrapped on the torso (on_torso (V,) bool: it closes round no arm) that lies along a forearm:
    within limb.flap_reach of the forearm's bones and past the elbow by limb.elbow_clearance along them (a cape's or a
    poncho's flap, a sleeve cut open). In every drape the arm would catch it. One ValueError naming the side, how
    much cloth, and what to set; a body whose arm is one bone (no forearm) is not checked."""
    p = np.asarray(points, np.float64)
    for side, joint in ARM_JOINTS.items():
        segs = limb_segments(body.skeleton, joint)
        if len(segs) < 2:
            continue
        along = on_torso & along_forearm(p, segs, limb)
        if along.sum() >= 8:
            raise ValueError(
                f"the garment cannot be wrapped: {int(along.sum())} of its vertices lie along the body's {side} "
                f"forearm, past the elbow, but close round no arm (less than garment.shrinkwrap.min_encircled_deg = "
                f"{min_deg:g} degrees round it): a cape's or poncho's flap, or a sleeve cut open, would be wrapped on "
                "the torso and caught by the arm in every drape. Give it sleeves that close round the arms, cut what "
                "passes the elbow, or lower garment.shrinkwrap.min_encircled_deg (e.g. to 120) to wrap it on the arms")
