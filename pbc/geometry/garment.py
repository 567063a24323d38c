"""The garment mesh: a procedural T-shirt (flat pattern, UV charts, sewn 3D rest shape) and its OBJ I/O.

One job: produce and store the garment as data. The T-shirt is a front and a back panel cut from the
same regular grid (a "kimono" T shape: torso plus horizontal sleeves for the T-pose), sewn into one
manifold mesh along the shoulder/sleeve-top, underarm and side seams. Each panel is one UV chart,
scaled uniformly so that ``uv * uv_scale`` is the flat pattern in metres (the cloth's rest shape).

Pattern frame: X to the body's left (= root x), Y up, origin at the top centre (neck) of the T.
Front chart u grows with X (seen from the front), back chart u grows with -X (seen from behind), so
both charts are seen from outside the garment and have the same winding as the outward 3D normal.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from omegaconf import OmegaConf
from scipy.sparse.csgraph import connected_components
from torch import Tensor

from pbc.geometry.cage import Cage, load_cage, save_cage, tshirt_cage, validate_cage
from pbc.geometry.meshio import obj_text
from pbc.io import write_text
from pbc.paths import resolve_path

# The repository root: relative cage paths in the garment config are resolved against it when they do
# not exist relative to the working directory (Hydra runs keep the cwd, tests may not).


@dataclass
class Garment:
    """A garment mesh with two UV charts (see docs/interfaces.md)."""

    vertices: Tensor  # (V, 3) sewn rest shape in 3D (T-pose frame)
    faces: Tensor  # (F, 3) long
    uv: Tensor  # (T, 2) in [0, 1]^2 of their chart; u -> column, v -> row (v = 0 top)
    face_uv: Tensor  # (F, 3) long, indices into uv per face corner
    face_side: Tensor  # (F,) long, 0 front, 1 back
    vertex_uv: Tensor  # (V, 2)
    vertex_side: Tensor  # (V,) long, front for seam vertices
    uv_scale: float  # metres per uv unit

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def pattern(self) -> Tensor:
        """Flat pattern corner positions (F, 3, 2) in metres: the cloth's rest shape."""
        return self.uv[self.face_uv] * self.uv_scale


@dataclass
class TShirtLayout:
    """Grid bookkeeping of the procedural T-shirt, used to lay out its cage.

    All arrays are per garment vertex (V,): ``gi``/``gj`` integer grid column/row (j = 0 at the top,
    growing downwards; i = 0 on the centre line, positive to the body's left), ``side`` 0 front /
    1 back / 2 seam (shared); the integers give the pattern's landmarks in grid cells.
    """

    gi: np.ndarray
    gj: np.ndarray
    side: np.ndarray
    half_torso: int  # torso half width in cells (side seam at |i| = half_torso)
    sleeve_cells: int  # sleeve length in cells
    sleeve_height: int  # sleeve opening height in cells (underarm at j = sleeve_height)
    torso_rows: int  # torso length in cells (hem at j = torso_rows)
    spacing: float


# --------------------------------------------------------------------------------------------------
# small geometry helpers (numpy, shared with shrinkwrap)


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


# --------------------------------------------------------------------------------------------------
# the procedural T-shirt


def _panel_cells(cfg, spacing: float, neck_depth: float) -> tuple[np.ndarray, dict]:
    """Boolean cell mask (rows, cols) of one panel and the grid landmarks.

    Columns are indexed c = i + (half_torso + sleeve_cells), i the signed grid column.
    """
    half_torso = int(round((0.5 * float(cfg.chest_girth) + float(cfg.chest_ease)) / 2.0 / spacing))
    sleeve_cells = int(round(float(cfg.sleeve_length) / spacing))
    sleeve_height = int(round(float(cfg.sleeve_opening) / spacing))
    torso_rows = int(round(float(cfg.torso_length) / spacing))
    off = half_torso + sleeve_cells
    cols = np.arange(-off, off)
    rows = np.arange(torso_rows)
    ii, jj = np.meshgrid(cols, rows)  # (rows, cols)
    torso = (ii >= -half_torso) & (ii < half_torso)
    sleeve = jj < sleeve_height
    mask = torso | sleeve
    # neck hole: an ellipse centred on the top middle, deeper on the front; cells whose centre is inside
    cx, cy = (ii + 0.5) * spacing, (jj + 0.5) * spacing
    neck_hw = 0.5 * float(cfg.neck_width)
    mask &= (cx / neck_hw) ** 2 + (cy / max(neck_depth, 1e-9)) ** 2 > 1.0
    land = dict(half_torso=half_torso, sleeve_cells=sleeve_cells, sleeve_height=sleeve_height,
                torso_rows=torso_rows, off=off)
    return mask, land


