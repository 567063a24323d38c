"""An automatic cage: cut every UV chart of a garment into patches whose crops fit (paper Sec. 4.1).

One job: given a garment and its charts, produce a :class:`~pbc.geometry.cage.base.Cage` that
``validate_cage`` accepts, in the same JSON format as ``patches/`` so a person can edit it.

How: per image side and per chart (a connected UV island), the chart's vertices are split
recursively. A piece whose pixel box plus the margin fits the crop at the reference resolution is a
patch; otherwise it is cut across its longer pixel axis into the fewest equal slabs that can fit,
and every slab is split again into its connected pieces (so cuts follow the chart's boundary: a slab
that crosses both sleeves of a shirt becomes two patches, not one box spanning the body). Pieces of
fewer than ``min_vertices`` vertices are merged into the neighbouring patch they share most edges
with when the merged box still fits. The number of patches follows from the garment.

Curves (guides for the shrink-wrap): the openings (boundary loops), the seams between charts and the
cuts between neighbouring patches.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pbc.geometry.cage.base import Cage, Patch, uv_box, validate_cage
from pbc.geometry.meshio import SIDE_NAMES
from pbc.geometry.meshops import boundary_loops, face_charts


def vertex_charts(garment, face_chart: np.ndarray) -> np.ndarray:
    """(V,) the chart each vertex is sampled from: a chart of a face on the vertex's side whose corner
    uv equals the vertex's vertex_uv (where several match, the lowest chart id)."""
    f = garment.faces.cpu().numpy()
    fuv = garment.face_uv.cpu().numpy()
    uv = garment.uv.double().cpu().numpy()
    vuv = garment.vertex_uv.double().cpu().numpy()
    vside = garment.vertex_side.cpu().numpy()
    fside = garment.face_side.cpu().numpy()
    v, t = f.ravel(), fuv.ravel()
    fc = np.repeat(face_chart, 3)
    match = (np.repeat(fside, 3) == vside[v]) & (np.abs(uv[t] - vuv[v]).max(1) < 1e-6)
    out = np.full(garment.num_vertices, np.iinfo(np.int64).max)
    np.minimum.at(out, v[match], fc[match])
    missing = np.flatnonzero(out == np.iinfo(np.int64).max)
    if len(missing):
        raise ValueError(f"autocage: vertices {missing[:5].tolist()} have a vertex_uv that no face of their "
                         "side uses; the garment's vertex_uv/vertex_side are inconsistent")
    return out


def _edges(garment) -> np.ndarray:
    f = garment.faces.cpu().numpy()
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def _components(ids: np.ndarray, edges: np.ndarray, nv: int) -> list[np.ndarray]:
    """Connected pieces of the vertex set ids (n,) through the mesh edges (E, 2) among them."""
    inside = np.zeros(nv, bool)
    inside[ids] = True
    e = edges[inside[edges[:, 0]] & inside[edges[:, 1]]]
    local = -np.ones(nv, np.int64)
    local[ids] = np.arange(len(ids))
    adj = sp.coo_matrix((np.ones(len(e)), (local[e[:, 0]], local[e[:, 1]])), shape=(len(ids), len(ids)))
    n, lab = connected_components(adj, directed=False)
    return [ids[lab == k] for k in range(n)]


def _fits(box, limit: int) -> bool:
    r0, c0, r1, c1 = box
    return r1 - r0 <= limit and c1 - c0 <= limit


def split_chart(ids: np.ndarray, px: np.ndarray, edges: np.ndarray, nv: int, limit: int,
                resolution: int, max_depth: int = 32) -> list[np.ndarray]:
    """Recursive split of one connected vertex set into pieces whose pixel box is <= limit a side.

    ids (n,) vertex ids, px (V, 2) their (col, row) pixel coordinates = vertex_uv * resolution.
    """
    box = uv_box(px[ids] / resolution, resolution)
    if _fits(box, limit) or len(ids) == 1:
        return [ids]
    if max_depth == 0:
        raise ValueError("autocage: the recursive split did not converge")
    r0, c0, r1, c1 = box
    axis = 0 if (c1 - c0) >= (r1 - r0) else 1  # 0: cut across columns (u), 1: across rows (v)
    x = px[ids, axis]
    lo, extent = float(x.min()), float(x.max() - x.min())
    # a box covers floor(hi) - floor(lo) + 1 <= extent + 2 pixels: slabs of limit - 2 always fit
    n = max(2, math.ceil(extent / max(limit - 2, 1)))
    slab = np.minimum(((x - lo) / (extent / n)).astype(np.int64), n - 1)
    out = []
    for k in range(n):
        part = ids[slab == k]
        if len(part) == 0:
            continue
        for comp in _components(part, edges, nv):
            out += split_chart(comp, px, edges, nv, limit, resolution, max_depth - 1)
    return out


