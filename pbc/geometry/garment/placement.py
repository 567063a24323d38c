"""A garment modelled on another body, in another frame, unit or rest pose, placed on the chosen rest body.

Tools export garments where their own body stood: SMPL's frame (feet at y = -1.1), a mannequin's (feet at
y = 0), centimetres at 3x life size, decimetres, an A-pose. `place_garment` puts the vertices (V, 3), in the
file's numbers, where a person would put them on the rest body of ``body``, in five steps:

1. **unit** from size: the hem's girth (the lowest opening of a top, the waist of a bottom) against the
   body's girth there, snapped to a named unit (m, dm, cm, mm, in) when one lies within
   ``placement.unit_snap`` x, else kept as an odd scale;
2. **registration** from landmarks: the collar (a top's highest opening) onto the midpoint of the body's
   shoulder joints plus ``placement.collar_from_shoulders`` (where pbc's shirt sized to the body has it), the
   waistband of a bottom onto the body's waist; an odd scale is then grown
   (within ``placement.scale_range``) until the torso's cloth is outside the body; a top with long straight
   sleeves is then moved onto the shoulders, each sleeve's axis through the body's shoulder joint
   (`_shoulder_shift`), as a person pulls a shirt on: a body's neck stands higher above its shoulders than
   another's, and the collar alone leaves long sleeves off the arms;
3. **rest-pose transfer**: sleeves modelled at another arm angle (a T-pose top on an A-posed body, or the
   other way round) turn the body's arms to the sleeves, the garment takes the skinning weights of the posed
   body where it lies (sleeves follow the arms), and is skinned back to the body's rest pose; a sleeve that
   reaches past the elbow turns the arm in two (the upper arm onto its inner band, the forearm about the elbow
   onto its outer band: `_elbow_turn`), a shorter one the whole arm as one bone;
4. **pushed out** of the rest body by ``placement.push_out_margin``;
5. **checked**: a garment that still does not sit (its collar below the shoulders, its cloth far from the
   body, a bottom's waist off the waist) is refused in one line: never a silent fit.

A garment that already sits on the body as given (in metres, no shift) is kept as it is, bit for bit.
``garment.position_unit`` (not ``auto``) fixes the unit; ``garment.position_offset`` fixes the frame
(no registration, no transfer). Every number comes from ``garment.placement`` (conf/garment/obj.yaml).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from pbc.geometry.body.base import Body, body_sdf
from pbc.geometry.body.measure import girth, measurements, torso_mesh
from pbc.geometry.body.skeleton import descendants, geodesic_deg, limb_segments
from pbc.geometry.garment.checks import (
    ARM_JOINTS,
    LimbCloth,
    cloth_encircled_degrees,
    sleeve_axes,
    sleeves_inside,
    tube_axis,
)
from pbc.geometry.garment.obj_import import check_mesh, drop_loose
from pbc.geometry.garment.unwrap import charted_as_asked
from pbc.geometry.meshio import ObjMesh, read_obj
from pbc.geometry.meshops import (
    boundary_loops,
    consistent_winding,
    encircled_degrees,
    mesh_pieces,
    push_out,
    split_nonmanifold,
)
from pbc.geometry.units import UNITS, metres_per_unit, name_unit

log = logging.getLogger(__name__)

SLEEVE_BAND = 0.05  # m along a sleeve's axis either side of its band's centre: where its radius is measured


# a joint this far below the root (the waist, m) is on a leg: the mannequin's lowest joint is its root
LEG_BELOW_ROOT = 0.1


@dataclass
class Placement:
    """What `place_garment` did, for the log and `pbc garment inspect`."""

    unit: float  # metres per file unit
    unit_name: str  # the named unit, or "odd scale"
    kind: str  # top / bottom
    translation: np.ndarray  # (3,) m, the collar's (a bottom's waistband's) move after the unit, shoulders' included
    kept: bool  # the garment already sat on the body: nothing moved
    arm_turn_deg: dict = field(default_factory=dict)  # side -> degrees the body's arm was turned onto the sleeve
    distance_before: float = float("nan")  # m, median |distance| to the rest body, as the file's numbers in metres
    distance_after: float = float("nan")  # m, the same after placement
    pushed_out: int = 0  # vertices moved out of the body
    forearm_turn_deg: dict = field(default_factory=dict)  # side -> degrees its forearm turned further, at the elbow
    sleeve_droop_deg: dict = field(default_factory=dict)  # side -> degrees its sleeve pointed down before the transfer

    def lines(self) -> list[str]:
        turn = ", ".join(f"{s} arm turned {d:.0f} deg" + (f" (its forearm {self.forearm_turn_deg[s]:.0f} deg more "
                                                          "at the elbow)" if s in self.forearm_turn_deg else "")
                         for s, d in self.arm_turn_deg.items()) or "none"
        how = "kept as given (it already sits on the body)" if self.kept else (
            f"unit {self.unit_name} ({self.unit:.4g} m per file unit), then shifted by "
            f"{np.round(self.translation, 3).tolist()} m")
        return [f"placement ({self.kind}): {how}; rest-pose transfer: {turn}; "
                f"{self.pushed_out} vertices pushed out of the body",
                f"median distance to the rest body: {self.distance_before:.3f} m as given (in metres), "
                f"{self.distance_after:.3f} m placed"]


def _sdf(body: Body, points: np.ndarray, rotations: torch.Tensor | None = None) -> np.ndarray:
    """(P,) signed distance (m) of points to the body's primitives, at rest or posed by rotations (1, J, 3, 3)."""
    if rotations is None:
        rotations = torch.eye(3).expand(1, body.skeleton.num_joints, 3, 3)
    with torch.no_grad():
        return body_sdf(body, rotations, torch.as_tensor(points, dtype=torch.float32)[None])[0].double().numpy()


def openings(points: np.ndarray, faces: np.ndarray) -> list[dict]:
    """The garment's openings (boundary loops), highest first: {ids, centre (3,), perimeter, half_width (half its
    extent along x)}."""
    out = []
    for loop in boundary_loops(np.asarray(faces)):
        q = points[loop]
        out.append({"ids": loop, "centre": q.mean(0), "half_width": 0.5 * float(np.ptp(q[:, 0])),
                    "perimeter": float(np.linalg.norm(q - np.roll(q, 1, 0), axis=1).sum())})
    return sorted(out, key=lambda o: -o["centre"][1])


def hem(ops: list[dict]) -> dict:
    """A top's hem among its openings (`openings`, highest first): the lowest one round the midline (its centre
    within half its half-width of the collar's x), so cuffs hanging lower beside the torso (sleeves modelled with
    the arms down) are not taken for it; the lowest opening when none is round the midline."""
    mid = [o for o in ops[1:] if abs(o["centre"][0] - ops[0]["centre"][0]) < 0.5 * o["half_width"]]
    return mid[-1] if mid else ops[-1]