def _cell_triangles(mask: np.ndarray, vid: np.ndarray) -> np.ndarray:
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


def _snap_neck(points: np.ndarray, faces: np.ndarray, verts: np.ndarray, neck_hw: float, depth: float,
               min_area: float) -> None:
    """Move the neck-hole boundary vertices (verts) onto the neck ellipse, in place, unless that would
    make an incident triangle smaller than min_area (the stair-stepped grid then stays)."""
    for v in verts:
        x, y = points[v]
        s = np.sqrt((x / neck_hw) ** 2 + (y / depth) ** 2)
        if s <= 0:
            continue
        old = points[v].copy()
        points[v] = old / s
        inc = faces[(faces == v).any(axis=1)]
        p = points[inc]
        area = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                      - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
        if (area < min_area).any():
            points[v] = old


def _boundary_vertices(mask: np.ndarray, keep_pts: np.ndarray) -> np.ndarray:
    """Grid points (rows+1, cols+1) bool that are corners of both a kept and a dropped/outside cell."""
    pad = np.pad(mask, 1, constant_values=False)
    kept_any = pad[:-1, :-1] | pad[:-1, 1:] | pad[1:, :-1] | pad[1:, 1:]
    drop_any = ~(pad[:-1, :-1] & pad[:-1, 1:] & pad[1:, :-1] & pad[1:, 1:])
    return kept_any & drop_any & keep_pts


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


