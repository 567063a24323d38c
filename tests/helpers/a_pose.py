"""Garments made as a new user's asset library would hand them over, for tests: the procedural
shirt with its sleeves turned down into an A-pose, written as one [0, 1] UV atlas with no groups and its
positions in decimetres, and an outfit in one mesh (that shirt, T- or A-posed, and a trouser-like tube
below the waist). Nothing here is shipped."""

from __future__ import annotations

import numpy as np

from pbc.core.config import load_config
from pbc.geometry.garment.tshirt import make_tshirt

# where the procedural shirt's sleeves leave its panels (|x|, m) and the arm axis they turn about (y, m)
SLEEVE_ROOT_X = 0.28
ARM_Y = 0.43
# the config overrides that import these files the way the user did first (garment.uv_unit=auto
# finds the unit from the 3D area; the positions are decimetres)
IMPORT = ["garment=obj", "garment.uv_unit=auto", "garment.position_unit=dm", "body.mesh.voxel_size=0.03"]


def shirt_parts(angle_deg: float = 40.0, garment: str = "tshirt"):
    """The procedural shirt's (positions (V, 3) m, faces, uv (T, 2) per side in [0, 1], face_uv, face_side),
    each sleeve (|x| > SLEEVE_ROOT_X) turned ``angle_deg`` down about its root on the arm axis. garment:
    its config (tshirt_coarse: 425 vertices, for tests that drape it)."""
    g, _ = make_tshirt(load_config([f"garment={garment}"]).garment)
    p = g.vertices.double().numpy().copy()
    a = np.radians(angle_deg)
    for sgn in (1.0, -1.0):
        sel = sgn * p[:, 0] > SLEEVE_ROOT_X
        dx, dy = p[sel, 0] - sgn * SLEEVE_ROOT_X, p[sel, 1] - ARM_Y
        # down for both sides: the left (+x) sleeve turns clockwise in (x, y), the right one anticlockwise
        c, s = np.cos(a), -sgn * np.sin(a)
        p[sel, 0] = sgn * SLEEVE_ROOT_X + c * dx - s * dy
        p[sel, 1] = ARM_Y + s * dx + c * dy
    return p, g.faces.numpy(), g.uv.double().numpy(), g.face_uv.numpy(), g.face_side.numpy()


def _tube(top: float, bottom: float, radius: float, cols: int = 24, rows: int = 10):
    """An open tube round the legs (m) and its pattern cut open at the back (m): (points, faces, uv, face_uv)."""
    ys = np.linspace(top, bottom, rows + 1)
    ang = np.linspace(-np.pi, np.pi, cols + 1)  # the cut at the back (z < 0) keeps u continuous in front
    pts = np.array([[radius * np.sin(t), y, -0.01 + radius * np.cos(t)] for y in ys for t in ang[:-1]])
    uv = np.array([[radius * t, y] for y in ys for t in ang])  # one more column: the cut's two edges
    faces, fuv = [], []
    for r in range(rows):
        for k in range(cols):
            v = [r * cols + k, r * cols + (k + 1) % cols, (r + 1) * cols + (k + 1) % cols, (r + 1) * cols + k]
            t = [r * (cols + 1) + k, r * (cols + 1) + k + 1, (r + 1) * (cols + 1) + k + 1, (r + 1) * (cols + 1) + k]
            faces += [[v[0], v[2], v[1]], [v[0], v[3], v[2]]]  # outward
            fuv += [[t[0], t[2], t[1]], [t[0], t[3], t[2]]]
    return pts, np.array(faces), uv, np.array(fuv)


def outfit_obj(angle_deg: float = 40.0, trousers: bool = True, unit: float = 0.1, garment: str = "tshirt") -> str:
    """An OBJ as the issue's asset: triangles, one UV atlas in [0, 1] (no `g` groups: every chart is
    `default...`), positions in ``unit`` metres (decimetres), the shirt with A-posed sleeves and, with
    ``trousers``, a separate trouser-like tube from just below the waist to the ankles in the same mesh."""
    p, f, uv, fuv, side = shirt_parts(angle_deg, garment)
    # the atlas: the front panel top left, the back beside it, the trousers below; one uniform scale
    # (0.4 atlas units per side image), so the pattern keeps its shape
    uv_side = np.zeros(len(uv), np.int64)
    uv_side[fuv.ravel()] = np.repeat(side, 3)
    atlas = np.stack([0.4 * uv[:, 0] + 0.4 * uv_side, 1.0 - 0.4 * uv[:, 1]], 1)  # file convention: v up
    pieces = [(p, f, atlas, fuv)]
    if trousers:
        g, _ = make_tshirt(load_config([f"garment={garment}"]).garment)
        per_metre = 0.4 / float(g.uv_scale)  # atlas units per pattern metre, as the shirt's
        tp, tf, tuv, tfuv = _tube(-0.10, -0.90, 0.17)
        tuv = (tuv - tuv.min(0)) * per_metre + np.array([0.02, 0.02])
        if tuv[:, 0].max() > 1.0 or tuv[:, 1].max() > 0.58:
            raise AssertionError(f"the trousers' pattern does not fit under the shirt in the atlas ({tuv.max(0)})")
        pieces.append((tp, tf, tuv, tfuv))
    lines = ["# exported by an asset library: one atlas, no groups, decimetres", "mtllib outfit.mtl", "o Outfit"]
    nv = nt = 0
    body = []
    for pts, faces, tex, ftex in pieces:
        lines += [f"v {x / unit:.6f} {y / unit:.6f} {z / unit:.6f}" for x, y, z in pts]
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in tex]
        body += [" ".join(["f"] + [f"{a + 1 + nv}/{b + 1 + nt}" for a, b in zip(fv, ft, strict=True)])
                 for fv, ft in zip(faces, ftex, strict=True)]
        nv, nt = nv + len(pts), nt + len(tex)
    return "\n".join(lines + ["usemtl Cloth", "s 1", *body]) + "\n"
