"""The paper's T-shirt: a front and a back panel sewn at the sides and shoulders, with sleeves and a neck
hole, laid out as two UV charts (``build_tshirt_mesh``), and its hand-made cage of seams and body loops that
cuts it into 28 patches (``tshirt_cage``; ``patches/tshirt_cage.json`` is its file)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pbc.core.paths import resolve_path
from pbc.geometry.cage.base import Cage, Patch, load_cage, save_cage, uv_box, validate_cage
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.patterns import cell_triangles, two_panel_uv
from pbc.geometry.meshio import SIDE_NAMES
from pbc.geometry.meshops import boundary_loops, cotan_laplacian, lumped_mass, solve_dirichlet


def tshirt_cage(garment, layout, row_fractions: list[float], col_fractions: list[float],
                resolution: int) -> Cage:
    """Cage of the procedural T-shirt: per side 2 sleeves + a torso grid.

    Rows: the underarm line plus horizontal loops at ``row_fractions`` of the way from the underarm to
    the hem (2 fractions -> 4 rows: shoulder, chest, waist, hip). Columns: vertical lines at
    ``col_fractions`` of the torso half width either side of the centre (1 fraction -> right, centre,
    left columns; names use the body's left/right). Patch ids: front 0..13 then back 14..27.
    layout: the TShirtLayout of build_tshirt_mesh. Boxes use the vertex_uv of each vertex at resolution.
    """
    gi, gj, vside = layout.gi, layout.gj, layout.side
    ht, sh, tr = layout.half_torso, layout.sleeve_height, layout.torso_rows
    off = ht + layout.sleeve_cells
    row_lines = [sh] + [sh + int(round(f * (tr - sh))) for f in row_fractions]
    col_lines = sorted({int(round(f * ht)) for f in col_fractions})
    row_names = ["shoulder", "chest", "waist", "hip"]
    if len(row_lines) != 3:
        row_names = [f"row{r}" for r in range(len(row_lines) + 1)]
    col_names = ["right", "center", "left"]
    if len(col_lines) != 1:
        col_names = [f"col{c}" for c in range(2 * len(col_lines) + 1)]
    # signed column boundaries (right of the body = negative X); a vertex on a line goes to the centre side
    bounds = sorted([-c for c in col_lines] + col_lines)
    vuv = garment.vertex_uv.detach().cpu().numpy()

    side = np.where(vside == 2, 0, vside)  # seam vertices belong to the front patch
    sleeve = np.abs(gi) > ht
    row = np.searchsorted(np.asarray(row_lines), gj, side="right")
    # columns: count the boundaries strictly left of the vertex on its side of the centre
    col = np.where(gi < 0, np.searchsorted(np.asarray(bounds), gi, side="right"),
                   np.searchsorted(np.asarray(bounds), gi, side="left"))
    patches: list[Patch] = []
    for s, sname in enumerate(SIDE_NAMES):
        groups = [(f"{sname}_sleeve_right", (side == s) & sleeve & (gi < 0)),
                  (f"{sname}_sleeve_left", (side == s) & sleeve & (gi > 0))]
        for r, rname in enumerate(row_names):
            for c, cname in enumerate(col_names):
                groups.append((f"{sname}_{rname}_{cname}", (side == s) & ~sleeve & (row == r) & (col == c)))
        for name, sel in groups:
            ids = np.nonzero(sel)[0]
            patches.append(Patch(id=len(patches), name=name, side=s, vertices=ids,
                                 box_512=uv_box(vuv[ids], resolution) if len(ids) else (0, 0, 0, 0)))

    curves: dict[str, np.ndarray] = {}

    def line(sel, key):
        ids = np.nonzero(sel)[0]
        return ids[np.argsort(key[ids], kind="stable")]

    for sgn, lr in ((1, "left"), (-1, "right")):
        curves[f"seam_shoulder_{lr}"] = line((gj == 0) & (vside == 2) & (sgn * gi > 0), sgn * gi)
        curves[f"seam_underarm_{lr}"] = line((gj == sh) & (vside == 2) & (sgn * gi >= ht), sgn * gi)
        curves[f"seam_side_{lr}"] = line((gi == sgn * ht) & (gj >= sh), gj)
        for s, sname in enumerate(SIDE_NAMES):
            on = (vside == 2) | (vside == s)
            curves[f"{sname}_armhole_{lr}"] = line(on & (gi == sgn * ht) & (gj <= sh), gj)
            for c in col_lines:
                curves[f"{sname}_vline_{lr}_{c}"] = line(on & (gi == sgn * c), gj)
    loop_names = ["underarm", "chest", "waist"]
    if len(row_lines) != 3:
        loop_names = [str(k) for k in range(len(row_lines))]
    for name, rl in zip(loop_names, row_lines, strict=True):
        front = line(((vside == 0) | (vside == 2)) & (gj == rl) & (np.abs(gi) <= ht), gi)
        back = line((vside == 1) & (gj == rl) & (np.abs(gi) < ht), -gi)
        curves[f"loop_{name}"] = np.concatenate([front, back])
    # the openings: hem, sleeve ends and the neck (the remaining boundary loop)
    faces = garment.faces.cpu().numpy()
    for loop in boundary_loops(faces):
        if (gj[loop] == tr).all():
            curves["opening_hem"] = loop
        elif (np.abs(gi[loop]) == off).all():
            curves["opening_sleeve_" + ("left" if gi[loop[0]] > 0 else "right")] = loop
        else:
            curves["opening_neck"] = loop
    return Cage(curves=curves, patches=patches, resolution=int(resolution))


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

    faces_f = cell_triangles(front_mask, vid_f)
    faces_b = cell_triangles(back_mask, vid_b)[:, ::-1].copy()  # back faces point to -z: flip winding

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