def build_tshirt_mesh(cfg) -> tuple[Garment, TShirtLayout]:
    """The sewn two-panel T-shirt mesh, its UVs and 3D pillow rest shape, plus its grid layout.

    cfg: the garment config node (see conf/garment/tshirt.yaml).
    """
    h = float(cfg.grid_spacing)
    front_mask, land = _panel_cells(cfg, h, float(cfg.neck_depth_front))
    back_mask, _ = _panel_cells(cfg, h, float(cfg.neck_depth_back))
    nrow, ncol = front_mask.shape
    off, ht, sh, tr = land["off"], land["half_torso"], land["sleeve_height"], land["torso_rows"]

    def used(mask):
        pad = np.pad(mask, 1, constant_values=False)
        return pad[:-1, :-1] | pad[:-1, 1:] | pad[1:, :-1] | pad[1:, 1:]

    # Seam edges: grid edges on the outline that both panels keep and that are not openings.
    jj, ii = np.meshgrid(np.arange(nrow + 1), np.arange(ncol + 1) - off, indexing="ij")
    both = used(front_mask) & used(back_mask)
    top_seam = np.zeros_like(both)
    # the top (shoulder + sleeve top) seam: j = 0 points touching a cell kept in both panels
    kept_both_top = front_mask[0] & back_mask[0]
    top_seam[0, :-1] |= kept_both_top
    top_seam[0, 1:] |= kept_both_top
    underarm = (jj == sh) & (np.abs(ii) >= ht) & (np.abs(ii) <= off)
    side = (np.abs(ii) == ht) & (jj >= sh) & (jj <= tr)
    seam = (top_seam | underarm | side) & both

    # vertex ids: front grid points first, then back-only points (seam points are shared)
    front_used, back_used = used(front_mask), used(back_mask)
    vid_f = -np.ones((nrow + 1, ncol + 1), dtype=np.int64)
    vid_f[front_used] = np.arange(front_used.sum())
    nv = int(front_used.sum())
    vid_b = -np.ones_like(vid_f)
    vid_b[seam] = vid_f[seam]
    back_only = back_used & ~seam
    vid_b[back_only] = nv + np.arange(back_only.sum())
    nv += int(back_only.sum())

    # pattern coordinates per panel (X right = body left, Y up) and grid ids per vertex
    px = ii * h
    py = -jj * h
    pat_f = np.zeros((nv, 2))
    pat_b = np.zeros((nv, 2))
    pat_f[vid_f[front_used]] = np.stack([px[front_used], py[front_used]], 1)
    pat_b[vid_b[back_used]] = np.stack([px[back_used], py[back_used]], 1)
    gi = np.zeros(nv, dtype=np.int64)
    gj = np.zeros(nv, dtype=np.int64)
    gi[vid_f[front_used]], gj[vid_f[front_used]] = ii[front_used], jj[front_used]
    gi[vid_b[back_only]], gj[vid_b[back_only]] = ii[back_only], jj[back_only]
    vside = np.zeros(nv, dtype=np.int64)
    vside[vid_b[back_only]] = 1
    vside[vid_f[seam]] = 2

    faces_f = _cell_triangles(front_mask, vid_f)
    faces_b = _cell_triangles(back_mask, vid_b)[:, ::-1].copy()  # back faces point to -z: flip winding

    # round the neck: snap neck-hole boundary points (not the j = 0 seam ends) onto the ellipse
    neck_hw = 0.5 * float(cfg.neck_width)
    min_area = float(cfg.neck_snap_min_area) * 0.5 * h * h
    for mask, vid, pat, faces, depth in ((front_mask, vid_f, pat_f, faces_f, cfg.neck_depth_front),
                                         (back_mask, vid_b, pat_b, faces_b[:, ::-1], cfg.neck_depth_back)):
        bnd = _boundary_vertices(mask, used(mask)) & (jj > 0) & (np.abs(ii) < ht) & (jj < sh)
        _snap_neck(pat, faces, vid[bnd], neck_hw, float(depth), min_area)
    seam_ids = np.nonzero(vside == 2)[0]
    pat_b[seam_ids] = pat_f[seam_ids]

    faces = np.concatenate([faces_f, faces_b])
    face_side = np.concatenate([np.zeros(len(faces_f), np.int64), np.ones(len(faces_b), np.int64)])

    # UV charts: one uniform scale for both so the pattern is uv * uv_scale; centre each chart
    xmin, xmax = -off * h, off * h
    ymin, ymax = -tr * h, 0.0
    pad = float(cfg.uv_padding)
    uv_scale = max(xmax - xmin, ymax - ymin) / (1.0 - 2.0 * pad)
    cxm, cym = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)

    def to_uv(p, mirror):
        u = 0.5 + (-1.0 if mirror else 1.0) * (p[:, 0] - cxm) / uv_scale
        v = 0.5 - (p[:, 1] - cym) / uv_scale
        return np.stack([u, v], 1)

    uv, face_uv, vertex_uv, vertex_side = two_panel_uv(faces_f, faces_b, to_uv(pat_f, False), to_uv(pat_b, True))
    on_front = vertex_side == 0

    # 3D rest shape: a pillow around the T-pose body. Per panel solve  lap(phi) = -1  with phi = 0 on
    # the seams; z = depth_ratio * sqrt(2 phi) is then an ellipse whose depth scales with the local
    # seam-to-seam width (deep over the torso, shallow over the sleeves).
    depth_ratio = float(cfg.pillow_depth_ratio)
    z = np.zeros(nv)
    for fcs, pat, sign in ((faces_f, pat_f, 1.0), (faces_b[:, ::-1], pat_b, -1.0)):
        verts = np.unique(fcs)
        local = -np.ones(nv, np.int64)
        local[verts] = np.arange(len(verts))
        lf = local[fcs]
        lap = cotan_laplacian(pat[verts], lf)
        mass = lumped_mass(pat[verts], lf)
        fixed = np.nonzero(vside[verts] == 2)[0]
        phi = solve_dirichlet(-lap, mass, fixed, np.zeros(len(fixed)))
        z[verts] = sign * depth_ratio * np.sqrt(np.maximum(2.0 * phi, 0.0))
    top_y = float(cfg.shoulder_height) + 0.5 * sh * h  # the sleeve is centred on the arm axis
    pos = np.zeros((nv, 3))
    pos[:, 0] = np.where(on_front, pat_f[:, 0], pat_b[:, 0])
    pos[:, 1] = top_y + np.where(on_front, pat_f[:, 1], pat_b[:, 1])
    pos[:, 2] = z + float(cfg.center_z)

    garment = Garment(
        vertices=torch.tensor(pos, dtype=torch.float32),
        faces=torch.tensor(faces, dtype=torch.long),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(face_uv, dtype=torch.long),
        face_side=torch.tensor(face_side, dtype=torch.long),
        vertex_uv=torch.tensor(vertex_uv, dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side, dtype=torch.long),
        uv_scale=float(uv_scale),
    )
    layout = TShirtLayout(gi=gi, gj=gj, side=vside, half_torso=ht, sleeve_cells=land["sleeve_cells"],
                          sleeve_height=sh, torso_rows=tr, spacing=h)
    return garment, layout


