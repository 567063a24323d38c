"""Shrink-wrap the garment onto the rest body and embed its vertices in body triangles (appendix D.5).

One job: turn (garment, cage, body) into the barycentric embedding that skins cloth pixels with the
body (paper Sec. 5). Steps: (a) the cage curves are projected onto the body surface and a Laplace
equation carries their displacements to the other vertices; (b) vertices inside the body are pushed
out and every vertex is put on the surface; (c) an edge-length-equalising relaxation constrained to
the surface spreads the distortion evenly; (d) each vertex is embedded in its closest body triangle.
The surface is the body's analytic SDF (rest pose); the embedding uses the body mesh.

Every step follows the body region a garment region covers (`garment_regions`): a sleeve is wrapped,
projected and embedded on the arm it surrounds, a trouser leg on its leg, even where another part's
surface is nearer (the inner sleeve of an A-posed body hangs a few centimetres from the torso's side).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
import trimesh
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from torch import Tensor

from pbc.geometry.body.base import Body, body_sdf
from pbc.geometry.body.skeleton import MIDPLANE_TOL, descendants, limb_segments
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.checks import (
    FaceLimits,
    LimbCloth,
    chart_names_from_cage,
    check_arm_flaps,
    check_face_stretch,
    check_far,
    check_sleeves,
    check_stretch,
    cloth_encircled_degrees,
    face_patches,
    face_stretch,
    faces_past,
    patch_stretch,
    sleeve_axes,
)
from pbc.geometry.meshops import (
    closest_on_mesh,
    face_areas,
    face_charts,
    face_normals,
    segment_hits,
    solve_dirichlet,
)

log = logging.getLogger(__name__)


@dataclass
class Embedding:
    face: Tensor  # (V,) long, body triangle of each garment vertex
    bary: Tensor  # (V, 3) barycentric weights, rows sum to 1
    part: Tensor  # (V,) long, primary collision part (0 torso, 1 left arm, 2 right arm)
    # (V,) float, metres along the body triangle's normal where a drape starts: a part lying on the garment's own
    # cloth (a collar, a cuff, a pocket) starts above the cloth under it; None: every vertex starts on the skin
    lift: Tensor | None = None


# m: a wrapped vertex farther than this from its embedded point lies on a layer (the wrap itself is on the skin)
LIFT_TOL = 1e-4
# barycentric weight by which a layer's way to the body may pass outside the cloth's triangle under it: the edge of
# a collar or cuff copied out from the cloth's own edge lies just beyond it
LAYER_EDGE_MARGIN = 0.25
# a layer's normal and the cloth's under it, both turned away from the body, are at most 60 degrees apart
LAYER_MIN_COS = 0.5


def _sw_cfg(cfg):
    """Accept the garment config (with a ``shrinkwrap`` node) or the shrinkwrap node itself."""
    return cfg["shrinkwrap"] if "shrinkwrap" in cfg else cfg


# --------------------------------------------------------------------------------------------------
# body regions: which body part a garment region covers

REGIONS = ("torso", "left arm", "right arm", "left leg", "right leg")
LIMB_JOINTS = {1: "l_arm", 2: "r_arm", 3: "l_hip", 4: "r_hip"}  # each limb: this joint and its descendants
LIMB_WEIGHT = 0.5  # a body vertex belongs to a limb when the limb's joints carry at least this skinning weight


def body_region_masks(body: Body) -> list[np.ndarray | None]:
    """Per region of REGIONS, the body vertices (Vb,) bool on it; None for the torso (everything) and for a limb
    the body lacks (the mannequin has no legs). Arms: the body's arm part masks (``body.parts``); legs: the
    vertices the hip's chain carries at least LIMB_WEIGHT of."""
    sk = body.skeleton
    names = list(sk.names)
    weights = body.weights.cpu().numpy()
    out: list[np.ndarray | None] = [None]
    for r, joint in LIMB_JOINTS.items():
        if joint not in names:
            out.append(None)
            continue
        if r in (1, 2) and body.parts.shape[0] > r:
            mask = body.parts[r].cpu().numpy().astype(bool)
        else:
            mask = weights[:, [1 + j for j in sorted(descendants(sk, joint))]].sum(1) >= LIMB_WEIGHT
        out.append(mask if mask.any() else None)
    return out


def body_region_faces(body: Body, core: bool = False) -> list[np.ndarray | None]:
    """Per region of REGIONS, the body triangles (ids) a garment region on it is wrapped and embedded on: those
    with any corner on the limb, so the seam band (the shoulder, the groin) stays reachable from both sides; with
    ``core``, those with every corner on it. None for the torso (the whole surface) and for a missing limb."""
    faces = body.faces.cpu().numpy()
    out: list[np.ndarray | None] = []
    for mask in body_region_masks(body):
        if mask is None:
            out.append(None)
            continue
        on = mask[faces].all(1) if core else mask[faces].any(1)
        out.append(np.flatnonzero(on) if on.any() else None)
    return out


def garment_regions(faces: np.ndarray, cage, points: np.ndarray, body: Body, min_encircled_deg: float,
                    smoothing: float, candidates: int = 12, limbs: bool = True) -> np.ndarray:
    """(V,) region of REGIONS per garment vertex (`_regions`)."""
    return _regions(faces, cage, points, _RestSurface(body, candidates), min_encircled_deg, smoothing, limbs)[0]