def top_or_bottom(points: np.ndarray, faces: np.ndarray, where: str) -> str:
    """``bottom`` (worn from the waist) or ``top`` (worn from the neck), from the garment's openings: two (a skirt,
    however flared, or a tube) is a bottom; three or more whose two lowest lie side by side under the highest
    (trouser legs under the waistband) is a bottom when both lie within the waistband's diameter of the midline
    or the highest opening is the widest (trousers modelled with the legs apart: a top's collar is narrower
    than its hem, and a long sleeve's cuffs lie farther out); any other (a collar, a hem and sleeves or
    armholes) is a top. A closed surface is no garment."""
    ops = openings(points, faces)
    if len(ops) < 2:
        raise ValueError(f"{where}: {'a closed surface' if not ops else 'a surface with one opening'} is not a "
                         "garment a body can wear (a garment has openings: a collar and a hem, a waist and legs); "
                         "give the garment's own mesh, not a body or a closed shape")
    if len(ops) == 2:
        return "bottom"
    a, b = ops[-1]["centre"], ops[-2]["centre"]
    reach = ops[0]["perimeter"] / np.pi  # twice the waistband's radius, were it round: a leg's ankle is within it
    side_by_side = abs(a[1] - b[1]) < 0.25 * abs(a[0] - b[0]) and a[0] * b[0] < 0
    widest_on_top = all(ops[0]["perimeter"] >= o["perimeter"] for o in ops[1:])
    legs = side_by_side and (max(abs(a[0]), abs(b[0])) < reach or widest_on_top)
    return "bottom" if legs else "top"


def _landmarks(body: Body) -> dict:
    sk = body.skeleton
    m = measurements(body)
    arms = sk.rest_heads[[sk.index("l_arm"), sk.index("r_arm")]].double().numpy()
    return {"neck": sk.rest_heads[sk.index("neck")].double().numpy(), "shoulder_y": float(arms[:, 1].mean()),
            "shoulders": np.array([0.0, float(arms[:, 1].mean()), float(arms[:, 2].mean())]),
            "arm_x": float(np.abs(arms[:, 0]).mean()), "waist_y": m["waist_at"], "torso": torso_mesh(body),
            "low": float(body.vertices[:, 1].min()),
            "girths": {k: (m[k], m[f"{k}_at"]) for k in ("chest", "hips") if k in m and f"{k}_at" in m}}


def _girth_at(lm: dict, y: float) -> float:
    """The body's torso girth at height y, or the nearest non-empty one below the torso's end."""
    bounds = lm["torso"].bounds
    return girth(lm["torso"], float(np.clip(y, bounds[0][1] + 0.02, bounds[1][1] - 0.02)))


def _anchor(points: np.ndarray, faces: np.ndarray, kind: str) -> tuple[np.ndarray, dict]:
    """(3,) the landmark the garment is hung by (collar or waistband centre) and the opening sized against the
    body (hem of a top, waistband of a bottom)."""
    ops = openings(points, faces)
    return ops[0]["centre"], (hem(ops) if kind == "top" else ops[0])


def _target(lm: dict, kind: str, pcfg) -> np.ndarray:
    if kind == "top":  # from the shoulders, as sizing places pbc's shirt (pbc.geometry.garment.sizing)
        return lm["shoulders"] + np.asarray(pcfg.collar_from_shoulders, np.float64)
    return np.array([0.0, lm["waist_y"], lm["neck"][2]]) + np.asarray(pcfg.waist_offset, np.float64)


def _unit(points, faces, kind, lm, pcfg, stated, where) -> tuple[float, str]:
    """Metres per file unit: the stated one, else from the sizing opening's girth against the body's there,
    confirmed by the girth at the body's chest (a top) or hips (a bottom) (`unit_measures`): the named unit every
    measure lies within ``placement.unit_snap`` of, else an odd scale from the opening's; measures that disagree
    by more than ``placement.unit_agreement`` are one ValueError naming each measure's unit."""
    height = float(lm["torso"].bounds[1][1] - lm["low"])
    if stated not in (None, "auto"):
        unit = metres_per_unit(stated, "garment.position_unit")
        extent = float(np.ptp(points, axis=0).max()) * unit
        if extent > float(pcfg.max_extent) * max(height, 1e-9):
            raise ValueError(f"{where}: the garment spans {extent:.2f} m with garment.position_unit={stated}, "
                             f"{extent / height:.1f}x the body's height: far larger than any body; give the "
                             "file's unit (garment.position_unit=cm, mm, ...) or garment.position_unit=auto")
        return unit, str(stated)
    measures = unit_measures(points, faces, kind, lm, pcfg)
    _check_agreement(measures, points, float(pcfg.unit_agreement), where)
    for name, m in UNITS.items():  # a named unit every measure lies within unit_snap of
        if all(max(u / m, m / u) <= float(pcfg.unit_snap) for u in measures.values()):
            return m, name
    return measures[_SIZING[kind]] * float(pcfg.odd_scale_ease) / float(pcfg.opening_ease), "odd scale"


# the measure that sizes each kind of garment (its lowest opening for a top, its waistband for a bottom), and the
# body girth that confirms it (measurements(): the chest, the hips)
_SIZING = {"top": "hem girth", "bottom": "waistband girth"}
_CONFIRM = {"top": ("chest girth", "chest", "chest_ease"), "bottom": ("hip girth", "hips", "hip_ease")}


def unit_measures(points: np.ndarray, faces: np.ndarray, kind: str, lm: dict, pcfg) -> dict[str, float]:
    """Metres per file unit by each measure of the garment (V, 3 file units) against the body (landmarks ``lm``):
    its sizing opening's girth (``placement.opening_ease`` x the body's girth where it lands: the hem of a top,
    the waistband of a bottom) and its girth where the body's chest (a top) or hips (a bottom) land when the
    garment is hung by its anchor (``chest_ease`` / ``hip_ease`` x the body's girth there). A measure that finds
    no cloth there is left out."""
    anchor, sizing = _anchor(points, faces, kind)
    unit = 1.0
    for _ in range(4):  # the body's girth is taken where the opening lands, which depends on the unit
        y = _target(lm, kind, pcfg)[1] + (sizing["centre"][1] - anchor[1]) * unit
        unit = float(pcfg.opening_ease) * _girth_at(lm, y) / max(sizing["perimeter"], 1e-12)
    out = {_SIZING[kind]: unit}
    name, body_key, ease = _CONFIRM[kind]
    body_girth, body_y = lm["girths"][body_key]
    mesh = trimesh.Trimesh(points, faces, process=False)
    centre_x = float(np.median(points[:, 0]))
    confirm = unit
    for _ in range(4):  # where the body's chest (hips) lands on the garment depends on the unit too
        y = anchor[1] + (body_y - _target(lm, kind, pcfg)[1]) / confirm
        # the garment's torso there: its cloth within the sizing opening's half width (and 5%) of its midline
        g = girth(mesh, y, 1.05 * sizing["half_width"], centre_x)
        if g <= 0.0:
            return out
        confirm = float(pcfg[ease]) * body_girth / g
    out[name] = confirm
    return out