def make_tshirt(cfg, use_cage_file: bool = True) -> tuple[Garment, Cage]:
    """The procedural T-shirt and its cage.

    cfg: garment config node (tshirt.yaml). The cage is generated from cfg.cage_rows / cfg.cage_cols;
    if ``use_cage_file`` and cfg.cage names an existing JSON file, that (possibly hand-edited) file is
    read and validated instead, so the committed patches/ atlas is the source of truth.
    """
    garment, layout = build_tshirt_mesh(cfg)
    res, crop, margin = int(cfg.patch_resolution), int(cfg.crop_size), int(cfg.margin)
    cage_path = cfg.get("cage", None)
    if use_cage_file and cage_path and resolve_path(cage_path).exists():
        return garment, load_cage(resolve_path(cage_path), garment, res, crop, margin)
    cage = tshirt_cage(garment, layout, list(cfg.cage_rows), list(cfg.cage_cols), res)
    validate_cage(cage, garment, res, crop, margin)
    return garment, cage


def write_tshirt_cage(cfg) -> Path:
    """Regenerate the committed cage JSON of a procedural garment config; returns its path."""
    garment, cage = make_tshirt(cfg, use_cage_file=False)
    path = resolve_path(cfg.cage)
    save_cage(cage, path)
    return path


# --------------------------------------------------------------------------------------------------
# OBJ I/O (by hand: trimesh would split vertices at UV seams)

_SIDES = ("front", "back")


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


def save_garment_obj(garment: Garment, path) -> None:
    """Write the garment as OBJ: v, vt, `g front`/`g back` groups of `f v/vt`; uv_scale in a header
    comment, vertex_side in `# vs` comments. Floats are written with repr so a round trip is exact.
    The dataset's format (byte-stable across versions); meshes for viewers: pbc.geometry.meshio."""
    path = Path(path)
    v = garment.vertices.detach().cpu().double().numpy()
    uv = garment.uv.detach().cpu().double().numpy()
    f = garment.faces.cpu().numpy()
    fuv = garment.face_uv.cpu().numpy()
    side = garment.face_side.cpu().numpy()
    header = ["pbc garment", f"uv_scale {float(garment.uv_scale)!r}",
              "vertex_side " + " ".join(str(int(s)) for s in garment.vertex_side.cpu().numpy())]
    # float32 values are exactly representable as float64 reprs: the round trip is bit exact
    groups = [(name, side == s) for s, name in enumerate(_SIDES)]
    write_text(path, obj_text(v, f, uv, fuv, groups=groups, header=header, number=repr))


def _is_pbc_obj(path: Path) -> bool:
    """A file save_garment_obj wrote: its header states uv_scale, and its UVs are already pbc's."""
    try:
        with open(path) as fh:
            head = [fh.readline() for _ in range(3)]
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the garment OBJ ({exc})") from None
    return any(ln.split()[:2] == ["#", "uv_scale"] for ln in head)


