"""Sewing-pattern helpers the procedural garments share: triangles of a grid of cells, a two-panel (front /
back) UV layout, and the rule that picks the UV corner each vertex is sampled at."""

from __future__ import annotations

import numpy as np


def cell_triangles(mask: np.ndarray, vid: np.ndarray) -> np.ndarray:
    """Two triangles per kept cell, CCW in the pattern frame (X right, Y up); diagonals alternate so
    the grid has no preferred shear direction. vid (rows+1, cols+1) maps grid points to vertex ids."""
    tris = []
    for r, c in zip(*np.nonzero(mask), strict=True):
        tl, tr, bl, br = vid[r, c], vid[r, c + 1], vid[r + 1, c], vid[r + 1, c + 1]
        # Y points up while rows go down: (bl, br, tr) is CCW in (X, Y)
        if (r + c) % 2 == 0:
            tris += [(bl, br, tr), (bl, tr, tl)]
        else:
            tris += [(bl, br, tl), (br, tr, tl)]
    return np.asarray(tris, dtype=np.int64)


def two_panel_uv(faces_f: np.ndarray, faces_b: np.ndarray, uv_f: np.ndarray, uv_b: np.ndarray):
    """The UV layout of a garment sewn from a front and a back panel: faces_f (Ff, 3), faces_b (Fb, 3) vertex
    ids, uv_f / uv_b (V, 2) every vertex's UV on each panel. A seam vertex gets one texture coordinate per
    panel. -> uv (T, 2) (front panel's first), face_uv (Ff + Fb, 3), vertex_uv (V, 2) and vertex_side (V,)
    (0 front, the front's UV for seam vertices; 1 back)."""
    nv = len(uv_f)
    on_front = np.zeros(nv, bool)
    on_front[np.unique(faces_f)] = True
    on_back = np.zeros(nv, bool)
    on_back[np.unique(faces_b)] = True
    front_tex = -np.ones(nv, np.int64)
    front_tex[on_front] = np.arange(on_front.sum())
    back_tex = -np.ones(nv, np.int64)
    back_tex[on_back] = on_front.sum() + np.arange(on_back.sum())
    uv = np.concatenate([uv_f[on_front], uv_b[on_back]])
    face_uv = np.concatenate([front_tex[faces_f], back_tex[faces_b]])
    return uv, face_uv, np.where(on_front[:, None], uv_f, uv_b), np.where(on_front, 0, 1)


def sample_corners(faces: np.ndarray, face_uv: np.ndarray, face_side: np.ndarray, face_chart: np.ndarray,
                   vertex_side: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Which uv each vertex is sampled at, by one rule that survives an OBJ round trip:
    the vertex's side (given, else its lowest), then its chart there that comes first, then the first
    corner of that chart in face order. faces / face_uv (F, 3), face_side / face_chart (F,).
    Returns vertex_tex (V,) indices into uv and vertex_side (V,).
    """
    v = faces.ravel()
    nv = int(v.max()) + 1
    side = np.repeat(face_side, 3)
    chart = np.repeat(face_chart, 3)
    if vertex_side is None:
        vertex_side = np.full(nv, np.iinfo(np.int64).max)
        np.minimum.at(vertex_side, v, side)
    ok = side == vertex_side[v]
    idx = np.flatnonzero(ok)
    order = idx[np.lexsort((idx, chart[idx], v[idx]))]
    first = order[np.r_[True, v[order][1:] != v[order][:-1]]]
    if len(first) != nv:
        missing = np.setdiff1d(np.arange(nv), v[first])
        raise ValueError(f"vertices {missing[:5].tolist()} have no face on their vertex_side chart")
    vertex_tex = np.empty(nv, np.int64)
    vertex_tex[v[first]] = face_uv.ravel()[first]
    return vertex_tex, np.asarray(vertex_side, np.int64)
