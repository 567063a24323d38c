"""Shrink-wrap the garment onto the rest body and embed its vertices in body triangles (appendix D.5).

One job: turn (garment, cage, body) into the barycentric embedding that skins cloth pixels with the
body (paper Sec. 5). Steps: (a) the cage curves are projected onto the body surface and a Laplace
equation carries their displacements to the other vertices; (b) vertices inside the body are pushed
out and every vertex is put on the surface; (c) an edge-length-equalising relaxation constrained to
the surface spreads the distortion evenly; (d) each vertex is embedded in its closest body triangle.
The surface is the body's analytic SDF (rest pose); the embedding uses the body mesh.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
import trimesh
from scipy.spatial import cKDTree
from torch import Tensor

from pbc.geometry.body.base import Body, body_sdf
from pbc.geometry.body.skeleton import MIDPLANE_TOL
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.checks import (
    chart_names_from_cage,
    check_far,
    check_sleeves,
    check_stretch,
    face_patches,
    patch_stretch,
    sleeve_axes,
)
from pbc.geometry.meshops import face_areas, face_charts, solve_dirichlet


@dataclass
class Embedding:
    face: Tensor  # (V,) long, body triangle of each garment vertex
    bary: Tensor  # (V, 3) barycentric weights, rows sum to 1
    part: Tensor  # (V,) long, primary collision part (0 torso, 1 left arm, 2 right arm)


def _sw_cfg(cfg):
    """Accept the garment config (with a ``shrinkwrap`` node) or the shrinkwrap node itself."""
    return cfg["shrinkwrap"] if "shrinkwrap" in cfg else cfg


# --------------------------------------------------------------------------------------------------
# garment-side helpers


def vertex_parts(cage, num_vertices: int, wrapped: np.ndarray | None = None, body: Body | None = None) -> np.ndarray:
    """(V,) primary collision part per vertex (appendix D.6): 0 torso, 1 left arm, 2 right arm.

    Sleeve patches (``*sleeve_left*`` / ``*sleeve_right*``) collide with their arm. With the wrapped rest
    positions (V, 3) and the body, torso-panel vertices lying beyond an arm joint (|x| past the ``l_arm``
    / ``r_arm`` head) collide with that arm too: they cover the upper arm, and a torso-only collider would
    let them sink into it once the arm moves.
    """
    part = np.zeros(num_vertices, np.int64)
    for p in cage.patches:
        if "sleeve_left" in p.name:
            part[p.vertices] = 1
        elif "sleeve_right" in p.name:
            part[p.vertices] = 2
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

    def sdf(self, points: np.ndarray, part: int | None = None) -> np.ndarray:
        with torch.no_grad():
            p = torch.as_tensor(points, dtype=torch.float32)[None]
            return body_sdf(self.body, self.rot, p, part=part)[0].double().numpy()

    def closest(self, points: np.ndarray, allowed: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """Closest mesh point (N, 3) and its triangle (N,) among ``k`` nearest-centroid candidates
        (of the ``allowed`` triangle ids if given)."""
        pts = np.asarray(points, np.float64)
        if allowed is None:
            tree, ids, k = self.tree, None, self.k
        else:
            tree, ids, k = cKDTree(self.tris[allowed].mean(axis=1)), allowed, min(self.k, len(allowed))
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
# the shrink-wrap


def relax_on_surface(garment: Garment, x: np.ndarray, surface: _RestSurface, iterations: int, step: float,
                     tol: float) -> tuple[np.ndarray, int]:
    """Edge-length-equalising relaxation constrained to the body surface (appendix D.5).

    Per step: alpha_v = mean over incident edges of l_e / rest_e; edge (a, b) targets
    0.5 (alpha_a + alpha_b) rest_e; each vertex moves by ``step`` x the mean of its springs' position
    corrections, then is projected back onto the surface. x (V, 3) -> (V, 3), steps taken.
    """
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
        ratio = length / rest
        alpha = (np.bincount(a, ratio, n) + np.bincount(b, ratio, n)) / deg
        target = 0.5 * (alpha[a] + alpha[b]) * rest
        # each endpoint takes half of the length error along the edge
        c = (0.5 * (length - target) / np.maximum(length, 1e-12))[:, None] * e
        move = np.zeros_like(x)
        for k in range(3):
            move[:, k] = np.bincount(a, c[:, k], n) - np.bincount(b, c[:, k], n)
        new = surface.project(x + step * move / deg[:, None])
        delta = np.abs(new - x).max()
        x = new
        if delta < tol:
            break
    return x, steps


def wrap_positions(garment: Garment, cage, body: Body, cfg) -> tuple[np.ndarray, dict]:
    """Steps (a)-(c): the garment shrink-wrapped onto the rest body, (V, 3) float64, and stats."""
    sw = _sw_cfg(cfg)
    t0 = time.perf_counter()
    surface = _RestSurface(body, int(sw.nearest_triangles))
    part = vertex_parts(cage, garment.num_vertices)  # rays start from the bone under each patch
    x0 = garment.vertices.double().cpu().numpy()
    faces = garment.faces.cpu().numpy()
    face_chart = face_charts(garment)
    chart_names = chart_names_from_cage(cage, face_chart, faces)
    # the checks before any drape (pbc.geometry.garment.checks): each names the part, the number and the fix, where a
    # drape would only say minutes later that every sample was discarded
    far = sw.get("max_start_distance")
    if far is not None:
        check_far(surface.sdf(x0), x0, faces, body, float(far), chart_names, face_chart)
    max_angle = sw.get("max_sleeve_angle_deg")
    sleeves = (sleeve_axes(x0, faces, body) if max_angle is None
               else check_sleeves(x0, faces, body, float(max_angle)))
    # (a) cage-guided Laplace morph of the displacements
    ids, targets = cage_targets(garment, cage, body, surface, part, int(sw.ray_bisection_steps))
    lap = pattern_laplacian(garment)
    disp = solve_dirichlet(-lap, np.zeros_like(x0), ids, targets - x0[ids])
    x = x0 + disp
    morph_inside = int((surface.sdf(x) < 0).sum())
    # (b) push out and settle every vertex on the surface (the wrap is skin tight)
    x = surface.project(x)
    before = area_ratio(garment, x)
    # (c) relaxation on the surface
    x, iters = relax_on_surface(garment, x, surface, int(sw.relax_iterations), float(sw.relax_step),
                                float(sw.relax_tol))
    after = area_ratio(garment, x)
    pattern = garment.pattern().double().cpu().numpy().reshape(-1, 2)
    stretch = patch_stretch(face_areas(x, faces), face_areas(pattern, np.arange(len(pattern)).reshape(-1, 3)),
                            face_patches(cage, faces), len(cage.patches))
    stats = {"cage_vertices": int(len(ids)), "morph_inside": morph_inside, "relax_iterations": int(iters),
             "max_abs_sdf": float(np.abs(surface.sdf(x)).max())}
    stats.update(_ratio_stats(before, "area_before"))
    stats.update(_ratio_stats(after, "area_after"))
    worst = int(stretch.argmax())
    stats.update(patch_stretch_max=float(stretch[worst]), patch_stretch_worst=cage.patches[worst].name)
    stats.update({f"sleeve_{side}_angle_deg": a["angle_deg"] for side, a in sleeves.items()})
    limit = sw.get("max_patch_stretch")
    if limit is not None:
        fp = face_patches(cage, faces)
        patch_chart = [chart_names[int(np.bincount(face_chart[fp == p.id]).argmax())] if (fp == p.id).any() else "?"
                       for p in cage.patches]
        check_stretch(stretch, [p.name for p in cage.patches], patch_chart, float(limit), sleeves)
    stats["wrap_seconds"] = time.perf_counter() - t0
    return x, stats


def embed_points(points: np.ndarray, body: Body, part: np.ndarray, candidates: int) -> Embedding:
    """(d) Closest rest-body-mesh triangle and barycentric weights of points (V, 3); part (V,) is stored
    as the primary collision part. ``candidates`` nearest triangle centroids are tested exactly."""
    surface = _RestSurface(body, candidates)
    cpt, face = surface.closest(np.asarray(points, np.float64))
    w = trimesh.triangles.points_to_barycentric(surface.tris[face], cpt)
    w = np.clip(w, 0.0, None)  # the closest point is on the triangle: only round-off is negative
    w /= w.sum(1, keepdims=True)
    return Embedding(face=torch.tensor(face), bary=torch.tensor(w, dtype=torch.float32),
                     part=torch.tensor(part, dtype=torch.long))


def shrinkwrap(garment: Garment, cage, body: Body, cfg) -> tuple[Embedding, dict]:
    """Shrink-wrap the garment onto the rest body and embed it (appendix D.5).

    cfg: the garment config (its ``shrinkwrap`` node is used) or that node itself. Returns the
    Embedding (V,) and stats: area distortion (wrapped area / pattern area per face) mean/min/max/std
    before and after the relaxation, iterations, max |sdf| of the wrap, embedding error, seconds.
    """
    t0 = time.perf_counter()
    x, stats = wrap_positions(garment, cage, body, cfg)
    # a garment that covers no arm (the skirt, the trousers: garment.shrinkwrap.arm_parts false) collides
    # with the torso part only, though its hips reach past the arm joints' x
    arms = bool(_sw_cfg(cfg).get("arm_parts", True))
    part = vertex_parts(cage, garment.num_vertices, x if arms else None, body if arms else None)
    emb = embed_points(x, body, part, int(_sw_cfg(cfg).nearest_triangles))
    rest = embedded_points(body.vertices[None].double(), body.faces, emb)[0].numpy()
    stats["embed_max_distance"] = float(np.linalg.norm(rest - x, axis=1).max())
    stats["seconds"] = time.perf_counter() - t0
    return emb, stats


def embedded_points(body_vertices: Tensor, body_faces: Tensor, emb: Embedding) -> Tensor:
    """Garment points carried by the body: (B, Vb, 3) body vertices -> (B, V, 3); differentiable."""
    tri = body_vertices[:, body_faces[emb.face.to(body_faces.device)]]  # (B, V, 3, 3)
    w = emb.bary.to(device=body_vertices.device, dtype=body_vertices.dtype)
    return (tri * w[None, :, :, None]).sum(dim=2)