def _check_agreement(measures: dict[str, float], points: np.ndarray, agreement: float, where: str) -> None:
    """One ValueError when the measures' units (`unit_measures`) lie more than ``agreement`` x apart: each measure,
    the garment's height it implies, and the settings that state the unit."""
    if max(measures.values()) <= agreement * min(measures.values()):
        return
    height = float(np.ptp(points[:, 1]))
    said = "; ".join(f"its {k} says {name_unit(v, agreement)} ({v:.4g} m per file unit: the garment "
                     f"{height * v:.2f} m tall)" for k, v in measures.items())
    raise ValueError(f"{where}: the garment's size does not tell its unit: {said}; these disagree by more than "
                     f"garment.placement.unit_agreement = {agreement:g}x. Give the "
                     "file's unit: " + " or ".join(f"garment.position_unit={name_unit(v, agreement)}"
                                                 for v in measures.values()))


def _inside_fraction(points: np.ndarray, body: Body, lm: dict, rotations=None) -> float:
    """The fraction of the torso's cloth (|x| inside the arm joints, below the shoulders) inside the body."""
    sel = (np.abs(points[:, 0]) < lm["arm_x"]) & (points[:, 1] < lm["shoulder_y"] - 0.05)
    if not sel.any():
        return 0.0
    return float((_sdf(body, points[sel], rotations) < 0.0).mean())


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit direction a onto unit direction b (Rodrigues)."""
    v, c = np.cross(a, b), float(np.clip(a @ b, -1.0, 1.0))
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c) if c > -1.0 + 1e-9 else -np.eye(3)


def arm_chain(body: Body, side: str) -> set[int]:
    """The joints (model-input indices) of one side's arm: its arm joint and every joint below it."""
    return descendants(body.skeleton, ARM_JOINTS[side])


def forearm_joint(body: Body, side: str) -> str | None:
    """The name of the joint below one side's arm joint (its forearm), or None for an arm of one bone."""
    sk = body.skeleton
    children = [j for j, par in enumerate(sk.parents) if par == sk.index(ARM_JOINTS[side])]
    return sk.names[children[0]] if children else None


def _rigid(rot: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(4, 4) the turn rot (3, 3) about pivot (3,)."""
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot, pivot - rot @ pivot
    return t


def _arm_transforms(body: Body, turns: dict) -> torch.Tensor:
    """(J+1, 4, 4) bone transforms of the body with each side's arm chain (its arm joint and every joint below
    it) turned by turns[side] = (R (3, 3) root axes, pivot (3,)) about the pivot, every other bone at rest. The
    pivot is the garment's own shoulder (on its sleeve's axis), not the body's joint: a sleeve modelled on
    another body turns where its maker turned it. A turn with an ``elbow`` (3,) (`_elbow_turn`) turns the
    forearm's chain (the forearm joint and every joint below it) further by its ``fore_rot`` (3, 3) about that
    point, the garment's own elbow on the turned upper arm's sleeve axis."""
    sk = body.skeleton
    out = torch.eye(4, dtype=torch.float64).repeat(sk.num_joints + 1, 1, 1)
    for side, turn in turns.items():
        t = _rigid(turn["rot"], turn["pivot"])
        fore = descendants(sk, forearm_joint(body, side)) if "elbow" in turn else set()
        t_fore = _rigid(turn["fore_rot"], turn["elbow"]) @ t if fore else t
        for j in arm_chain(body, side):
            out[1 + j] = torch.as_tensor(t_fore if j in fore else t)
    return out


def _unpose(points: np.ndarray, body: Body, turns: dict, neighbours: int, ramp: float,
            elbow_ramp: float = 0.0) -> np.ndarray:
    """Garment points on the body with its arms turned (`_arm_transforms` of turns) taken back to its rest pose,
    with the skinning weights of the posed body's nearest vertices (inverse-distance blended), each sleeve's own
    points held to its arm (`_sleeve_membership`), a long sleeve's split between its upper arm and its forearm
    across the elbow (`_forearm_share`, over elbow_ramp m): (P, 3)."""
    transforms = _arm_transforms(body, turns)
    weights = body.weights.double()
    posed = torch.einsum("vk,kij->vij", weights, transforms[:, :3, :]).numpy()  # per body vertex (Vb, 3, 4)
    posed_vertices = np.einsum("vij,vj->vi", posed[:, :, :3], body.vertices.double().numpy()) + posed[:, :, 3]
    dist, idx = cKDTree(posed_vertices).query(points, k=neighbours)
    w = 1.0 / np.maximum(dist, 1e-6)
    w /= w.sum(1, keepdims=True)
    blend = np.einsum("pk,pkj->pj", w, weights.numpy()[idx])  # (P, J+1)
    for side, turn in turns.items():
        cols = [1 + j for j in sorted(arm_chain(body, side))]
        had = blend[:, cols].sum(1)
        member, cylinder = _sleeve_membership(points, turn, ramp)
        want = np.maximum(had * cylinder, member)  # the body's arm weights inside the sleeve only
        rest = 1.0 - had
        blend *= np.where(rest > 1e-9, (1.0 - want) / np.maximum(rest, 1e-9), 0.0)[:, None]  # the other bones
        blend[:, cols] = 0.0
        if "elbow" in turn:  # two bones: the upper arm's turn, the forearm's chain's (`_arm_transforms`)
            share = _forearm_share(points, turn, elbow_ramp)
            blend[:, cols[0]] = want * (1.0 - share)
            blend[:, 1 + body.skeleton.index(forearm_joint(body, side))] = want * share
        else:
            blend[:, cols[0]] = want  # the chain turns as one bone (`_arm_transforms`)
        # cloth the arm alone held, outside the sleeve (an A-posed arm against the torso's side): the shoulder's
        blend[:, 1 + body.skeleton.parents[min(cols) - 1]] += 1.0 - blend.sum(1)
    m = torch.einsum("pk,kij->pij", torch.as_tensor(blend), transforms[:, :3, :]).numpy()  # (P, 3, 4)
    return np.linalg.solve(m[:, :, :3], (points - m[:, :, 3])[..., None])[..., 0]


def _axial(points: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """points (P, 3) about the line through origin (3,) along the unit axis (3,): (P,) how far along it, (P,)
    how far from it (m)."""
    rel = points - origin
    along = rel @ axis
    return along, np.linalg.norm(rel - along[:, None] * axis, axis=1)


def _band_radius(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> float:
    """The median distance (m) of the points within SLEEVE_BAND of centre (3,) along axis (3,) from that axis."""
    along, radial = _axial(points, centre, axis)
    band = (np.abs(along) < SLEEVE_BAND) & (radial < 2 * SLEEVE_BAND)
    return float(np.median(radial[band])) if band.any() else SLEEVE_BAND


def _nearest_on_axis(point: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(3,) the point of the line through centre (3,) along the unit axis (3,) nearest point (3,): a sleeve's
    pivot, the point of its axis level with the body's shoulder joint."""
    return centre + axis * float((point - centre) @ axis)