def smooth_over_mesh(values: np.ndarray, faces: np.ndarray, radius: float, points: np.ndarray) -> np.ndarray:
    """values (V,) averaged over the garment's mesh out to about ``radius`` m: (radius / mean edge)^2 steps of
    v <- (v + mean of the neighbours' v) / 2, a diffusion that reaches that far (V,)."""
    f = np.asarray(faces)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n = len(values)
    w = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    w.data[:] = 1.0  # an edge shared by two faces counts once
    deg = np.maximum(np.asarray(w.sum(1)).ravel(), 1.0)
    edge = float(np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=1).mean())
    out = np.asarray(values, np.float64).copy()
    for _ in range(int(np.ceil((radius / max(edge, 1e-9)) ** 2))):
        out = 0.5 * (out + (w @ out) / deg)
    return out


def _regions(faces: np.ndarray, cage, points: np.ndarray, surface: _RestSurface, min_encircled_deg: float,
             smoothing: float, limbs: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """(V,) region of REGIONS per garment vertex at ``points`` (V, 3) (the garment as placed on ``surface``'s
    rest body).

    pbc's shirt names its sleeve patches (``*sleeve_left*`` / ``*sleeve_right*``): those are on their arm, the
    rest on the torso. Any other garment: how much nearer each vertex lies to a limb's surface than to the
    torso's (the torso measured on its own triangles, outside every limb), averaged over the garment out to
    ``smoothing`` m (`smooth_over_mesh`), so the inner side of a sleeve, a few centimetres from the torso's side
    under a hanging arm, goes with the rest of its sleeve, and the chest beside a sleeve with the chest; a vertex
    nearer a limb on that average is on its nearest limb, kept only where the garment's faces on that limb surround
    it (`cloth_encircled_degrees`, the sleeve check's measure, >= ``min_encircled_deg``: a sleeve or a trouser
    leg, not a skirt's side beside a leg or a cape over an arm). ``limbs`` False (garment.shrinkwrap.arm_parts:
    the skirt, the trousers): all torso.

    Returns the regions (V,) and, where measured, the region each cage patch lies nearest on median (P,) (for
    the stretch check's words), else None."""
    region = np.zeros(len(points), np.int64)
    named = [p for p in cage.patches if "sleeve_left" in p.name or "sleeve_right" in p.name]
    for p in named:
        region[np.asarray(p.vertices, np.int64)] = 1 if "sleeve_left" in p.name else 2
    if named or not limbs:
        return region, None
    body = surface.body
    tris = surface.region_faces
    reached = [r for r, tri in enumerate(tris) if tri is not None]
    if not reached:
        return region, None
    # nearness is measured to each limb's core (triangles wholly on it) and to everything else as the torso, so
    # the seam band (the shoulder, the groin) counts for the torso here; a limb's vertices are then wrapped and
    # embedded on its triangles with the band (`body_region_faces`)
    cores = body_region_faces(body, core=True)
    core = {r: tris[r] if cores[r] is None else cores[r] for r in reached}
    in_core = np.zeros(len(surface.tris), bool)
    for r in reached:
        in_core[core[r]] = True
    allowed = {0: np.flatnonzero(~in_core), **core}
    pts = np.asarray(points, np.float64)
    dist = np.full((len(REGIONS), len(pts)), np.inf)
    for r, tri in allowed.items():
        if len(tri):
            cp, _ = surface.closest(pts, tri)
            dist[r] = np.linalg.norm(cp - pts, axis=1)
    limb = 1 + np.argmin(dist[1:], axis=0)
    nearer = np.clip(dist[0] - dist[1:].min(0), -1.0, 1.0)  # m nearer a limb than the torso
    on_limb = smooth_over_mesh(nearer, faces, smoothing, pts) > 0.0
    region[on_limb] = limb[on_limb]
    face_region = region[np.asarray(faces)]
    for r in reached:
        on = region == r
        if not on.any():
            continue
        # measured on the faces wholly on the limb, not on its vertices: a coarse sleeve's rings (8 vertices, 4.5 cm
        # apart, skewed to the bone) read 199 degrees round A-posed Anny's arm on their vertices, 280 on their faces
        deg = cloth_encircled_degrees(pts, np.asarray(faces)[(face_region == r).all(1)],
                                      limb_segments(body.skeleton, LIMB_JOINTS[r]))
        if deg >= min_encircled_deg:
            continue
        # cloth along a limb that does not close round it goes on the torso: a skirt beside the legs, and a short
        # loose sleeve over the shoulder (155-265 degrees round the arm's bones on Anny) alike; a cape's flap along
        # the arm measures less (140-150), so it is wrapped on the torso too rather than refused
        region[on] = 0
    nearest = np.array([int(np.argmin(np.median(dist[:, p.vertices], axis=1))) if len(p.vertices) else 0
                        for p in cage.patches], np.int64)
    return region, nearest


# --------------------------------------------------------------------------------------------------
# garment-side helpers


def vertex_parts(region: np.ndarray, wrapped: np.ndarray | None = None, body: Body | None = None) -> np.ndarray:
    """(V,) primary collision part per vertex (appendix D.6): 0 torso, 1 left arm, 2 right arm.

    A vertex on an arm region (`garment_regions`) collides with that arm; legs collide with the torso part
    (its primitives hold the legs). With the wrapped rest positions (V, 3) and the body, torso-region vertices
    lying beyond an arm joint (|x| past the ``l_arm`` / ``r_arm`` head) collide with that arm too: they cover
    the upper arm, and a torso-only collider would let them sink into it once the arm moves.
    """
    part = np.where(np.isin(region, (1, 2)), region, 0).astype(np.int64)
    if wrapped is not None and body is not None:
        names = list(body.skeleton.names)
        heads = body.skeleton.rest_heads.numpy()
        x = np.asarray(wrapped)[:, 0]
        part[(part == 0) & (x > heads[names.index("l_arm"), 0])] = 1
        part[(part == 0) & (x < heads[names.index("r_arm"), 0])] = 2
    return part


def garment_edges(garment: Garment) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges (E, 2) and their flat-pattern rest lengths (E,) in metres (uv * uv_scale)."""
    f = garment.faces.cpu().numpy()
    corners = (garment.uv[garment.face_uv] * garment.uv_scale).double().cpu().numpy()  # (F, 3, 2)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lens = np.concatenate([np.linalg.norm(corners[:, a] - corners[:, b], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    e = np.sort(e, axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.ravel()
    # a seam edge appears once per chart with the same length; average them anyway
    rest = np.bincount(inv, weights=lens, minlength=len(uniq)) / np.bincount(inv, minlength=len(uniq))
    return uniq, rest


def pattern_laplacian(garment: Garment) -> sp.csr_matrix:
    """Cotangent Laplacian (V, V) of the flat pattern, assembled from each face's own chart corners so
    seam vertices (two uvs) are handled; negative semi-definite."""
    f = garment.faces.cpu().numpy()
    c = (garment.uv[garment.face_uv] * garment.uv_scale).double().cpu().numpy()
    c = np.concatenate([c, np.zeros((*c.shape[:2], 1))], axis=2)
    n = garment.num_vertices
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = (k + 1) % 3, (k + 2) % 3, k
        a, b = c[:, i] - c[:, o], c[:, j] - c[:, o]
        cot = (a * b).sum(1) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-12)
        rows += [f[:, i], f[:, j]]
        cols += [f[:, j], f[:, i]]
        vals += [0.5 * cot, 0.5 * cot]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    return (w - sp.diags(np.asarray(w.sum(axis=1)).ravel())).tocsr()


def area_ratio(garment: Garment, positions: np.ndarray) -> np.ndarray:
    """(F,) 3D face area at positions (V, 3) over the flat-pattern face area."""
    f = garment.faces.cpu().numpy()
    p = positions[f]
    a3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    c = (garment.uv[garment.face_uv] * garment.uv_scale).double().cpu().numpy()
    e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    a2 = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return a3 / a2


def _ratio_stats(r: np.ndarray, prefix: str) -> dict:
    return {f"{prefix}_mean": float(r.mean()), f"{prefix}_min": float(r.min()), f"{prefix}_max": float(r.max()),
            f"{prefix}_std": float(r.std())}


# --------------------------------------------------------------------------------------------------
# body-side helpers (rest pose, analytic SDF)


class _RestSurface:
    """The rest body as a surface: analytic SDF (whole body or one part) for inside tests and ray
    bisection, and closest-point projection onto the body mesh (the surface the embedding uses)."""

    def __init__(self, body: Body, candidates: int):
        self.body = body
        j = body.skeleton.rest_heads.shape[0]
        self.rot = torch.eye(3, dtype=torch.float32).expand(1, j, 3, 3)
        self.tris = body.vertices.double().cpu().numpy()[body.faces.cpu().numpy()]  # (Fb, 3, 3)
        self.tree = cKDTree(self.tris.mean(axis=1))
        self.k = min(int(candidates), len(self.tris))
        self._trees: dict = {}
        self.region_faces = body_region_faces(body)

    def sdf(self, points: np.ndarray, part: int | None = None) -> np.ndarray:
        with torch.no_grad():
            p = torch.as_tensor(points, dtype=torch.float32)[None]
            return body_sdf(self.body, self.rot, p, part=part)[0].double().numpy()

    def _tree(self, allowed: np.ndarray) -> cKDTree:
        key = np.asarray(allowed, np.int64).tobytes()
        if key not in self._trees:
            self._trees[key] = cKDTree(self.tris[allowed].mean(axis=1))
        return self._trees[key]

    def closest(self, points: np.ndarray, allowed: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Closest mesh point (N, 3) and its triangle (N,) among ``k`` nearest-centroid candidates
        (of the ``allowed`` triangle ids if given)."""
        pts = np.asarray(points, np.float64)
        if allowed is None:
            tree, ids, k = self.tree, None, self.k
        else:
            tree, ids, k = self._tree(allowed), allowed, min(self.k, len(allowed))
        _, cand = tree.query(pts, k=k)
        cand = np.asarray(cand).reshape(len(pts), k)
        if ids is not None:
            cand = ids[cand]
        p = np.repeat(pts, k, axis=0)
        cp = trimesh.triangles.closest_point(self.tris[cand.ravel()], p).reshape(len(pts), k, 3)
        best = np.linalg.norm(cp - pts[:, None], axis=2).argmin(1)
        rows = np.arange(len(pts))
        return cp[rows, best], cand[rows, best]

    def project(self, points: np.ndarray) -> np.ndarray:
        return self.closest(points)[0]

    def closest_in_regions(self, points: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`closest` for garment points (N, 3) each kept on its region's triangles (region (N,) of REGIONS;
        the torso, and a limb the body lacks, reach the whole surface)."""
        cp, face = self.closest(points)
        for r in np.unique(region):
            tri = self.region_faces[r] if r < len(self.region_faces) else None
            if tri is None:
                continue
            sel = region == r
            cp[sel], face[sel] = self.closest(np.asarray(points)[sel], tri)
        return cp, face


def _bone_segments(body: Body) -> tuple[np.ndarray, np.ndarray, float]:
    """Bone axes (S, 2, 3) guiding the cage projection, their kind (S,), and the shoulder line height.

    kind 0: the centre line (spine, neck), extended below its lowest joint to the hem region;
    kind 3: the shoulder line, from each bone leaving the centre line (clavicle) out to the tip of its
    arm (for torso vertices above the shoulder line, so the shoulder seam lands on the shoulder top);
    kind 1 / 2: the left / right arm bones, extended beyond the arm's outermost joint (sleeves).
    """
    skel = body.skeleton
    heads = skel.rest_heads.double().cpu().numpy()
    parents = skel.parents
    root = np.zeros(3)
    span = float(np.ptp(heads, axis=0).max())  # extension length: the skeleton's size
    on_centre = np.abs(heads[:, 0]) < MIDPLANE_TOL
    segs, kind, shoulder_y = [], [], []
    for sgn, side in ((1.0, 1), (-1.0, 2)):
        tip = int(np.argmax(sgn * heads[:, 0]))
        par = parents[tip]
        d = heads[tip] - (root if par < 0 else heads[par])
        d /= max(np.linalg.norm(d), 1e-12)
        segs.append((heads[tip], heads[tip] + span * d))
        kind.append(side)
        # the shoulder line: the centre-line end of this arm's chain out to its extended tip
        j = tip
        while parents[j] >= 0 and not on_centre[parents[j]]:
            j = parents[j]
        start = heads[j] * np.array([0.0, 1.0, 1.0])  # horizontal: from the centre at the shoulder's height
        segs.append((start, heads[tip] + span * d))
        kind.append(3)
        shoulder_y.append(heads[tip][1])
    for j, par in enumerate(parents):
        a = root if par < 0 else heads[par]
        b = heads[j]
        if on_centre[j] and abs(a[0]) < MIDPLANE_TOL:
            segs.append((a, b))
            kind.append(0)
        elif not on_centre[j]:
            segs.append((a, b))
            kind.append(1 if b[0] > 0 else 2)
    low = np.vstack([root, heads[on_centre]])
    bottom = low[np.argmin(low[:, 1])]
    segs.append((bottom - np.array([0.0, span, 0.0]), bottom))
    kind.append(0)
    return np.asarray(segs), np.asarray(kind), float(np.mean(shoulder_y))


def _closest_on_segments(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Closest point on any of segs (S, 2, 3) for each point p (N, 3) -> (N, 3)."""
    a, b = segs[:, 0], segs[:, 1]
    ab = b - a
    t = np.einsum("nsk,sk->ns", p[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-12)
    q = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    d = np.linalg.norm(p[:, None] - q, axis=2)
    return q[np.arange(len(p)), d.argmin(1)]


def cage_targets(garment: Garment, cage, body: Body, surface: _RestSurface, part: np.ndarray, steps: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Body-surface targets of the cage-curve vertices: (K,) ids, (K, 3) targets.

    Each vertex is moved along the ray from the closest point of its part's bone axes through the
    vertex to where the ray leaves that part's surface (bisection on the part SDF, ``steps`` halvings).
    Axes: the spine for torso vertices below the shoulder line, the spine or the shoulder line above it
    (so shoulder seams land on the shoulder top), the arm bones for sleeves.
    """
    ids = np.unique(np.concatenate([np.asarray(c, np.int64) for c in cage.curves.values()]))
    p = garment.vertices.double().cpu().numpy()[ids]
    segs, kind, shoulder_y = _bone_segments(body)
    vpart = part[ids]
    a = np.empty_like(p)
    # which SDF each ray must leave: spine rays the torso's own (not run along an arm), shoulder-line
    # and sleeve rays the whole body (the shoulder is where torso and arm primitives blend)
    ray_part = np.where(vpart == 0, 0, -1)
    for k in range(3):
        sel = vpart == k
        if k == 0:
            low = sel & (p[:, 1] < shoulder_y)
            a[low] = _closest_on_segments(p[low], segs[kind == 0])
            high = sel & ~low
            a[high] = _closest_on_segments(p[high], segs[(kind == 0) | (kind == 3)])
            on_spine = np.abs(a[:, 0]) < MIDPLANE_TOL
            ray_part[high & ~on_spine] = -1
        elif sel.any():
            a[sel] = _closest_on_segments(p[sel], segs[kind == k])
    d = p - a
    dist = np.linalg.norm(d, axis=1)
    d /= np.maximum(dist, 1e-12)[:, None]

    def part_sdf(x):
        out = np.empty(len(x))
        for k in (-1, 0):
            sel = ray_part == k
            if sel.any():
                out[sel] = surface.sdf(x[sel], part=None if k < 0 else k)
        return out

    # bracket [axis point (inside), beyond the vertex (outside)]
    lo = np.zeros(len(p))
    hi = dist + part_sdf(p).clip(min=0.0) + 0.05
    inside0 = part_sdf(a) < 0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        s = part_sdf(a + mid[:, None] * d) < 0
        lo = np.where(s, mid, lo)
        hi = np.where(s, hi, mid)
    q = a + (0.5 * (lo + hi))[:, None] * d
    # an axis point outside the body (e.g. the extended spine below the pelvis): closest point instead
    if (~inside0).any():
        q[~inside0] = surface.project(p[~inside0])
    return ids, q


# --------------------------------------------------------------------------------------------------
# layers: parts that lie on the garment's own cloth

def garment_layers(points: np.ndarray, faces: np.ndarray, body_points: np.ndarray, max_gap: float,
                   min_area: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which vertices lie on top of the garment's own cloth (a folded collar, a turned-back cuff, a pocket).

    points (V, 3) the garment as modelled; body_points (V, 3) each vertex's closest body point (on its region). A
    vertex is on a layer when the way from it towards the body crosses a garment triangle within ``max_gap`` (m),
    not in its own neighbourhood (the faces of its one-ring), facing the same way (LAYER_MIN_COS), and the layer
    it belongs to (the connected faces of such vertices) covers at least ``min_area`` (m^2): a few vertices where
    a modelled garment folds at the armpit are no collar. Returns the triangle under each vertex (V,) int64 (-1:
    none), the barycentric weights of the crossing (V, 3) and the gap (V,) m.
    """
    pts = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    n = len(pts)
    inc = sp.csr_matrix((np.ones(f.size), (f.ravel(), np.repeat(np.arange(len(f)), 3))), shape=(n, len(f)))
    skip = ((inc @ inc.T) @ inc).tocsr()  # (V, F): faces touching a vertex of the vertex's one-ring
    way = np.asarray(body_points, np.float64) - pts
    to_body = np.linalg.norm(way, axis=1)
    ends = pts + way / np.maximum(to_body, 1e-12)[:, None] * np.minimum(to_body, max_gap)[:, None]
    face, dist, bary = segment_hits(pts, ends, pts, f, skip, margin=LAYER_EDGE_MARGIN)
    # a layer lies on the cloth under it facing the same way (both away from the body): cloth facing it across a
    # gap (a torso's side under a hanging sleeve's inner side) is another sheet, not the one it lies on
    hit = np.flatnonzero(face >= 0)
    vn = trimesh.Trimesh(pts, f, process=False).vertex_normals[hit]
    vn *= np.sign(np.einsum("nd,nd->n", vn, -way[hit]))[:, None]
    tri = pts[f[face[hit]]]
    fn = face_normals(tri)
    below = np.asarray(body_points, np.float64)[f[face[hit]]].mean(1)
    fn *= np.sign(np.einsum("nd,nd->n", fn, tri.mean(1) - below))[:, None]
    other = hit[np.einsum("nd,nd->n", vn, fn) < LAYER_MIN_COS]
    face[other], dist[other], bary[other] = -1, np.inf, 0.0
    # each layer: the faces whose three vertices lie on cloth, joined through shared vertices; a small one is not
    on = face >= 0
    full = np.flatnonzero(on[f].all(1))
    keep = np.zeros(n, bool)
    if len(full):
        adj = sp.csr_matrix((np.ones(3 * len(full)), (f[full].ravel(), np.repeat(np.arange(len(full)), 3))),
                            shape=(n, len(full)))
        _, comp = connected_components(adj.T @ adj, directed=False)
        area = np.bincount(comp, face_areas(pts, f[full]))
        big = np.flatnonzero(area >= min_area)
        keep[np.unique(f[full][np.isin(comp, big)])] = True
    drop = on & ~keep
    face[drop], dist[drop], bary[drop] = -1, np.inf, 0.0
    # a layer's border (its edge copied out from the cloth's own edge, or where it is sewn on) lies on the cloth
    # nearest to it, whichever way the body is
    if keep.any():
        border = np.zeros(n, bool)
        border[f[keep[f].any(1)].ravel()] = True
        border &= ~keep
        cloth = np.flatnonzero(~(keep | border)[f].any(1))
        if border.any() and len(cloth):
            cp, tri, w = closest_on_mesh(pts[border], pts, f[cloth])
            gap_b = np.linalg.norm(cp - pts[border], axis=1)
            near = gap_b <= max_gap
            ids = np.flatnonzero(border)[near]
            face[ids], dist[ids], bary[ids] = cloth[tri[near]], gap_b[near], w[near]
    return face, bary, dist


def place_layers(x: np.ndarray, faces: np.ndarray, under: np.ndarray, bary: np.ndarray, gap: np.ndarray,
                 surface: _RestSurface) -> np.ndarray:
    """Put each layer vertex (under >= 0) at `gap` (V,) above its point of the wrapped cloth under it, along that
    triangle's normal turned away from the body; a layer on a layer after the one under it. x (V, 3) -> (V, 3)."""
    x = x.copy()
    layered = under >= 0
    placed = ~layered
    for _ in range(8):
        ready = layered & ~placed & placed[faces[np.maximum(under, 0)]].all(1)
        if not ready.any():
            ready = layered & ~placed  # a cycle of layers: put the rest on what is there
        if not ready.any():
            break
        tri = x[faces[under[ready]]]
        p = np.einsum("nk,nkd->nd", bary[ready], tri)
        normal = face_normals(tri)
        out = surface.sdf(p + 1e-3 * normal) >= surface.sdf(p - 1e-3 * normal)
        normal[~out] *= -1
        x[ready] = p + gap[ready, None] * normal
        placed |= ready
    return x


# --------------------------------------------------------------------------------------------------
# the shrink-wrap


def vertex_stretch(edges: np.ndarray, length: np.ndarray, rest: np.ndarray, n: int) -> np.ndarray:
    """(n,) the stretch of each vertex's incident edges: their total length over their total rest length, the
    mean of their stretches l_e / rest_e weighted by rest_e. edges (E, 2), length and rest (E,) m (rest > 0).

    An edge moves the stretch at its ends by at most 1 / (its ends' total rest length) per metre it grows, so the
    relaxation's target for another edge there grows by at most half as much as it: a pattern with a short edge
    among long ones (a sliver of UV compressed at a seam or a crotch) cannot feed its own stretch back through its
    neighbours' targets. A vertex with no edge reads 1."""
    a, b = edges[:, 0], edges[:, 1]
    total = np.bincount(a, length, n) + np.bincount(b, length, n)
    total_rest = np.bincount(a, rest, n) + np.bincount(b, rest, n)
    return np.where(total_rest > 0, total / np.where(total_rest > 0, total_rest, 1.0), 1.0)


RELAX_STRETCH = ("rest_weighted", "mean")  # and "auto" (`shrinkwrap`): the mean, rest_weighted where it runs away


def relax_as_configured(garment: Garment, x: np.ndarray, surface, sw, region: np.ndarray | None = None
                        ) -> tuple[np.ndarray, int, str]:
    """`relax_on_surface` under ``sw`` (garment.shrinkwrap): its relax_stretch rule, or for ``auto`` the mean, run
    again rest-weighted where the mean grows the garment past ``relax_runaway`` x its area at x. A config recorded
    without the key (the shipped models' data) is relaxed with the mean, as its data is. -> (x, steps, the rule)."""
    rule = str(sw.get("relax_stretch", "mean"))
    args = (int(sw.relax_iterations), float(sw.relax_step), float(sw.relax_tol), region)
    first = "mean" if rule == "auto" else rule
    relaxed, steps = relax_on_surface(garment, x, surface, *args, first)
    if rule != "auto":
        return relaxed, steps, rule
    grew = float(area_ratio(garment, relaxed).sum() / max(area_ratio(garment, x).sum(), 1e-12))
    if grew <= float(sw.relax_runaway):
        return relaxed, steps, first
    log.info("the shrink-wrap's relaxation grew the garment %.1fx its area on the body (garment.shrinkwrap."
             "relax_runaway %.1f): relaxed again with each vertex's stretch weighted by rest length", grew,
             float(sw.relax_runaway))
    relaxed, steps = relax_on_surface(garment, x, surface, *args, "rest_weighted")
    return relaxed, steps, "rest_weighted"


def relax_on_surface(garment: Garment, x: np.ndarray, surface: _RestSurface, iterations: int, step: float,
                     tol: float, region: np.ndarray | None = None, stretch: str = "rest_weighted"
                     ) -> tuple[np.ndarray, int]:
    """Edge-length-equalising relaxation constrained to the body surface (appendix D.5).

    Per step: alpha_v = the stretch of v's incident edges (`vertex_stretch`; ``stretch="mean"``: the plain mean of
    their l_e / rest_e, which a sliver of compressed pattern feeds back into); edge (a, b) targets
    0.5 (alpha_a + alpha_b) rest_e; each vertex moves by ``step`` x the mean of its springs' position
    corrections, then is projected back onto the surface (its region's, with ``region`` (V,)). x (V, 3) ->
    (V, 3), steps taken.
    """
    if stretch not in RELAX_STRETCH:
        raise ValueError(f"garment.shrinkwrap.relax_stretch={stretch}: one of {', '.join(RELAX_STRETCH)}")
    region = np.zeros(len(x), np.int64) if region is None else region
    edges, rest = garment_edges(garment)
    a, b = edges[:, 0], edges[:, 1]
    n = len(x)
    deg = np.bincount(edges.ravel(), minlength=n).astype(np.float64)
    x = x.copy()
    steps = 0
    for _ in range(iterations):
        steps += 1
        e = x[b] - x[a]
        length = np.linalg.norm(e, axis=1)
        alpha = vertex_stretch(edges, length, rest, n) if stretch == "rest_weighted" else \
            (np.bincount(a, length / rest, n) + np.bincount(b, length / rest, n)) / deg
        target = 0.5 * (alpha[a] + alpha[b]) * rest
        # each endpoint takes half of the length error along the edge
        c = (0.5 * (length - target) / np.maximum(length, 1e-12))[:, None] * e
        move = np.zeros_like(x)
        for k in range(3):
            move[:, k] = np.bincount(a, c[:, k], n) - np.bincount(b, c[:, k], n)
        new = surface.closest_in_regions(x + step * move / deg[:, None], region)[0]
        delta = np.abs(new - x).max()
        x = new
        if delta < tol:
            break
    return x, steps


def wrap_positions(garment: Garment, cage, body: Body, cfg) -> tuple[np.ndarray, dict]:
    """Steps (a)-(c): the garment shrink-wrapped onto the rest body, (V, 3) float64, and stats."""
    x, _, stats = wrap_with_regions(garment, cage, body, cfg)
    return x, stats


def wrap_with_regions(garment: Garment, cage, body: Body, cfg) -> tuple[np.ndarray, np.ndarray, dict]:
    """`wrap_positions` and the garment regions (V,) of REGIONS it wrapped each vertex on."""
    sw = _sw_cfg(cfg)
    t0 = time.perf_counter()
    surface = _RestSurface(body, int(sw.nearest_triangles))
    x0 = garment.vertices.double().cpu().numpy()
    faces = garment.faces.cpu().numpy()
    region, nearest = _regions(faces, cage, x0, surface, float(sw.min_encircled_deg), float(sw.region_smoothing),
                               bool(sw.get("arm_parts", True)))
    # parts lying on the garment's own cloth go on the body part under that cloth, and back on top of it after (c)
    under, under_bary, gap = garment_layers(x0, faces, surface.closest_in_regions(x0, region)[0],
                                            float(sw.layer_max_gap), float(sw.layer_min_area))
    layered = under >= 0
    if layered.any():
        for _ in range(3):  # a layer on a layer takes its region from the cloth under it
            below = region[faces[under[layered]]]
            region[layered] = [np.bincount(r, minlength=len(REGIONS)).argmax() for r in below]
    part = vertex_parts(region)  # rays start from the bone under each patch
    face_chart = face_charts(garment)
    chart_names = chart_names_from_cage(cage, face_chart, faces)
    # the checks before any drape (pbc.geometry.garment.checks): each names the part, the number and the fix, where a
    # drape would only say minutes later that every sample was discarded
    far = sw.get("max_start_distance")
    limb = LimbCloth.from_config(sw)
    if far is not None:
        check_far(surface.sdf(x0), x0, faces, body, float(far), chart_names, face_chart)
    if bool(sw.get("arm_parts", True)) and far is not None:
        # cloth along a forearm that closes round no arm (a cape's flap) would be wrapped on the torso and caught by
        # the arm in every drape
        check_arm_flaps(x0, region == REGIONS.index("torso"), body, float(sw.min_encircled_deg), limb)
    max_angle = sw.get("max_sleeve_angle_deg")
    sleeves = (sleeve_axes(x0, faces, body, limb) if max_angle is None
               else check_sleeves(x0, faces, body, float(max_angle), limb))
    # (a) cage-guided Laplace morph of the displacements
    ids, targets = cage_targets(garment, cage, body, surface, part, int(sw.ray_bisection_steps))
    lap = pattern_laplacian(garment)
    disp = solve_dirichlet(-lap, np.zeros_like(x0), ids, targets - x0[ids])
    x = x0 + disp
    morph_inside = int((surface.sdf(x) < 0).sum())
    # (b) push out and settle every vertex on the surface (the wrap is skin tight)
    x = surface.closest_in_regions(x, region)[0]
    before = area_ratio(garment, x)
    # (c) relaxation on the surface
    x, iters, _ = relax_as_configured(garment, x, surface, sw, region)
    if layered.any():
        x = place_layers(x, faces, under, under_bary, np.maximum(gap, float(sw.layer_min_gap)), surface)
    after = area_ratio(garment, x)
    pattern = garment.pattern().double().cpu().numpy().reshape(-1, 2)
    wrapped_area, pattern_area = face_areas(x, faces), face_areas(pattern, np.arange(len(pattern)).reshape(-1, 3))
    fp = face_patches(cage, faces)
    stretch = patch_stretch(wrapped_area, pattern_area, fp, len(cage.patches))
    ratio, principal = face_stretch(x, faces, pattern.reshape(-1, 3, 2))
    stats = {"cage_vertices": int(len(ids)), "morph_inside": morph_inside, "relax_iterations": int(iters),
             "max_abs_sdf": float(np.abs(surface.sdf(x[~layered])).max()), "layer_vertices": int(layered.sum())}
    stats.update(_ratio_stats(before, "area_before"))
    stats.update(_ratio_stats(after, "area_after"))
    worst = int(stretch.argmax())
    stats.update(patch_stretch_max=float(stretch[worst]), patch_stretch_worst=cage.patches[worst].name)
    worst_face = int(np.nan_to_num(ratio, nan=np.inf).argmax())
    faces_limit = FaceLimits.from_config(sw)
    stats.update(face_stretch_max=float(ratio[worst_face]), face_stretch_worst=worst_face,
                 face_principal_max=float(principal[worst_face, 0]))
    if faces_limit.limit is not None:
        stats["faces_past_limit"] = int(len(faces_past(ratio, faces_limit.limit)))
    stats.update({f"sleeve_{side}_angle_deg": a["angle_deg"] for side, a in sleeves.items()})
    limit = sw.get("max_patch_stretch")
    if limit is not None:
        patch_chart = [chart_names[int(np.bincount(face_chart[fp == p.id]).argmax())] if (fp == p.id).any() else "?"
                       for p in cage.patches]
        on = [REGIONS[int(np.bincount(region[p.vertices]).argmax())] if len(p.vertices) else "torso"
              for p in cage.patches]
        overall = float(wrapped_area.sum() / max(float(pattern_area.sum()), 1e-30))
        given = float(face_areas(x0, faces).sum() / max(float(pattern_area.sum()), 1e-30))
        check_stretch(stretch, [p.name for p in cage.patches], patch_chart, float(limit), sleeves, on,
                      None if nearest is None else [REGIONS[r] for r in nearest], overall, given)
    # one face past the limit is refused, as one face past the drape's limit discards a drape
    check_face_stretch(ratio, principal, faces, faces_limit, x, body, chart_names, face_chart,
                       [p.name for p in cage.patches], fp, [REGIONS[r] for r in region], pattern_area,
                       surface.sdf(x0))
    stats["wrap_seconds"] = time.perf_counter() - t0
    return x, region, stats


def embed_points(points: np.ndarray, body: Body, part: np.ndarray, candidates: int,
                 region: np.ndarray | None = None) -> Embedding:
    """(d) Closest rest-body-mesh triangle and barycentric weights of points (V, 3), each within its region's
    triangles when ``region`` (V,) is given (`garment_regions`); part (V,) is stored as the primary collision
    part. ``candidates`` nearest triangle centroids are tested exactly."""
    surface = _RestSurface(body, candidates)
    pts = np.asarray(points, np.float64)
    cpt, face = surface.closest(pts) if region is None else surface.closest_in_regions(pts, region)
    w = trimesh.triangles.points_to_barycentric(surface.tris[face], cpt)
    w = np.clip(w, 0.0, None)  # the closest point is on the triangle: only round-off is negative
    w /= w.sum(1, keepdims=True)
    return Embedding(face=torch.tensor(face), bary=torch.tensor(w, dtype=torch.float32),
                     part=torch.tensor(part, dtype=torch.long))


def shrinkwrap(garment: Garment, cage, body: Body, cfg) -> tuple[Embedding, dict]:
    """Shrink-wrap the garment onto the rest body and embed it (appendix D.5).

    cfg: the garment config (its ``shrinkwrap`` node is used) or that node itself. Returns the
    Embedding (V,) and stats: area distortion (wrapped area / pattern area per face) mean/min/max/std
    before and after the relaxation, iterations, max |sdf| of the wrap, embedding error, seconds, and how
    many vertices each body region took.
    """
    t0 = time.perf_counter()
    x, region, stats = wrap_with_regions(garment, cage, body, cfg)
    # a garment that covers no arm (the skirt, the trousers: garment.shrinkwrap.arm_parts false) collides
    # with the torso part only, though its hips reach past the arm joints' x
    arms = bool(_sw_cfg(cfg).get("arm_parts", True))
    part = vertex_parts(region, x if arms else None, body if arms else None)
    emb = embed_points(x, body, part, int(_sw_cfg(cfg).nearest_triangles), region)
    rest = embedded_points(body.vertices[None].double(), body.faces, emb)[0].numpy()
    off = np.linalg.norm(rest - x, axis=1)
    if stats["layer_vertices"]:
        # a layer's start is lifted off the skin by its height over the body triangle (signed along its normal)
        normal = face_normals(body.vertices.double().numpy()[body.faces.numpy()[emb.face.numpy()]])
        lift = np.where(off > LIFT_TOL, np.einsum("nd,nd->n", x - rest, normal), 0.0)
        emb.lift = torch.tensor(lift, dtype=torch.float32)
        stats["layer_lift_max"] = float(np.abs(lift).max())
    stats["embed_max_distance"] = float(off[off <= LIFT_TOL].max(initial=0.0))
    stats.update({f"region_{name.replace(' ', '_')}_vertices": int((region == r).sum())
                  for r, name in enumerate(REGIONS)})
    stats["seconds"] = time.perf_counter() - t0
    return emb, stats


def start_points(body_vertices: Tensor, body_faces: Tensor, emb: Embedding, under: float = 0.0) -> Tensor:
    """Where a drape starts: the embedded points (B, V, 3), each lifted by ``emb.lift`` along its posed body
    triangle's unit normal (a layer starts above the cloth under it), a lifted one by ``under`` (m) more: the
    cloth under a layer starts on the skin and settles that far out (the simulator's cloth thickness).
    (B, Vb, 3) body vertices -> (B, V, 3)."""
    p = embedded_points(body_vertices, body_faces, emb)
    if emb.lift is None:
        return p
    tri = body_vertices[:, body_faces[emb.face.to(body_faces.device)]]  # (B, V, 3, 3)
    normal = torch.linalg.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :], dim=-1)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    lift = emb.lift.to(device=p.device, dtype=p.dtype)
    lift = lift + under * torch.sign(lift)
    return p + lift[None, :, None] * normal


def embedded_points(body_vertices: Tensor, body_faces: Tensor, emb: Embedding) -> Tensor:
    """Garment points carried by the body: (B, Vb, 3) body vertices -> (B, V, 3); differentiable."""
    tri = body_vertices[:, body_faces[emb.face.to(body_faces.device)]]  # (B, V, 3, 3)
    w = emb.bary.to(device=body_vertices.device, dtype=body_vertices.dtype)
    return (tri * w[None, :, :, None]).sum(dim=2)
