"""MakeHuman-format clothes for tests: a small patch garment bound to base-mesh vertices, written as a `.mhclo` with
its `.obj` (UVs, quads), the way MakeClothes writes them (header comments, CRLF, material and z_depth lines).

`chest_patch(base)` picks the binding on a base mesh (N, 3) (metres, pbc's frame): an n x n grid over the chest,
each vertex bound to three helper-tights vertices in front (weights 0.5, 0.3, 0.2) with an offset of
`OFFSET_DM` decimetres outwards, so the fit sits well outside the body and nothing is pushed out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TIGHTS = (15328, 18002)  # MakeHuman hm08's helper-tights vertices
# MakeClothes' own scale lines (head vertices, their distances on the base mesh in decimetres)
SCALES = {"x": (5399, 11998, 1.4800), "y": (791, 881, 2.3298), "z": (962, 5320, 1.9221)}
WEIGHTS = (0.5, 0.3, 0.2)
OFFSET_DM = (0.01, -0.02, 0.3)  # decimetres (x, y, z): 3 cm in front of the tights helper
SPACING = 0.025  # m between grid points
CHEST_Y = 0.35  # m above the root (pbc frame): the chest


def chest_patch(base: np.ndarray, n: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(refs (n*n, 3) int, weights (n*n, 3), offsets (n*n, 3) dm) of an n x n patch on the chest of `base`."""
    ids = np.arange(*TIGHTS)
    front = ids[base[ids, 2] > 0.0]  # the front of the torso: z forward
    refs = []
    for j in range(n):
        for i in range(n):
            at = np.array([(i - (n - 1) / 2) * SPACING, CHEST_Y - j * SPACING])
            near = front[np.argsort(np.linalg.norm(base[front, :2] - at, axis=1))[:3]]
            refs.append(near)
    k = len(refs)
    return np.asarray(refs, np.int64), np.tile(WEIGHTS, (k, 1)), np.tile(OFFSET_DM, (k, 1))


def grid_faces(n: int) -> list[tuple[int, int, int, int]]:
    """Quads of an n x n vertex grid (row-major), counter-clockwise seen from the front (+z)."""
    return [(j * n + i, (j + 1) * n + i, (j + 1) * n + i + 1, j * n + i + 1)
            for j in range(n - 1) for i in range(n - 1)]


def write_mhclo(folder, refs: np.ndarray, weights: np.ndarray, offsets: np.ndarray, positions_dm: np.ndarray,
                n: int, name: str = "patch", scales: dict | None = None, extra_obj_vertices: int = 0) -> Path:
    """Write `name.mhclo` and `name.obj` (an n x n grid with UVs) into folder; the .mhclo's path."""
    obj = ["# MakeClothes", f"mtllib {name}.mtl", f"o {name}"]
    pos = np.concatenate([positions_dm, np.zeros((extra_obj_vertices, 3))])
    obj += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pos]
    obj += [f"vt {i / (n - 1):.6f} {1 - j / (n - 1):.6f}" for j in range(n) for i in range(n)]
    obj += ["usemtl cloth", "s off"]
    obj += ["f " + " ".join(f"{a + 1}/{a + 1}" for a in q) for q in grid_faces(n)]
    return write_mhclo_for_obj(folder, "\n".join(obj) + "\n", refs, weights, offsets, name, scales)


def write_mhclo_for_obj(folder, obj_text: str, refs: np.ndarray, weights: np.ndarray, offsets: np.ndarray,
                        name: str, scales: dict | None = None) -> Path:
    """Write `name.obj` (obj_text as given) and its `name.mhclo` (one binding per vertex) into folder, as
    MakeClothes writes them; the .mhclo's path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scales = SCALES if scales is None else scales
    lines = ["# This is a clothes file for MakeHuman Community, exported by MakeClothes 2", "#",
             "# author: tests", "# license: CC0", "#", "basemesh hm08", "", f"name {name}", f"obj_file {name}.obj",
             f"material {name}.mhmat", "", "uuid 59985471-ab08-479f-a32d-2d88411714ef"]
    lines += [f"{axis}_scale {a} {b} {d:.4f}" for axis, (a, b, d) in scales.items()]
    lines += ["z_depth 50", "max_pole 4", "", "# Vertex info:", "verts 0"]
    for r, w, o in zip(refs, weights, offsets, strict=True):
        lines.append(" ".join(str(int(x)) for x in r) + " " + " ".join(f"{x:.6f}" for x in (*w, *o)))
    lines += ["", "delete_verts", " 100 - 104 200"]
    (folder / f"{name}.mhclo").write_bytes(("\r\n".join(lines) + "\r\n").encode())
    (folder / f"{name}.obj").write_text(obj_text)
    return folder / f"{name}.mhclo"


def axis_scales(base: np.ndarray, scales: dict | None = None) -> np.ndarray:
    """(3,) metres per offset unit along x, y, z: |v_a - v_b| along the axis / its base distance d."""
    scales = SCALES if scales is None else scales
    return np.array([abs(base[a, k] - base[b, k]) / d for k, (a, b, d) in enumerate(scales.values())])


def bind_to_tights(points: np.ndarray, base: np.ndarray, scales: dict | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bind points (V, 3) (metres, pbc's frame) as MakeClothes binds clothes: each to its three nearest
    helper-tights vertices of `base`, weighted by inverse distance, with the rest as the scaled offset. (refs,
    weights, offsets dm); `hand_fit` of them gives the points back on this base mesh."""
    ids = np.arange(*TIGHTS)
    d = np.linalg.norm(points[:, None, :] - base[None, ids, :], axis=2)  # (V, T)
    near = np.argsort(d, axis=1)[:, :3]
    refs = ids[near]
    w = 1.0 / np.maximum(np.take_along_axis(d, near, 1), 1e-6)
    w /= w.sum(1, keepdims=True)
    offsets = (points - np.einsum("vt,vtk->vk", w, base[refs])) / axis_scales(base, scales)
    return refs, w, offsets


def hand_fit(base: np.ndarray, refs: np.ndarray, weights: np.ndarray, offsets: np.ndarray,
             scales: dict | None = None) -> np.ndarray:
    """The fit written out by hand: per vertex w0 v_a + w1 v_b + w2 v_c + (sx dx, sy dy, sz dz), s per axis =
    |v_p - v_q| along it / the base distance (metres per decimetre)."""
    s = axis_scales(base, scales)
    out = np.zeros((len(refs), 3))
    for v in range(len(refs)):
        for t in range(3):
            out[v] += weights[v, t] * base[refs[v, t]]
        out[v] += np.array([s[0] * offsets[v, 0], s[1] * offsets[v, 1], s[2] * offsets[v, 2]])
    return out