def _sleeve_reach(points: np.ndarray, pivot: np.ndarray, axis: np.ndarray, radius: float) -> float:
    """How far (m) along the unit axis (3,) from pivot (3,) the sleeve's cloth (points (P, 3) within 1.5 of its
    radius of the axis) reaches: past the body's upper arm, a long sleeve."""
    along, radial = _axial(points, pivot, axis)
    return float(along[radial < 1.5 * radius].max(initial=0.0))


def _long_sleeve(points: np.ndarray, faces: np.ndarray, body: Body, side: str, a: dict, pcfg, limb: LimbCloth
                 ) -> bool:
    """Whether one side's sleeve (a: its `sleeve_axes` entry) is long and straight: it reaches past the body's
    elbow by pcfg.elbow_reach along its axis from the point nearest the body's shoulder joint, and the axis of
    its inner part (pcfg.sleeve_inner_band: fractions of its sideways reach past the body's shoulder joint) is
    within pcfg.sleeve_straight_deg of its outer half's. False on an arm of one bone (no elbow to pass)."""
    sk = body.skeleton
    segs = limb_segments(sk, ARM_JOINTS[side])
    if len(segs) < 2:
        return False
    joint = segs[0][0]
    reach = _sleeve_reach(points, _nearest_on_axis(joint, a["centre"], a["axis"]), a["axis"],
                          _band_radius(points, a["centre"], a["axis"]))
    if reach < float(np.linalg.norm(segs[0][1] - segs[0][0])) + float(pcfg.elbow_reach):
        return False
    sgn = 1.0 if side == "left" else -1.0
    sideways = sgn * points[faces].mean(1)[:, 0]
    x0 = abs(float(joint[0]))
    lo, hi = (x0 + float(t) * (float(sideways.max()) - x0) for t in pcfg.sleeve_inner_band)
    inner = tube_axis(points, faces[(sideways > lo) & (sideways <= hi)])
    if inner is None or inner[1] > limb.tube_limit:
        return False
    return float(np.degrees(np.arccos(min(abs(float(inner[0] @ a["axis"])), 1.0)))) <= float(pcfg.sleeve_straight_deg)


def _shoulder_shift(points: np.ndarray, faces: np.ndarray, body: Body, pcfg, limb: LimbCloth) -> np.ndarray:
    """(3,) the move (m, up/down and back/forth: a top stays centred on the midline) that puts each long straight
    sleeve's axis (`sleeve_axes`, `_long_sleeve`) through the body's shoulder (arm) joint, least squares over
    both sides, the sleeve turning about that joint in the rest-pose transfer; zeros with
    pcfg.shoulder_registration off, unless both sleeves are long and straight, or when the move is past
    pcfg.max_anchor_error (it would take the collar, registered at its place, out of where `sits` finds it: the
    sleeves are not where a shoulder would hold them, and the collar's registration stands). A short sleeve round
    a real shoulder lies off the arm's bone (`sleeve_axes`): its collar places it."""
    if not pcfg.shoulder_registration:
        return np.zeros(3)
    sk = body.skeleton
    axes = {s: a for s, a in sleeve_axes(points, faces, body, limb).items() if s in ARM_JOINTS}
    if set(axes) != set(ARM_JOINTS) or not all(_long_sleeve(points, faces, body, s, a, pcfg, limb)
                                               for s, a in axes.items()):
        return np.zeros(3)
    lhs, rhs = 1e-9 * np.eye(2), np.zeros(2)  # the move (y, z); the tiny ridge holds a direction no axis fixes
    for side, a in axes.items():
        off = np.eye(3) - np.outer(a["axis"], a["axis"])  # across the sleeve's axis
        lhs += off[1:, 1:]
        rhs += (off @ (sk.rest_heads[sk.index(ARM_JOINTS[side])].double().numpy() - a["centre"]))[1:]
    move = np.array([0.0, *np.linalg.solve(lhs, rhs)])
    return move if float(np.linalg.norm(move)) <= float(pcfg.max_anchor_error) else np.zeros(3)


def _transfer_turns(points: np.ndarray, faces: np.ndarray, body: Body, pcfg, limb: LimbCloth) -> dict:
    """Per side whose sleeve is more than pcfg.transfer_min_deg off the rest arm (`sleeve_axes`: like with like,
    the arm's skin in the sleeve's band): {rot (3, 3) turning the rest arm onto the sleeve, pivot (3,) the point
    of the sleeve's axis nearest the body's shoulder joint, axis (3,), radius (m) of the sleeve round it}, with
    the elbow's turn (`_elbow_turn`) in place of the one turn for a sleeve that reaches past the elbow; {} when
    no sleeve is off."""
    sk = body.skeleton
    out = {}
    for side, a in sleeve_axes(points, faces, body, limb).items():
        if side in ARM_JOINTS and a["angle_deg"] > float(pcfg.transfer_min_deg):
            joint = sk.rest_heads[sk.index(ARM_JOINTS[side])].double().numpy()
            pivot = _nearest_on_axis(joint, a["centre"], a["axis"])
            out[side] = {"rot": _rotation_between(a["arm"], a["axis"]), "pivot": pivot, "axis": a["axis"],
                         "radius": _band_radius(points, a["centre"], a["axis"])}
            if pcfg.forearm_turn:
                out[side] = _elbow_turn(points, faces, body, side, out[side], pcfg, limb) or out[side]
    return out


def _skin_band_axis(body: Body, side: str, bone: np.ndarray, band, limb: LimbCloth) -> np.ndarray | None:
    """(3,) the axis of the body's arm skin (its part's faces) whose centres lie over the fraction ``band``
    (lo, hi) of the bone (2, 3) (rest heads, m), pointing down the bone; None where that is no tube. Like with
    like: a sleeve's band is compared with the skin it covers, not the bone's line."""
    row = 1 if side == "left" else 2
    bv = body.vertices.double().cpu().numpy()
    bf = body.faces.cpu().numpy()
    centre = bv[bf].mean(1)
    d = bone[1] - bone[0]
    t = (centre - bone[0]) @ d / max(float(d @ d), 1e-12)
    sel = body.parts[row].cpu().numpy()[bf].all(1) & (t >= float(band[0])) & (t <= float(band[1]))
    skin = tube_axis(bv, bf[sel])
    if skin is None or skin[1] > limb.tube_limit:
        return None
    return skin[0] * (1.0 if skin[0] @ d >= 0 else -1.0)


