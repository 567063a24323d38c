"""Procedural lower-body garments sized to the body they are worn on: the skirt and the trousers.

One job: produce each as data (a Garment and its automatic Cage), from the garment config and the body's
own landmarks (waist and hip girths and heights, the crotch, the leg joints' rest heads, the legs' girths),
so the same preset fits any body that has legs (Anny at any phenotype).

Both are a front and a back panel sewn into one mesh, as the T-shirt (pbc.geometry.garment): each panel is a
structured grid of rows (down from the waist) and columns (to the body's left, seen from the front), one UV
chart per panel, scaled uniformly so that ``uv * uv_scale`` is the flat pattern in metres (the cloth's rest
shape); the back chart is mirrored so both are seen from outside. Rows are straight and level in the
pattern; the columns fan out where the garment widens, so a panel is a trapezoid, not a stair-stepped grid.

- skirt: each panel runs from the waist (its girth plus ease) over the hips (their girth plus ease) and
  flares to the hem above the knees; sewn at the two side seams. Openings: waist, hem.
- trousers: each panel is one piece above the crotch and two legs below it (the columns on the centre line
  split into the left leg's and the right leg's inner edge, and the two legs part in a V of
  ``notch_angle_deg`` a side, so the charts stay apart in the image); sewn at the two side seams, the two
  inseams and the crotch point. Openings: waist and the two ankles.

The 3D rest shape (the shrink-wrap's starting point) is an ellipse around the trunk per row, and a circle
around the leg's bone axis per row of a leg. Metres, root frame (y up, x to the body's left, z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from pbc.geometry.body.base import Body
from pbc.geometry.body.measure import girth, measurements, torso_mesh
from pbc.geometry.cage.auto import auto_cage
from pbc.geometry.cage.base import Cage
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.patterns import cell_triangles, two_panel_uv

LEG_SIDES = ("left", "right")
MIDPLANE = 0.015  # m: body vertices this close to x = 0 are on the mid-plane (the crotch is their lowest)


# --------------------------------------------------------------------------------------------------
# the body's landmarks


def leg_mesh(body: Body, joints) -> trimesh.Trimesh:
    """The rest mesh's faces whose corners the leg's joints carry (their weights sum past a half)."""
    sk = body.skeleton
    cols = [sk.index(str(j)) + 1 for j in joints]
    carried = (body.weights[:, cols].sum(1) > 0.5).numpy()
    f = body.faces.numpy()
    return trimesh.Trimesh(body.vertices.double().numpy(), f[carried[f].all(1)], process=False)


def lower_landmarks(body: Body, legs) -> dict:
    """What the lower-body garments are sized from (m, root frame): the waist and hips girths and heights,
    the trunk's centre z at them, the crotch height, each leg's joints' rest heads (hip, knee, ankle) and
    the legs' girths at a height (a function, `leg_girth(side, y)`: mean of the two legs).

    legs: {'left': [hip, knee, ankle], 'right': [...]} joint names.
    """
    missing = [str(j) for side in LEG_SIDES for j in legs[side] if str(j) not in body.skeleton.names]
    if missing:
        raise ValueError(f"this garment is worn on the legs, and the body has no joints {missing}: use a body "
                         "with legs (body=anny); its joints are " + ", ".join(body.skeleton.names))
    m = measurements(body)
    sk = body.skeleton
    heads = {side: sk.rest_heads[sk.indices([str(j) for j in legs[side]], "garment.legs")].double().numpy()
             for side in LEG_SIDES}
    v = body.vertices.double().numpy()
    mid = np.abs(v[:, 0]) < MIDPLANE
    below = v[:, 1] < 0.5 * (heads["left"][0, 1] + heads["right"][0, 1]) + 0.05
    crotch = float(v[mid & below, 1].min())
    torso = torso_mesh(body)

    def centre_z(y: float) -> float:
        seg = trimesh.intersections.mesh_plane(torso, [0.0, 1.0, 0.0], [0.0, float(y), 0.0])
        pts = np.asarray(seg).reshape(-1, 3)
        return float(0.5 * (pts[:, 2].min() + pts[:, 2].max())) if len(pts) else 0.0

    meshes = {side: leg_mesh(body, legs[side]) for side in LEG_SIDES}

    def leg_girth(y: float) -> float:
        return float(np.mean([girth(meshes[s], y) for s in LEG_SIDES]))

    return {"waist": m["waist"], "waist_at": m["waist_at"], "hips": m["hips"], "hips_at": m["hips_at"],
            "waist_z": centre_z(m["waist_at"]), "hips_z": centre_z(m["hips_at"]), "crotch": crotch,
            "legs": heads, "leg_girth": leg_girth}


def _interp(y, ys, values) -> np.ndarray:
    """Piecewise-linear in height: ys need not be sorted (given top down); clamped at the ends."""
    ys, values = np.asarray(ys, np.float64), np.asarray(values, np.float64)
    order = np.argsort(ys)
    return np.interp(y, ys[order], values[order])


def _ellipse_radii(circumference, aspect: float):
    """Semi-axes (a, aspect a) of an ellipse of that circumference (Ramanujan's approximation)."""
    k = float(aspect)
    unit = math.pi * (3.0 * (1.0 + k) - math.sqrt((3.0 + k) * (1.0 + 3.0 * k)))
    a = np.asarray(circumference, np.float64) / unit
    return a, k * a


def _leg_axis(heads: np.ndarray, y) -> np.ndarray:
    """(n, 3) points on a leg's bone axis (hip -> knee -> ankle heads (3, 3)) at heights y (n,); beyond the
    hip or the ankle the end bone is extended."""
    y = np.atleast_1d(np.asarray(y, np.float64))
    out = np.zeros((len(y), 3))
    for k, yy in enumerate(y):
        b = 0 if yy >= heads[1, 1] else 1  # thigh above the knee, shin below
        p, q = heads[b], heads[b + 1]
        t = (yy - p[1]) / (q[1] - p[1])
        out[k] = p + t * (q - p)
    return out


# --------------------------------------------------------------------------------------------------
# two panels sewn into one mesh


@dataclass
class Panels:
    """One panel's grid (the back panel is the same pattern): rows r = 0..R top down, columns k = 0..K-1 to
    the body's left. pattern (R+1, K, 2) metres (X left, Y up); point (R+1, K) long: the panel vertex each
    grid point is (points with the same id are one vertex); cells (R, K-1) bool: quads kept; seam (R+1, K)
    bool: points the front and back share; front / back (R+1, K, 3): 3D rest positions per side."""

    pattern: np.ndarray
    point: np.ndarray
    cells: np.ndarray
    seam: np.ndarray
    front: np.ndarray
    back: np.ndarray


def sew_panels(p: Panels, uv_padding: float) -> Garment:
    """The Garment of a front and back panel sewn at their seam points (see Panels); one UV chart each."""
    used = np.zeros(p.point.shape, bool)
    rr, kk = np.nonzero(p.cells)
    for dr, dk in ((0, 0), (0, 1), (1, 0), (1, 1)):
        used[rr + dr, kk + dk] = True
    ids = np.unique(p.point[used])
    # front vertices: the panel's points; back vertices: the seam's shared, the others new
    front_id = -np.ones(int(p.point.max()) + 1, np.int64)
    front_id[ids] = np.arange(len(ids))
    seam_ids = np.unique(p.point[used & p.seam])
    back_id = -np.ones_like(front_id)
    back_id[seam_ids] = front_id[seam_ids]
    own = np.setdiff1d(ids, seam_ids)
    back_id[own] = len(ids) + np.arange(len(own))
    nv = len(ids) + len(own)
    vid_f, vid_b = front_id[p.point], back_id[p.point]
    faces_f = cell_triangles(p.cells, vid_f)
    faces_b = cell_triangles(p.cells, vid_b)[:, ::-1].copy()  # the back faces -z: flipped winding

    pat = np.zeros((nv, 2))
    pos = np.zeros((nv, 3))
    pat[vid_b[used]] = p.pattern[used]
    pos[vid_b[used]] = p.back[used]
    pat[vid_f[used]] = p.pattern[used]
    pos[vid_f[used]] = p.front[used]  # seam points: the front's (equal to the back's by construction)

    # one uniform scale for both charts (uv * uv_scale = pattern), each centred; the back mirrored
    lo, hi = p.pattern[used].min(0), p.pattern[used].max(0)
    uv_scale = float((hi - lo).max()) / (1.0 - 2.0 * float(uv_padding))
    c = 0.5 * (lo + hi)

    def to_uv(q, mirror):
        return np.stack([0.5 + (-1.0 if mirror else 1.0) * (q[:, 0] - c[0]) / uv_scale,
                         0.5 - (q[:, 1] - c[1]) / uv_scale], 1)

    uv, face_uv, vertex_uv, vertex_side = two_panel_uv(faces_f, faces_b, to_uv(pat, False), to_uv(pat, True))
    faces = np.concatenate([faces_f, faces_b])
    return Garment(
        vertices=torch.tensor(pos, dtype=torch.float32),
        faces=torch.tensor(faces, dtype=torch.long),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(face_uv, dtype=torch.long),
        face_side=torch.tensor(np.repeat([0, 1], [len(faces_f), len(faces_b)]), dtype=torch.long),
        vertex_uv=torch.tensor(vertex_uv, dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side, dtype=torch.long),
        uv_scale=uv_scale,
    )


def _trunk_ring(x_pattern, half_width, y, centre_z, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """Front and back 3D points (n, 3) of pattern points on the trunk ellipse of one row: x_pattern (n,) in
    [-half_width, half_width], the ellipse's circumference 4 half_width (a front and a back panel)."""
    a, b = _ellipse_radii(4.0 * half_width, aspect)
    theta = 0.5 * math.pi * np.clip(x_pattern / half_width, -1.0, 1.0)
    x, z = a * np.sin(theta), b * np.cos(theta)
    yy = np.full_like(x, y)
    return np.stack([x, yy, centre_z + z], -1), np.stack([x, yy, centre_z - z], -1)


def _auto(garment: Garment, gcfg) -> Cage:
    return auto_cage(garment, int(gcfg.patch_resolution), int(gcfg.crop_size), int(gcfg.margin),
                     chart_names=["front", "back"], face_chart=garment.face_side.numpy().copy(),
                     **dict(gcfg.get("autocage") or {}))


def _legs(gcfg) -> dict:
    return {side: [str(j) for j in gcfg.legs[side]] for side in LEG_SIDES}


# --------------------------------------------------------------------------------------------------
# the skirt


def skirt_panels(gcfg, land: dict) -> Panels:
    """The skirt's panel grid from the config (conf/garment/skirt.yaml) and the body's landmarks."""
    h = float(gcfg.grid_spacing)
    top = land["waist_at"] + float(gcfg.top_offset)
    knee = float(np.mean([land["legs"][s][1, 1] for s in LEG_SIDES]))
    hem = top + float(gcfg.length) * (knee - top)
    rows = max(int(round((top - hem) / h)), 2)
    y = top - (top - hem) * np.arange(rows + 1) / rows
    hips_w = land["hips"] + float(gcfg.hips_ease)
    widths = [land["waist"] + float(gcfg.waist_ease), hips_w, hips_w * (1.0 + float(gcfg.flare))]
    half = 0.25 * _interp(y, [top, land["hips_at"], hem], widths)  # a panel's half width per row
    cols = 2 * max(int(round(float(half.mean()) / h)), 1)
    t = np.linspace(-1.0, 1.0, cols + 1)
    pattern = np.stack(np.broadcast_arrays(half[:, None] * t[None], (y - top)[:, None]), -1)
    zc = _interp(y, [land["waist_at"], land["hips_at"]], [land["waist_z"], land["hips_z"]])
    front, back = np.zeros((rows + 1, cols + 1, 3)), np.zeros((rows + 1, cols + 1, 3))
    for r in range(rows + 1):
        front[r], back[r] = _trunk_ring(pattern[r, :, 0], half[r], y[r], zc[r], float(gcfg.depth_ratio))
    seam = np.zeros((rows + 1, cols + 1), bool)
    seam[:, [0, -1]] = True
    point = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    return Panels(pattern, point, np.ones((rows, cols), bool), seam, front, back)


def make_skirt(gcfg, body: Body) -> tuple[Garment, Cage]:
    """The skirt sized to `body` and its automatic cage. gcfg: conf/garment/skirt.yaml."""
    garment = sew_panels(skirt_panels(gcfg, lower_landmarks(body, _legs(gcfg))), float(gcfg.uv_padding))
    return garment, _auto(garment, gcfg)


# --------------------------------------------------------------------------------------------------
# the trousers


def trousers_panels(gcfg, land: dict) -> Panels:
    """The trousers' panel grid from the config (conf/garment/trousers.yaml) and the body's landmarks.

    Columns: k = 0..n the right half (outer edge k = 0 to the centre line k = n), k = n+1..2n+1 the left half
    (centre line k = n+1 to the outer edge); above the crotch the two centre columns are one point, below
    it they are the right and left leg's inner edges; the cells between them are never kept.
    """
    h = float(gcfg.grid_spacing)
    top = land["waist_at"] + float(gcfg.top_offset)
    crotch = land["crotch"] - float(gcfg.crotch_drop)
    ankle = float(np.mean([land["legs"][s][2, 1] for s in LEG_SIDES]))
    hem = crotch + float(gcfg.leg_length) * (ankle - crotch)
    knee = float(np.mean([land["legs"][s][1, 1] for s in LEG_SIDES]))
    rise = max(int(round((top - crotch) / h)), 2)
    rows = rise + max(int(round((crotch - hem) / h)), 2)
    dy = (top - crotch) / rise
    y = top - dy * np.arange(rows + 1)
    y[rise:] = crotch - (crotch - hem) * np.arange(rows + 1 - rise) / (rows - rise)
    g = land["leg_girth"]
    thigh_y, calf_y = land["crotch"] - float(gcfg.thigh_below_crotch), hem + float(gcfg.hem_girth_above)
    leg_w = 0.5 * (np.array([g(thigh_y), g(knee), g(calf_y)]) + float(gcfg.leg_ease))  # a leg panel's width
    leg_w[2] = max(leg_w[2], 0.5 * float(gcfg.min_hem_girth))
    width_leg = _interp(y, [crotch, knee, hem], leg_w)
    trunk = [0.5 * (land["waist"] + float(gcfg.waist_ease)), 0.5 * (land["hips"] + float(gcfg.hips_ease))]
    hips_at = min(land["hips_at"], top - dy)
    if hips_at <= crotch:
        raise ValueError(f"trousers: the hips ({hips_at:.2f} m) are not above the crotch ({crotch:.2f} m) on this "
                         "body; lower garment.crotch_drop")
    # the panel's width above the crotch: the waist's, the hips', then both legs' at the crotch
    width_top = _interp(y, [top, hips_at, crotch], [trunk[0], trunk[1], 2.0 * width_leg[rise]])
    n = max(int(round(0.5 * float(width_leg.mean()) / h)), 2)  # cells across one leg panel
    K = 2 * n + 2
    tan = math.tan(math.radians(float(gcfg.notch_angle_deg)))
    gap = np.where(np.arange(rows + 1) > rise, 2.0 * tan * (crotch - y), 0.0)
    pattern = np.zeros((rows + 1, K, 2))
    pattern[..., 1] = (y - top)[:, None]
    s = np.arange(n + 1) / n
    above = np.arange(rows + 1) <= rise
    half = np.where(above, 0.5 * width_top, width_leg)  # above: the half panel; below: one leg
    # right half: the outer edge (k = 0) to the centre (k = n); left half: the centre (k = n+1) to the outer edge
    pattern[:, : n + 1, 0] = -0.5 * gap[:, None] - half[:, None] * (1.0 - s[None])
    pattern[:, n + 1 :, 0] = 0.5 * gap[:, None] + half[:, None] * s[None]
    point = np.arange((rows + 1) * K).reshape(rows + 1, K)
    point[: rise + 1, n + 1] = point[: rise + 1, n]  # one centre line above the crotch
    cells = np.ones((rows, K - 1), bool)
    cells[:, n] = False
    seam = np.zeros((rows + 1, K), bool)
    seam[:, [0, -1]] = True  # the side seams
    seam[rise:, [n, n + 1]] = True  # the inseams, from the crotch point down
    # 3D: the trunk's ellipse above the crotch, a circle round each leg's bone axis below it
    front, back = np.zeros((rows + 1, K, 3)), np.zeros((rows + 1, K, 3))
    zc = _interp(y, [land["waist_at"], land["hips_at"]], [land["waist_z"], land["hips_z"]])
    aspect = float(gcfg.depth_ratio)
    for r in range(rows + 1):
        if above[r]:
            front[r], back[r] = _trunk_ring(pattern[r, :, 0], 0.5 * width_top[r], y[r], zc[r], aspect)
            continue
        radius = width_leg[r] / math.pi  # the leg's girth is a front and a back panel's width
        for side, cols, sgn in (("right", slice(0, n + 1), -1.0), ("left", slice(n + 1, K), 1.0)):
            centre = _leg_axis(land["legs"][side], y[r])[0]
            # theta: -pi/2 on the leg's inner side, +pi/2 on its outer side, 0 in front
            frac = (np.abs(pattern[r, cols, 0]) - 0.5 * gap[r]) / width_leg[r]
            theta = math.pi * (frac - 0.5)
            x = centre[0] + sgn * radius * np.sin(theta)
            z = radius * np.cos(theta)
            front[r, cols] = np.stack([x, np.full_like(x, y[r]), centre[2] + z], -1)
            back[r, cols] = np.stack([x, np.full_like(x, y[r]), centre[2] - z], -1)
    return Panels(pattern, point, cells, seam, front, back)


def make_trousers(gcfg, body: Body) -> tuple[Garment, Cage]:
    """The trousers sized to `body` and their automatic cage. gcfg: conf/garment/trousers.yaml."""
    garment = sew_panels(trousers_panels(gcfg, lower_landmarks(body, _legs(gcfg))), float(gcfg.uv_padding))
    return garment, _auto(garment, gcfg)


BUILDERS = {"skirt": make_skirt, "trousers": make_trousers}


def make_lower_body(gcfg, body: Body) -> tuple[Garment, Cage]:
    """The lower-body garment of `gcfg.kind` (skirt / trousers) sized to the body."""
    return BUILDERS[str(gcfg.kind)](gcfg, body)
