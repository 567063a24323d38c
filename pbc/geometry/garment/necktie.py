"""The procedural necktie (appendix F): one UV chart, a knot at the collar, a hanging blade.

One job: produce the necktie as data (a Garment and its automatic Cage), for the same mannequin and
drape engine as the T-shirt.

Construction (one flat piece cut from a regular grid of ``grid_spacing``; pattern frame: X along the
tie from the knot's top, Y across it): the knot (a short trapezoid) at the collar; the blade below it,
widening to the tip, which ends in a point; two narrow band strips leaving the knot's top edge side by
side, which wrap round the left and right of the neck and are sewn to each other at the back of the
neck (their end vertices are shared, with two uvs in the one chart). The band holds the tie on, the
knot sits at the front of the neck, the blade hangs down the chest.

UV: the chart's long axis is u (image columns), scaled uniformly so that ``uv * uv_scale`` is the
pattern in metres, centred with ``uv_padding`` left at the ends. The necktie image is the
``uv_window`` band of rows of a square UV image (appendix F: 64 x 256, aspect 1:4): pixels stay
square in metres, and ``make_necktie`` checks that the chart lies inside that window.
"""

from __future__ import annotations

import numpy as np
import torch

from pbc.geometry.cage.auto import auto_cage
from pbc.geometry.cage.base import Cage
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.patterns import cell_triangles, sample_corners


def necktie_pattern(cfg) -> tuple[np.ndarray, dict]:
    """Boolean cell mask (rows across the tie, cols along it) and the landmarks, in grid cells.

    Column 0 is the far end of the bands (back of the neck); the knot's top edge is at column
    ``band_cells``; row ``centre`` is the tie's centre line.
    """
    h = float(cfg.grid_spacing)
    band = int(round(0.5 * float(cfg.neck_girth) / h))  # each band strip: half the neck girth
    knot = int(round(float(cfg.knot_length) / h))
    blade = int(round(float(cfg.blade_length) / h))
    tip = int(round(float(cfg.tip_length) / h))
    half = int(np.ceil(0.5 * float(cfg.blade_width) / h)) + 1
    rows, cols = 2 * half, band + knot + blade + tip
    jj, ii = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    x = (ii + 0.5 - band) * h  # along the tie from the knot's top (cell centres)
    y = np.abs((jj + 0.5 - half) * h)  # across, from the centre line
    # the band strips fill the knot's top edge but for a gap at the centre line, so they are sewn to the
    # knot along whole cell edges at any grid spacing (one chart); kh: the knot's top half width in cells
    gap = int(cfg.band_gap_cells)
    kh = max(int(round(0.5 * float(cfg.knot_width_top) / h)), gap + 1)
    off = np.abs(jj + 0.5 - half)
    in_band = (x < 0) & (off > gap) & (off < kh)
    knot_w = 0.5 * (float(cfg.knot_width_top) + (float(cfg.knot_width_bottom) - float(cfg.knot_width_top))
                    * x / max(float(cfg.knot_length), 1e-9))
    in_knot = (x >= 0) & (x < knot * h) & (off < np.maximum(knot_w / h, kh - 0.5 * (x > 0.5 * knot * h)))
    xb = x - knot * h
    blade_w = 0.5 * (float(cfg.knot_width_bottom) + (float(cfg.blade_width) - float(cfg.knot_width_bottom))
                     * xb / max(float(cfg.blade_length), 1e-9))
    in_blade = (xb >= 0) & (xb < blade * h) & (y < blade_w)
    xt = xb - blade * h
    in_tip = (xt >= 0) & (y < 0.5 * float(cfg.blade_width) * (1.0 - xt / max(tip * h, 1e-9)))
    mask = in_band | in_knot | in_blade | in_tip
    return mask, {"band": band, "knot": knot, "blade": blade, "tip": tip, "half": half, "gap": gap,
                  "band_cells": kh - gap}