def _sleeve_band_axis(points: np.ndarray, faces: np.ndarray, turn: dict, reach, limb: LimbCloth
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """(3,) the axis and (3,) the centre of the sleeve's band of faces whose centres are ``reach`` (lo, hi) m
    from its pivot, within 1.5 sleeve radii of its axis (turn's, `_transfer_turns`): the axis points away from
    the pivot. None where that is no tube. The distance from the pivot, not the reach along the axis, holds a
    sleeve bent at the elbow (an A-posed arm's) in the same band as a straight one."""
    centre = points[faces].mean(1)
    along, radial = _axial(centre, turn["pivot"], turn["axis"])
    dist = np.linalg.norm(centre - turn["pivot"], axis=1)
    sel = (radial < 1.5 * turn["radius"]) & (along > 0.0) & (dist >= float(reach[0])) & (dist <= float(reach[1]))
    tube = tube_axis(points, faces[sel])
    if tube is None or tube[1] > limb.tube_limit:
        return None
    axis = tube[0] * (1.0 if tube[0] @ (centre[sel].mean(0) - turn["pivot"]) >= 0 else -1.0)
    return axis, centre[sel].mean(0)


def _elbow_turn(points: np.ndarray, faces: np.ndarray, body: Body, side: str, turn: dict, pcfg, limb: LimbCloth
                ) -> dict | None:
    """The arm turned in two for a sleeve that reaches past the body's elbow by pcfg.elbow_reach m (along its
    axis from its pivot, `_transfer_turns`' one turn): the upper arm's skin over pcfg.upper_band (fractions of
    the upper arm) onto the sleeve's band as far from its shoulder, then the forearm's skin over
    pcfg.forearm_band onto the sleeve's band there, turned about the garment's elbow (on its upper sleeve's axis,
    as far from its shoulder as the body's elbow from its shoulder joint). One turn of the whole arm lays a long
    T-pose sleeve along an A-posed body's forearm, bent forward at the elbow, and leaves its upper part off the
    upper arm. {rot, pivot, axis, radius (the upper sleeve's), elbow (3,), fore_rot (3, 3) (root axes, after
    rot), fore_axis (3,), fore_radius}; None for a shorter sleeve, an arm of one bone, or a band that is no tube
    (then the one turn stands). The bands are picked round the one turn's axis: a sleeve modelled bent at the
    elbow (an A-posed long sleeve) has its upper part off that axis, finds no upper band and keeps one turn."""
    fore = forearm_joint(body, side)
    if fore is None:
        return None
    sk = body.skeleton
    heads = sk.rest_heads.double().cpu().numpy()
    segs = limb_segments(sk, ARM_JOINTS[side])  # shoulder -> elbow -> wrist (-> ...)
    upper_len, fore_len = (float(np.linalg.norm(s[1] - s[0])) for s in segs[:2])
    reach = _sleeve_reach(points, turn["pivot"], turn["axis"], turn["radius"])
    if reach < upper_len + float(pcfg.elbow_reach):
        return None
    ub, fb = pcfg.upper_band, pcfg.forearm_band
    upper = _sleeve_band_axis(points, faces, turn, [upper_len * float(ub[0]), upper_len * float(ub[1])], limb)
    lower = _sleeve_band_axis(points, faces, turn, [upper_len + fore_len * float(fb[0]),
                                                    min(upper_len + fore_len * float(fb[1]), reach)], limb)
    arm_axis = _skin_band_axis(body, side, segs[0], ub, limb)
    fore_axis = _skin_band_axis(body, side, segs[1], fb, limb)
    if upper is None or lower is None:
        return None
    arm_axis = (segs[0][1] - segs[0][0]) / upper_len if arm_axis is None else arm_axis
    fore_axis = (segs[1][1] - segs[1][0]) / fore_len if fore_axis is None else fore_axis
    (g1, c1), (g2, c2) = upper, lower
    joint = heads[sk.index(ARM_JOINTS[side])]
    pivot = _nearest_on_axis(joint, c1, g1)
    rot = _rotation_between(arm_axis, g1)
    # the garment's elbow: as far down its upper sleeve from its shoulder as the body's elbow down its upper arm
    elbow = pivot + g1 * float((heads[sk.index(fore)] - joint) @ arm_axis)
    return {"rot": rot, "pivot": pivot, "axis": g1, "radius": _band_radius(points, c1, g1), "elbow": elbow,
            "fore_rot": _rotation_between(rot @ fore_axis, g2), "fore_axis": g2,
            "fore_radius": _band_radius(points, c2, g2)}


def _forearm_share(points: np.ndarray, turn: dict, ramp: float) -> np.ndarray:
    """(P,) 0..1 how much of each point's arm weight is the forearm's: past the plane through the turn's elbow
    halfway between its upper and lower sleeve axes (a bent sleeve's elbow), over a ramp of ``ramp`` m across it,
    as a rig's weights blend across a joint."""
    n = turn["axis"] + turn["fore_axis"]
    n = n / max(float(np.linalg.norm(n)), 1e-12)
    return np.clip((points - turn["elbow"]) @ n / max(ramp, 1e-9) + 0.5, 0.0, 1.0)


def _sleeve_membership(points: np.ndarray, turn: dict, ramp: float) -> tuple[np.ndarray, np.ndarray]:
    """How much each point belongs to the sleeve (P,) 0..1: beyond the pivot along the sleeve's axis (a ramp of
    `ramp` m across it) within 1.5 sleeve radii of the axis; and (P,) bool, whether it lies in that cylinder at
    all. A loose sleeve's underside lies nearer the torso's side than the arm, and an A-posed arm lies against
    the torso's side: the nearest body vertex alone would leave the one behind and carry the other off. With an
    elbow (`_elbow_turn`), past the elbow's plane (`_forearm_share`) the cylinder is the forearm's: 1.5 forearm
    band radii round the lower sleeve's axis through the elbow."""
    along, radial = _axial(points, turn["pivot"], turn["axis"])
    cylinder = (radial < 1.5 * turn["radius"]) & (along > -0.5 * ramp)
    if "elbow" in turn:  # past the elbow the sleeve lies round the lower axis (a bent sleeve's is off the upper)
        fore = _axial(points, turn["elbow"], turn["fore_axis"])[1]
        cylinder = np.where(_forearm_share(points, turn, 0.0) > 0.5, (fore < 1.5 * turn["fore_radius"]) & (along > 0.0),
                            cylinder)
    return np.clip(along / ramp + 0.5, 0.0, 1.0) * cylinder, cylinder


def _already_placed(points: np.ndarray, faces: np.ndarray, body: Body, gcfg, kind: str, lm: dict) -> bool:
    """Whether a garment in metres was placed on this body by its maker: every vertex within the shrink-wrap's
    reach (garment.shrinkwrap.max_start_distance) and, for a top, its collar above the shoulders (a top from
    another body's frame can sit within reach of the hips, as the issue's SMPL top did); a top on a body whose
    rest turns (Anny): its torso's cloth within reach and its collar within placement.kept_collar_error of
    where registration would put it."""
    reach = (gcfg.get("shrinkwrap") or {}).get("max_start_distance")
    anchor = _anchor(points, faces, kind)[0]
    if kind == "top" and has_rest_turn(body):
        # sleeves modelled at another arm angle lie off this rest's arms, not off its frame: a body whose rest turns
        # is turned to them (garment.made_on_rest, which inspect names); the torso's cloth and the collar, where
        # registration would put it, say the garment was made on this body (another body's shirt in the same
        # frame, the mannequin's on Anny, sits within reach, its collar 6 cm off: it is registered)
        torso = points[np.abs(points[:, 0]) <= lm["arm_x"]]
        near = np.linalg.norm(anchor - _target(lm, kind, gcfg.placement)) <= float(gcfg.placement.kept_collar_error)
        return near and float(_sdf(body, torso).max()) <= float(0.3 if reach is None else reach)
    if float(_sdf(body, points).max()) > float(0.3 if reach is None else reach):
        return False
    return kind != "top" or anchor[1] >= lm["shoulder_y"]


def torso_segments(body: Body) -> np.ndarray:
    """(S, 2, 3) the rest bones (m) from the skeleton's root up to its neck joint: the torso's axis."""
    sk = body.skeleton
    chain = [sk.index("neck")]
    while int(sk.parents[chain[-1]]) >= 0:
        chain.append(int(sk.parents[chain[-1]]))
    heads = sk.rest_heads.double().cpu().numpy()
    return np.asarray([(heads[a], heads[b]) for a, b in zip(chain[:0:-1], chain[-2::-1], strict=True)])


def torso_cover_deg(points: np.ndarray, faces: np.ndarray, body: Body, lm: dict) -> float:
    """How far round the body's torso axis (`torso_segments`) the garment's cloth there reaches, in degrees
    (`encircled_degrees` of its faces' centres and edge midpoints between the hips and the neck; a torso's sides
    lie outside the arm joints, and sleeves there only fill its sides): a garment
    worn on the body surrounds it (a shirt, a skirt: about 360; an open-back gown: less), a sheet laid in front
    of it or beside it about 180. NaN when no cloth lies there."""
    p = np.asarray(points, np.float64)
    f = np.asarray(faces)
    c = p[f].mean(1)
    names = list(body.skeleton.names)
    heads = body.skeleton.rest_heads.double().cpu().numpy()
    hips = [heads[names.index(j), 1] for j in ("l_hip", "r_hip") if j in names]
    low = min(hips) if hips else lm["waist_y"]
    sel = (c[:, 1] > low - LEG_BELOW_ROOT) & (c[:, 1] < lm["neck"][1])
    if sel.sum() < 3:
        return float("nan")
    t = p[f[sel]]  # the faces' centres and edge midpoints: a coarse garment's cloth sampled densely enough
    samples = np.concatenate([t.mean(1), 0.5 * (t + np.roll(t, -1, axis=1)).reshape(-1, 3)])
    return encircled_degrees(samples, torso_segments(body))


def surround_problem(points: np.ndarray, faces: np.ndarray, body: Body, pcfg, lm: dict) -> str | None:
    """None when the garment surrounds the body's torso (`torso_cover_deg` at least
    ``placement.min_torso_cover_deg``), else what is wrong, in words."""
    deg = torso_cover_deg(points, faces, body, lm)
    limit = float(pcfg.min_torso_cover_deg)
    if not deg < limit:
        return None
    return (f"its cloth reaches {deg:.0f} degrees round the body's torso (garment.placement.min_torso_cover_deg = "
            f"{limit:g}): it lies beside the body, not round it, as a garment laid flat, given in another up axis "
            "(pbc reads y up) or made for no body does. Give the garment as worn on a body, y up (export it "
            "from the tool it was made in with Y up, on its avatar)")


def sits(points: np.ndarray, faces: np.ndarray, body: Body, pcfg, kind: str, lm: dict | None = None,
         wrap: tuple[float, LimbCloth] | None = None) -> str | None:
    """None when the garment (V, 3) m sits on the rest body, else what is wrong, in words; with
    ``wrap`` (garment.shrinkwrap's min_encircled_deg and limb cloth) long sleeves must surround the forearms
    (`sleeves_inside`) and trouser legs the legs (`legs_inside`)."""
    lm = lm or _landmarks(body)
    d = _sdf(body, points)
    anchor, _ = _anchor(points, faces, kind)
    if kind == "top" and anchor[1] < lm["shoulder_y"]:
        return (f"its collar (the highest opening, centre {np.round(anchor, 3).tolist()}) is below the body's "
                f"shoulders (y = {lm['shoulder_y']:.2f} m)")
    if kind == "bottom" and abs(anchor[1] - lm["waist_y"]) > float(pcfg.max_anchor_error):
        return (f"its waistband (centre {np.round(anchor, 3).tolist()}) is not at the body's waist "
                f"(y = {lm['waist_y']:.2f} m)")
    if np.linalg.norm(anchor - _target(lm, kind, pcfg)) > float(pcfg.max_anchor_error):
        return (f"its {'collar' if kind == 'top' else 'waistband'} (centre {np.round(anchor, 3).tolist()}) is "
                f"more than garment.placement.max_anchor_error = {pcfg.max_anchor_error} m from where it is worn "
                f"({np.round(_target(lm, kind, pcfg), 3).tolist()})")
    median = float(np.median(np.abs(d)))
    if median > float(pcfg.max_median_distance):
        return (f"half its cloth is more than {median:.2f} m from the body (garment.placement.max_median_distance "
                f"= {pcfg.max_median_distance} m)")
    around = surround_problem(points, faces, body, pcfg, lm)
    if around is not None:
        return around
    if wrap is None:
        return None
    min_encircled_deg, limb = wrap
    return (sleeves_inside(points, faces, body, min_encircled_deg, kind, limb)
            or legs_inside(points, faces, body, min_encircled_deg, kind))


def legs_inside(points: np.ndarray, faces: np.ndarray, body: Body, min_deg: float, kind: str) -> str | None:
    """None unless the garment is trousers (a bottom with three openings or more) on a body with legs and a trouser
    leg does not surround its leg: then which, in words. Measured with `cloth_encircled_degrees` (the sleeve
    check's measure) on the faces of each trouser leg below mid-thigh about the leg's bones: a ring round the leg
    reaches 360 degrees, cloth beside it (trousers registered a leg's width off) much less. (A top's short
    sleeves are not measured so: round a real shoulder a short sleeve lies off the arm's bone, as `sleeve_axes`
    says.)"""
    p = np.asarray(points, np.float64)
    f = np.asarray(faces)
    for side, leg in trouser_legs(p, f, body, kind).items():
        deg = cloth_encircled_degrees(p, f[leg], limb_segments(body.skeleton, f"{side[0]}_hip"))
        if deg < min_deg:
            return (f"its {side} trouser leg does not surround the body's {side} leg (it reaches {deg:.0f} degrees "
                    f"round it; garment.shrinkwrap.min_encircled_deg = {min_deg:g})")
    return None


def trouser_legs(points: np.ndarray, faces: np.ndarray, body: Body, kind: str) -> dict[str, np.ndarray]:
    """Per side, the (F,) mask of a trouser leg's faces below the body's mid-thigh; {} unless the garment is
    trousers (a bottom with three openings or more) on a body with legs. A side with under 8 faces is left out."""
    p = np.asarray(points, np.float64)
    f = np.asarray(faces)
    names = list(body.skeleton.names)
    if kind != "bottom" or len(openings(p, f)) < 3 or not {"l_hip", "r_hip"} <= set(names):
        return {}
    centre = p[f].mean(1)
    heads = body.skeleton.rest_heads.double().numpy()
    out = {}
    for side, sgn in (("left", 1.0), ("right", -1.0)):
        hip = heads[names.index(f"{side[0]}_hip")]
        knee = f"{side[0]}_knee"
        low = hip[1] if knee not in names else 0.5 * (hip[1] + heads[names.index(knee)][1])  # mid-thigh
        leg = (centre[:, 1] < low) & (sgn * centre[:, 0] > 0.0)
        if leg.sum() >= 8:
            out[side] = leg
    return out


def _outward_deg(direction: np.ndarray, sgn: float) -> float:
    """Degrees a downward direction (3,) leans outward from straight down, in the body's frontal plane."""
    d = direction if direction[1] <= 0 else -direction
    return float(np.degrees(np.arctan2(sgn * d[0], -d[1])))


def trouser_leg_stance(points: np.ndarray, faces: np.ndarray, body: Body, kind: str) -> dict[str, dict]:
    """Per trouser leg (`trouser_legs`): {"leg_deg": how far its tube's axis leans outward from straight down,
    "thigh_deg": the same for the body's thigh (hip to knee), "apart_deg": their difference} in degrees, in the
    body's frontal plane; a body without knees is left out."""
    names = list(body.skeleton.names)
    heads = body.skeleton.rest_heads.double().numpy()
    out = {}
    for side, leg in trouser_legs(points, faces, body, kind).items():
        knee = f"{side[0]}_knee"
        axis = tube_axis(np.asarray(points, np.float64), np.asarray(faces)[leg])
        if knee not in names or axis is None:
            continue
        sgn = 1.0 if side == "left" else -1.0
        leg_deg = _outward_deg(axis[0], sgn)
        thigh_deg = _outward_deg(heads[names.index(knee)] - heads[names.index(f"{side[0]}_hip")], sgn)
        out[side] = {"leg_deg": leg_deg, "thigh_deg": thigh_deg, "apart_deg": leg_deg - thigh_deg}
    return out


def has_rest_turn(body: Body) -> bool:
    """Whether the body's rest pose can be turned (``body.rest``: Anny's arms, forearms and legs): a garment can
    be made on it turned (``garment.made_on_rest``)."""
    return body.config is not None and "rest" in body.config


def has_legs(body: Body) -> bool:
    """Whether the body has joints below its root (the waist): legs a bottom can be worn on."""
    return bool((body.skeleton.rest_heads[:, 1] < -LEG_BELOW_ROOT).any())


def place_garment(points: np.ndarray, faces: np.ndarray, body: Body, gcfg, where: str = "<garment>"
                  ) -> tuple[np.ndarray, Placement]:
    """The garment's vertices (V, 3), in the file's numbers, placed on the rest body: (V, 3) m and what was
    done (see the module docstring). ``gcfg``: the garment config node (position_unit, position_offset,
    placement). One ValueError naming the file when the garment does not sit on the body after placement."""
    pcfg = gcfg.placement
    p = np.asarray(points, np.float64)
    f = np.asarray(faces)
    kind = top_or_bottom(p, f, where)
    lm = _landmarks(body)
    stated = gcfg.get("position_unit", "auto")
    offset = gcfg.get("position_offset")
    before = float(np.median(np.abs(_sdf(body, p))))
    if offset is not None:  # the user's frame: the unit and the shift as given, nothing registered
        unit, name = _unit(p, f, kind, lm, pcfg, "m" if stated in (None, "auto") else stated, where)
        placed = p * unit + np.asarray(offset, np.float64)
        return placed, Placement(unit, name, kind, np.asarray(offset, np.float64), False, {}, before,
                                 float(np.median(np.abs(_sdf(body, placed)))))
    limb = LimbCloth.from_config(gcfg.shrinkwrap)
    if stated in (None, "auto", "m", 1.0) and _already_placed(p, f, body, gcfg, kind, lm):
        if kind == "top" and not has_rest_turn(body) and _transfer_turns(p, f, body, pcfg, limb):
            # in the body's frame, its sleeves at another arm angle, on a body whose rest cannot turn to them
            # (the mannequin): the rest-pose transfer, as a registered garment gets
            return _checked(*_transfer(p, f, body, pcfg, limb), f, body, gcfg, kind, lm, where,
                            (1.0, "m", np.zeros(3), before))
        wrong = surround_problem(p, f, body, pcfg, lm)
        if wrong is not None:
            raise ValueError(f"{where}: as given (metres, on the body), the garment does not sit on it: {wrong}")
        return p, Placement(1.0, "m", kind, np.zeros(3), True, {}, before, before)
    if stated not in (None, "auto"):  # a stated unit overrides the size; a garment that then sits within the
        # shrink-wrap's reach in its own frame is where its maker put it (a flared skirt's hem is its widest
        # opening, so by its openings alone it would be taken for a top and registered at the neck)
        unit, name = _unit(p, f, kind, lm, pcfg, stated, where)
        reach = (gcfg.get("shrinkwrap") or {}).get("max_start_distance")
        if float(_sdf(body, p * unit).max()) <= float(0.3 if reach is None else reach):
            placed = p * unit
            wrong = surround_problem(placed, f, body, pcfg, lm)
            if wrong is not None:
                raise ValueError(f"{where}: as given (garment.position_unit={stated}), the garment does not sit on "
                                 f"the body: {wrong}")
            return placed, Placement(unit, name, kind, np.zeros(3), True, {}, before,
                                     float(np.median(np.abs(_sdf(body, placed)))))
    # a garment already sitting on the body (a tube top: its top opening the widest) was kept above; one that
    # must be registered at a waist needs legs below it
    if kind == "bottom" and not has_legs(body):
        raise ValueError(f"{where}: its widest opening is at the top, a waistband: trousers or a skirt, worn on the "
                         f"legs, and this body has no legs there (its joints: {', '.join(body.skeleton.names)}): "
                         "use a body with legs (body=anny)")
    unit, name = _unit(p, f, kind, lm, pcfg, stated, where)
    x = p * unit
    anchor, _ = _anchor(x, f, kind)
    target = _target(lm, kind, pcfg)
    x = x + (target - anchor)
    if name == "odd scale":  # refine about the anchor: grown until the torso's cloth is out of the body (a
        # tight garment's hem is smaller than opening_ease assumes; a loose one is kept at the estimate)
        lo, hi = (float(s) for s in pcfg.scale_range)
        for s in np.geomspace(lo, hi, int(pcfg.scale_steps)):
            y = target + s * (x - target)
            if _inside_fraction(y, body, lm) <= float(pcfg.max_inside_fraction):
                x, unit = y, unit * s
                break
    shift = _shoulder_shift(x, f, body, pcfg, limb) if kind == "top" else np.zeros(3)
    x = x + shift
    moved = _transfer(x, f, body, pcfg, limb) if kind == "top" else (*push_out(
        x, body.vertices.double().numpy(), body.faces.numpy(), float(pcfg.push_out_margin)), {}, {}, {})
    return _checked(*moved, f, body, gcfg, kind, lm, where,
                    (unit, name, target + shift - _anchor(p * unit, f, kind)[0], before))


def _transfer(x: np.ndarray, f: np.ndarray, body: Body, pcfg, limb: LimbCloth
              ) -> tuple[np.ndarray, dict, dict, dict, dict]:
    """A top's rest-pose transfer (the module docstring's step 3) in up to pcfg.transfer_iterations passes, then
    the push-out (step 4): the points (V, 3), the push-out's stats, and per side the degrees its arm and its
    forearm (at the elbow) were turned and how far its sleeve pointed below the horizontal before."""
    droop = {side: a["droop_deg"] for side, a in sleeve_axes(x, f, body, limb).items()}
    turned: dict[str, float] = {}
    forearm: dict[str, float] = {}
    for _ in range(int(pcfg.transfer_iterations)):
        # each pass takes what the last left: a long sleeve's band follows the forearm, not the upper arm turned
        turns = _transfer_turns(x, f, body, pcfg, limb)
        if not turns:
            break
        x = _unpose(x, body, turns, int(pcfg.skin_neighbours), float(pcfg.sleeve_ramp),
                    float(pcfg.elbow_ramp))
        for side, turn in turns.items():
            turned[side] = turned.get(side, 0.0) + float(geodesic_deg(turn["rot"], np.eye(3)))
            if "elbow" in turn:
                forearm[side] = forearm.get(side, 0.0) + float(geodesic_deg(turn["fore_rot"], np.eye(3)))
    x, stats = push_out(x, body.vertices.double().numpy(), body.faces.numpy(), float(pcfg.push_out_margin))
    return x, stats, turned, forearm, {side: droop[side] for side in turned if side in droop}


def _checked(x: np.ndarray, stats: dict, turned: dict, forearm: dict, droop: dict, f: np.ndarray, body: Body, gcfg,
             kind: str, lm: dict, where: str, moved: tuple) -> tuple[np.ndarray, Placement]:
    """The placed points x (V, 3) and their Placement (moved: unit, its name, translation (3,), the median
    distance as given), or one ValueError when the garment does not sit on the body (step 5)."""
    unit, name, translation, before = moved
    pcfg = gcfg.placement
    placement = Placement(unit, name, kind, translation, False, turned, before,
                          float(np.median(np.abs(_sdf(body, x)))), stats["inside"], forearm, droop)
    wrong = sits(x, f, body, pcfg, kind, lm, (float(gcfg.shrinkwrap.min_encircled_deg),
                                              LimbCloth.from_config(gcfg.shrinkwrap)))
    if wrong is not None:
        raise ValueError(f"{where}: placed on the body ({placement.unit_name}, shifted by "
                         f"{np.round(placement.translation, 2).tolist()} m), the garment does not sit on it: {wrong}. "
                         "Give its unit and frame by hand (garment.position_unit=..., garment.position_offset="
                         "[x,y,z] in metres on the rest body: y up, root at the waist, x to the body's left)")
    return x, placement


def _split_nonmanifold(mesh: ObjMesh, min_fraction: float, where: str) -> ObjMesh:
    """The mesh cut apart at its non-manifold edges and vertices (`meshops.split_nonmanifold`), without the pieces
    the cut made that hold under ``min_fraction`` of its vertices (flaps hanging on by those edges: a label, a
    button's panel); what was cut and dropped goes to the log."""
    faces, source = split_nonmanifold(mesh.faces)
    if len(source) == len(mesh.vertices):
        return mesh
    before = int(mesh_pieces(mesh.faces, len(mesh.vertices)).max()) + 1
    piece = mesh_pieces(faces, len(source))
    size = np.bincount(piece)
    small = np.flatnonzero(size < min_fraction * len(source)) if len(size) > before else np.zeros(0, np.int64)
    keep = ~np.isin(piece[faces[:, 0]], small)
    log.info("%s: cut apart at %d non-manifold vertices (garment.split_nonmanifold); %d pieces of under %g of its "
             "vertices dropped (%d faces)", where, len(source) - len(mesh.vertices), len(small), min_fraction,
             int((~keep).sum()))
    cut = replace(mesh, vertices=mesh.vertices[source], vertex_line=mesh.vertex_line[source], faces=faces[keep],
                  face_uv=mesh.face_uv[keep], face_group=mesh.face_group[keep], face_line=mesh.face_line[keep])
    return drop_loose(cut)[0]  # the dropped pieces' vertices


def placed_mesh(path, gcfg, body: Body | None) -> tuple[ObjMesh, Placement | None]:
    """A tool's garment OBJ as the importer takes it, in metres on the rest body: read (UVs optional), its
    loose vertices dropped (counted in the log), charted as modelled when it has no UVs or ``garment.uvs=unwrap``
    (`pbc.geometry.garment.unwrap.charted_as_asked`: the projection or xatlas's charts, whichever is better), and placed
    (`place_garment`, when ``garment.placement.enabled``, a body is given and the mesh is one piece; else the
    stated unit and offset)."""
    where = str(path)
    mesh, loose = drop_loose(read_obj(path, "garment OBJ", require_uv=False))
    if loose:
        log.info("%s: %d loose vertices (used by no face) dropped", where, loose)
    if gcfg.get("split_nonmanifold", False):
        mesh = _split_nonmanifold(mesh, float(gcfg.min_piece_fraction), where)
    check_mesh(mesh, where, split_setting=True)  # non-manifold edges are refused before anything is measured
    faces, flipped = consistent_winding(mesh.faces)
    if flipped.any():
        face_uv = mesh.face_uv.copy()
        if len(face_uv):
            face_uv[flipped] = face_uv[flipped][:, [0, 2, 1]]
        mesh = replace(mesh, faces=faces, face_uv=face_uv)
        log.info("%s: %d faces wound against their neighbours turned to match them", where, int(flipped.sum()))
    mesh = charted_as_asked(mesh, gcfg, where)
    pcfg = gcfg.get("placement")
    placement = None
    several = int(mesh_pieces(mesh.faces, len(mesh.vertices)).max()) + 1 > 1  # an outfit: split it first (checks)
    if body is not None and pcfg is not None and pcfg.get("enabled", False) and not several:
        x, placement = place_garment(mesh.vertices, mesh.faces, body, gcfg, where)
        log.info("%s: %s", where, "; ".join(placement.lines()))
    else:
        unit = gcfg.get("position_unit", "m")
        x = (mesh.vertices * metres_per_unit("m" if unit in (None, "auto") else unit, "garment.position_unit")
             + np.asarray(gcfg.get("position_offset") or (0.0, 0.0, 0.0), np.float64))
    return replace(mesh, vertices=x), placement