def _merge_small(pieces: list[np.ndarray], px: np.ndarray, edges: np.ndarray, nv: int, limit: int,
                 resolution: int, min_vertices: int, min_side: int) -> list[np.ndarray]:
    """Merge pieces of fewer than min_vertices, or whose box is thinner than min_side px (slivers
    left where a slab boundary meets the chart's edge), into the neighbour they share most edges
    with, when the merged box still fits."""

    def small(p):
        r0, c0, r1, c1 = uv_box(px[p] / resolution, resolution)
        return len(p) < min_vertices or min(r1 - r0, c1 - c0) < min_side

    pieces = [p for p in pieces]
    changed = True
    while changed:
        changed = False
        owner = -np.ones(nv, np.int64)
        for k, p in enumerate(pieces):
            owner[p] = k
        for k in sorted(range(len(pieces)), key=lambda i: len(pieces[i])):
            if not small(pieces[k]):
                continue
            a, b = owner[edges[:, 0]], owner[edges[:, 1]]
            nb = np.concatenate([b[(a == k) & (b >= 0) & (b != k)], a[(b == k) & (a >= 0) & (a != k)]])
            for j in np.bincount(nb).argsort()[::-1] if len(nb) else []:
                if j == k or not np.any(nb == j):
                    continue
                merged = np.concatenate([pieces[j], pieces[k]])
                if _fits(uv_box(px[merged] / resolution, resolution), limit):
                    pieces[j] = np.sort(merged)
                    pieces.pop(k)
                    changed = True
                    break
            if changed:
                break
    return pieces


def _order_curve(ids: np.ndarray, edges: np.ndarray, nv: int) -> list[np.ndarray]:
    """Split a vertex set into its connected pieces, each walked depth first from an end point."""
    out = []
    for comp in _components(np.unique(ids), edges, nv):
        inside = np.zeros(nv, bool)
        inside[comp] = True
        e = edges[inside[edges[:, 0]] & inside[edges[:, 1]]]
        nbrs: dict[int, list[int]] = {int(v): [] for v in comp}
        for a, b in e.tolist():
            nbrs[a].append(b)
            nbrs[b].append(a)
        start = min(nbrs, key=lambda v: (len(nbrs[v]), v))
        seen, stack, walk = set(), [start], []
        while stack:
            v = stack.pop()
            if v in seen:
                continue
            seen.add(v)
            walk.append(v)
            stack += sorted((w for w in nbrs[v] if w not in seen), reverse=True)
        out.append(np.asarray(walk, np.int64))
    return out