def load_garment_obj(path) -> Garment:
    """Read a garment OBJ.

    A file save_garment_obj wrote (its `# uv_scale` header) is read exactly as written (`f v/vt`
    triangles, `g front` / `g back`); another tool's OBJ is refused with a pointer to
    pbc.geometry.garments.load_any_obj (the importer). Raises ValueError naming the file (and the line)
    if UVs are missing, faces reference missing vt, etc.
    """
    path = Path(path)
    if not _is_pbc_obj(path):
        raise ValueError(f"{path} is not a garment file pbc wrote (no '# uv_scale' header): import another "
                         "tool's OBJ with pbc.geometry.garments.load_any_obj, or from a config with "
                         "garment=obj garment.obj=<path>")
    verts, uvs, faces, fuvs, sides = [], [], [], [], []
    uv_scale = None
    vertex_side = None
    side = 0
    with open(path) as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            if key == "#" and len(parts) >= 3 and parts[1] == "uv_scale":
                uv_scale = float(parts[2])
            elif key == "#" and len(parts) >= 2 and parts[1] == "vertex_side":
                vertex_side = np.array([int(s) for s in parts[2:]], dtype=np.int64)
            elif key == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif key == "vt":
                uvs.append([float(x) for x in parts[1:3]])
            elif key == "g":
                name = parts[1] if len(parts) > 1 else ""
                if name not in _SIDES:
                    raise ValueError(f"{path}: line {lineno}: group {name!r} is not one of {_SIDES}")
                side = _SIDES.index(name)
            elif key == "f":
                if len(parts) != 4:
                    raise ValueError(f"{path}: line {lineno}: only triangles are supported")
                fv, ft = [], []
                for corner in parts[1:]:
                    idx = corner.split("/")
                    if len(idx) < 2 or not idx[1]:
                        raise ValueError(f"{path}: line {lineno}: face corner {corner!r} has no vt index "
                                         "(a garment OBJ needs UVs)")
                    fv.append(int(idx[0]) - 1)
                    ft.append(int(idx[1]) - 1)
                faces.append(fv)
                fuvs.append(ft)
                sides.append(side)
    if not uvs:
        raise ValueError(f"{path}: no texture coordinates (vt); a garment OBJ needs UVs")
    if not faces:
        raise ValueError(f"{path}: no faces")
    faces = np.asarray(faces, np.int64)
    fuvs = np.asarray(fuvs, np.int64)
    if faces.min() < 0 or faces.max() >= len(verts):
        raise ValueError(f"{path}: faces reference missing vertices (v has {len(verts)} entries)")
    if fuvs.min() < 0 or fuvs.max() >= len(uvs):
        raise ValueError(f"{path}: faces reference missing texture coordinates (vt has {len(uvs)} entries)")
    if uv_scale is None:
        raise ValueError(f"{path}: missing '# uv_scale <metres per uv unit>' header comment")
    uv = np.asarray(uvs, np.float64)
    sides = np.asarray(sides, np.int64)
    nv = len(verts)
    if vertex_side is None or len(vertex_side) != nv:
        vertex_side = None  # the lowest side each vertex appears on (front for seam vertices)
    # the corner each vertex is sampled at: the rule the importer and the necktie use, so that a vertex
    # with two uvs on one side (a seam between two charts of one image, or within one chart) reads back
    # at the uv it was made with
    chart = uv_islands(faces, uv[fuvs] + 2.0 * sides[:, None, None])
    vertex_tex, vertex_side = sample_corners(faces, fuvs, sides, chart, vertex_side)
    return Garment(
        vertices=torch.tensor(np.asarray(verts), dtype=torch.float32),
        faces=torch.tensor(faces),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(fuvs),
        face_side=torch.tensor(sides),
        vertex_uv=torch.tensor(uv[vertex_tex], dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side),
        uv_scale=float(uv_scale),
    )


def load_garment_config(garment_yaml, image_yaml=None):
    """The garment config node from its YAML file, its ``${image.*}`` keys filled from the image config
    (default: conf/image/default.yaml next to it). For scripts and tests outside a Hydra run."""
    garment_yaml = resolve_path(garment_yaml)
    if image_yaml is None:
        image_yaml = garment_yaml.parents[1] / "image" / "default.yaml"
    image_yaml = resolve_path(image_yaml)
    root = OmegaConf.create({"garment": _load_with_defaults(garment_yaml), "image": OmegaConf.load(image_yaml)})
    return root.garment


def _load_with_defaults(path):
    """A config file merged over the sibling files its ``defaults:`` list names (as Hydra composes a group
    option that inherits from another, e.g. tshirt_coarse.yaml over tshirt.yaml)."""
    node = OmegaConf.load(path)
    defaults = list(node.pop("defaults", None) or [])
    if "_self_" not in defaults:
        defaults.append("_self_")
    parts = [node if d == "_self_" else _load_with_defaults(Path(path).parent / f"{d}.yaml") for d in defaults]
    return OmegaConf.merge(*parts)