def make_necktie(cfg) -> tuple[Garment, Cage]:
    """The necktie garment and its automatic cage. cfg: conf/garment/necktie.yaml."""

    h = float(cfg.grid_spacing)
    mask, land = necktie_pattern(cfg)
    rows, cols = mask.shape
    pad = np.pad(mask, 1, constant_values=False)
    used = pad[:-1, :-1] | pad[:-1, 1:] | pad[1:, :-1] | pad[1:, 1:]  # (rows+1, cols+1) grid points
    tex = -np.ones(used.shape, np.int64)
    tex[used] = np.arange(used.sum())
    jj, ii = np.nonzero(used)
    # vertices: grid points, the two bands' end columns (back of the neck) merged into one
    vid = tex.copy()
    half = land["half"]
    for j in range(rows + 1):
        mirror = 2 * half - j
        if j > half and used[j, 0] and 0 <= mirror <= rows and used[mirror, 0]:
            vid[j, 0] = tex[mirror, 0]
    keep = np.unique(vid[used])
    compact = -np.ones(int(tex.max()) + 1, np.int64)
    compact[keep] = np.arange(len(keep))
    vid[used] = compact[vid[used]]
    faces = cell_triangles(mask, vid)
    face_uv = cell_triangles(mask, tex)

    # pattern (X along the tie from the knot's top, Y across) and uv
    X = (ii - land["band"]) * h
    Y = (jj - half) * h
    pattern = np.stack([X, Y], 1)
    ext = float(np.ptp(X))
    uv_scale = ext / (1.0 - 2.0 * float(cfg.uv_padding))
    cx = 0.5 * (X.min() + X.max())
    uv = np.stack([0.5 + (X - cx) / uv_scale, 0.5 + Y / uv_scale], 1)
    v0, v1 = (float(x) for x in cfg.uv_window)
    if uv[:, 1].min() < v0 or uv[:, 1].max() > v1:
        raise ValueError(f"necktie: the chart spans v {uv[:, 1].min():.3f}..{uv[:, 1].max():.3f}, outside the "
                         f"image window uv_window={[v0, v1]}: the tie is too wide for its length; narrow it "
                         "or widen the window")

    # 3D rest shape: the knot and blade hang down the front, the bands wrap round the neck
    nv = len(keep)
    pos = np.zeros((nv, 3))
    y_top, zf = float(cfg.collar_height), float(cfg.front_z)
    r, zc = float(cfg.neck_radius), float(cfg.neck_center_z)
    lb = land["band"] * h
    for k, (x, y) in enumerate(pattern):
        v = vid[jj[k], ii[k]]
        # across the tie (pattern Y) runs to the body's right (-x): faces then turn like the outward normal,
        # as the shirt's charts do (seen from outside)
        if x >= 0:  # knot + blade: down the front
            p = (-y, y_top - x, zf + 0.4 * x * float(cfg.blade_lean))
        else:  # band: angle round the neck from the front (0) to the back (pi)
            theta = np.pi * min(-x / lb, 1.0)
            side = -1.0 if y > 0 else 1.0
            p = (side * r * np.sin(theta), y_top + abs(y), zc + r * np.cos(theta))
        pos[v] = p
    # a merged band-end vertex has two uvs: sampled at the one the OBJ reader picks back (sample_corners)
    vertex_tex, _ = sample_corners(faces, face_uv, np.zeros(len(faces), np.int64), np.zeros(len(faces), np.int64))
    garment = Garment(
        vertices=torch.tensor(pos, dtype=torch.float32),
        faces=torch.tensor(faces, dtype=torch.long),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(face_uv, dtype=torch.long),
        face_side=torch.zeros(len(faces), dtype=torch.long),
        vertex_uv=torch.tensor(uv[vertex_tex], dtype=torch.float32),
        vertex_side=torch.zeros(nv, dtype=torch.long),
        uv_scale=float(uv_scale),
    )
    cage = auto_cage(garment, int(cfg.patch_resolution), int(cfg.crop_size), int(cfg.margin),
                     chart_names=["necktie"], face_chart=np.zeros(len(faces), np.int64))
    return garment, cage