def auto_cage(garment, resolution: int, crop_size: int, margin: int, chart_names: list[str] | None = None,
              face_chart: np.ndarray | None = None, min_vertices: int = 4, min_side: int | None = None,
              max_patches: int | None = None) -> Cage:
    """The automatic cage of a garment (see the module docstring), validated.

    resolution: the reference (patch) resolution the boxes are at; crop_size / margin: pixels at it.
    chart_names (C,) / face_chart (F,): the charts (default: UV islands of each side, named
    ``front``/``back`` when a side has one chart, else ``front_0``, ``front_1``, ...).
    min_vertices / min_side: smaller pieces (vertex count; box side in px, default a quarter of the
    largest box side that fits) are merged into a neighbour where the merged box fits.
    Raises ValueError naming the chart that cannot be covered (it comes within the margin of the
    image edge, or needs more than max_patches patches).
    """
    limit = int(crop_size) - 2 * int(margin)
    if limit < 1:
        raise ValueError(f"autocage: a crop of {crop_size} px cannot hold a {margin} px margin on both sides; "
                         "raise image.crop_size or lower image.margin")
    if face_chart is None:
        face_chart = face_charts(garment)
    face_chart = np.asarray(face_chart, np.int64)
    fside = garment.face_side.cpu().numpy()
    nchart = int(face_chart.max()) + 1
    chart_side = np.zeros(nchart, np.int64)
    chart_side[face_chart] = fside
    if chart_names is None:
        chart_names = []
        for c in range(nchart):
            same = np.flatnonzero(chart_side == chart_side[c])
            base = SIDE_NAMES[chart_side[c]] if chart_side[c] < len(SIDE_NAMES) else f"side{chart_side[c]}"
            chart_names.append(base if len(same) == 1 else f"{base}_{int(np.searchsorted(same, c))}")
    nv = garment.num_vertices
    vchart = vertex_charts(garment, face_chart)
    px = garment.vertex_uv.double().cpu().numpy() * resolution
    edges = _edges(garment)
    patches: list[Patch] = []
    for side in np.unique(chart_side):
        for c in np.flatnonzero(chart_side == side):
            ids = np.flatnonzero(vchart == c)
            if len(ids) == 0:
                continue  # every vertex of this chart is sampled from another one (a seam strip)
            name = chart_names[c]
            r0, c0, r1, c1 = uv_box(px[ids] / resolution, resolution)
            if r0 - margin < 0 or c0 - margin < 0 or r1 + margin > resolution or c1 + margin > resolution:
                raise ValueError(f"autocage: chart '{name}' (side {side}) reaches within the {margin} px margin of "
                                 f"the {resolution} px image edge (box {(r0, c0, r1, c1)}), so no crop around its "
                                 "border patches fits in the image: leave more empty UV space at the borders "
                                 "(garment.uv_padding)")
            pieces = []
            for comp in _components(ids, edges, nv):
                pieces += split_chart(comp, px, edges, nv, limit, resolution)
            pieces = _merge_small(pieces, px, edges, nv, limit, resolution, min_vertices,
                                  limit // 4 if min_side is None else int(min_side))
            # row-major order of the patch boxes, for readable names
            centres = [px[p].mean(0) for p in pieces]
            order = sorted(range(len(pieces)), key=lambda k: (round(centres[k][1] / limit), centres[k][0]))
            for k, i in enumerate(order):
                ids_k = np.sort(pieces[i])
                patches.append(Patch(id=len(patches), name=f"{name}_{k:02d}", side=int(side), vertices=ids_k,
                                     box_512=uv_box(px[ids_k] / resolution, resolution)))
            if max_patches is not None and len(patches) > max_patches:
                raise ValueError(f"autocage: chart '{name}' brings the cage past garment.autocage.max_patches = "
                                 f"{max_patches} patches (a patch per chart at least, more where a chart is larger "
                                 f"than a {crop_size} px crop at {resolution}): raise it "
                                 f"(garment.autocage.max_patches={2 * max_patches}), or give the garment fewer, "
                                 "smaller charts (its own UVs, or garment.unwrap.max_cost higher: xatlas merges more)")
    curves: dict[str, np.ndarray] = {}
    for k, loop in enumerate(boundary_loops(garment.faces.cpu().numpy())):
        curves[f"opening_{k}"] = loop
    # seams: vertices whose faces lie in more than one chart; cuts: vertices with a neighbour in another patch
    f = garment.faces.cpu().numpy()
    vmin = np.full(nv, nchart)
    vmax = -np.ones(nv, np.int64)
    np.minimum.at(vmin, f.ravel(), np.repeat(face_chart, 3))
    np.maximum.at(vmax, f.ravel(), np.repeat(face_chart, 3))
    for k, walk in enumerate(_order_curve(np.flatnonzero(vmin != vmax), edges, nv)):
        curves[f"seam_{k}"] = walk
    owner = Cage(curves={}, patches=patches).vertex_patch(nv)
    a, b = owner[edges[:, 0]], owner[edges[:, 1]]
    cut = np.unique(edges[a != b].ravel())
    cut = cut[vmin[cut] == vmax[cut]]  # seam vertices are already curves
    for k, walk in enumerate(_order_curve(cut, edges, nv)):
        curves[f"cut_{k}"] = walk
    cage = Cage(curves=curves, patches=patches, resolution=int(resolution))
    validate_cage(cage, garment, int(resolution), int(crop_size), int(margin))
    return cage


def cage_summary(cage: Cage) -> dict:
    """Patch count per side and box sizes (px): for comparing two cages of one garment."""
    h = np.array([p.box_512[2] - p.box_512[0] for p in cage.patches])
    w = np.array([p.box_512[3] - p.box_512[1] for p in cage.patches])
    n = np.array([len(p.vertices) for p in cage.patches])
    sides = [p.side for p in cage.patches]
    return {"patches": len(cage.patches), "per_side": {int(s): sides.count(s) for s in sorted(set(sides))},
            "box_h_mean": float(h.mean()), "box_w_mean": float(w.mean()), "box_max": int(max(h.max(), w.max())),
            "box_area_mean": float((h * w).mean()), "vertices_min": int(n.min()), "vertices_max": int(n.max()),
            "vertices_mean": float(n.mean())}
