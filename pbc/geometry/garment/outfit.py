"""Outfits: one mesh holding several garments (a shirt and trousers), its pieces named by where they sit on
the body (``top`` / ``bottom``), one piece picked (``garment.piece``) or each written to its own OBJ."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from pbc.core.io import atomic_path
from pbc.geometry.meshio import ObjMesh, read_obj
from pbc.geometry.meshops import mesh_pieces
from pbc.geometry.units import metres_per_unit

# the body frame (metres, y up, root at the waist): a piece centred above HEAD_Y sits on the head, above
# TOP_Y on the torso, above FEET_Y on the legs, below on the feet
HEAD_Y, TOP_Y, FEET_Y = 0.60, -0.05, -0.80


def piece_name(centre_y: float) -> str:
    """Where a piece centred at height centre_y (m, body frame) sits."""
    if centre_y > HEAD_Y:
        return "head"
    if centre_y > TOP_Y:
        return "top"
    if centre_y > FEET_Y:
        return "bottom"
    return "feet"


def split_outfit(path, out_dir, position_unit="m", position_offset=(0.0, 0.0, 0.0)) -> list[tuple[str, Path, int]]:
    """Cut an OBJ holding several separate pieces (connected through no vertex) into one OBJ each, in the
    file's own units and polygons (v, vt, `g` groups kept; indices renumbered), named by where each sits
    (`piece_name` of its centre in the body frame; `top_2` when two sit alike). Returns (name, path,
    polygons) per piece, highest first."""
    path, out_dir = Path(path), Path(out_dir)
    mesh = read_obj(path, "outfit OBJ")
    piece = mesh_pieces(mesh.faces, len(mesh.vertices))
    p = mesh.vertices * metres_per_unit(position_unit, "garment.position_unit") + np.asarray(position_offset)
    ids = sorted(range(int(piece.max()) + 1), key=lambda k: -p[piece == k, 1].mean())
    if len(ids) < 2:
        raise ValueError(f"{path}: one connected piece only; nothing to split (pbc garment inspect shows its charts)")
    # each `f` line's polygon back from its fan triangles: (v0, v1, v2), (v0, v2, v3), ...
    polys: dict[int, tuple[list[int], list[int], int]] = {}
    for k, line in enumerate(mesh.face_line):
        if line not in polys:
            polys[line] = (list(mesh.faces[k]), list(mesh.face_uv[k]), int(mesh.face_group[k]))
        else:
            polys[line][0].append(int(mesh.faces[k, 2]))
            polys[line][1].append(int(mesh.face_uv[k, 2]))
    out, seen = [], {}
    for k in ids:
        base = piece_name(float(p[piece == k, 1].mean()))
        seen[base] = seen.get(base, 0) + 1
        name = base if seen[base] == 1 else f"{base}_{seen[base]}"
        mine = [v for v in polys.values() if piece[v[0][0]] == k]
        vids = np.unique(np.concatenate([m[0] for m in mine]))
        tids = np.unique(np.concatenate([m[1] for m in mine]))
        vmap = {int(v): i + 1 for i, v in enumerate(vids)}
        tmap = {int(v): i + 1 for i, v in enumerate(tids)}
        lines = [f"# {name}: piece of {path.name} cut by pbc garment split"]
        lines += ["v " + " ".join(f"{x:.6g}" for x in mesh.vertices[v]) for v in vids]
        lines += ["vt " + " ".join(f"{x:.6g}" for x in mesh.uv[t]) for t in tids]
        group = None
        for fv, ft, g in mine:
            if g != group:
                lines.append(f"g {mesh.groups[g]}")
                group = g
            lines.append("f " + " ".join(f"{vmap[int(a)]}/{tmap[int(b)]}" for a, b in zip(fv, ft, strict=True)))
        target = out_dir / f"{name}.obj"
        with atomic_path(target, suffix=".obj") as tmp:
            Path(tmp).write_text("\n".join(lines) + "\n")
        out.append((name, target, len(mine)))
    return out


def name_pieces(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Each vertex's piece (V,) and each piece's name: where it sits (pbc.geometry.garment.outfit.piece_name: head, top,
    bottom, feet), numbered by size within a place (`top` the largest, `top_2` ...)."""
    piece = mesh_pieces(faces, len(positions))
    n = int(piece.max()) + 1
    size = np.bincount(piece, minlength=n)
    base = [piece_name(float(positions[piece == k, 1].mean())) for k in range(n)]
    names = [""] * n
    for place in dict.fromkeys(base):
        mine = sorted((k for k in range(n) if base[k] == place), key=lambda k: -size[k])
        for rank, k in enumerate(mine):
            names[k] = place if rank == 0 else f"{place}_{rank + 1}"
    return piece, names


def select_piece(mesh: ObjMesh, positions: np.ndarray, piece, where: str) -> tuple[ObjMesh, np.ndarray]:
    """The part of the garment `garment.piece` asks for: `all`, a place (`top`: every piece sitting there), or
    one numbered piece (`top_2`); null keeps the garment whole when its pieces all sit in one place and refuses
    an outfit, naming its pieces. Returns the cut mesh and its positions (vertices renumbered)."""
    vpiece, names = name_pieces(positions, mesh.faces)
    places = sorted({n.split("_")[0] for n in names})
    size = np.bincount(vpiece, minlength=len(names))
    listing = ", ".join(f"{n} ({size[k]:,} vertices)" for k, n in enumerate(names))
    if piece is None or str(piece) == "all":
        if piece is None and len(places) > 1:
            raise ValueError(f"{where}: an outfit of {len(names)} pieces: {listing}; choose one: "
                             f"{' or '.join(f'garment.piece={p}' for p in places)} (every piece sitting there), a "
                             "numbered piece, or garment.piece=all for the whole outfit as one garment")
        return mesh, positions
    piece = str(piece)
    keep = [k for k, n in enumerate(names) if n == piece or (piece in places and n.split("_")[0] == piece)]
    if not keep:
        raise ValueError(f"{where}: garment.piece={piece} is none of its pieces: {listing}; give one of them, a "
                         f"place ({', '.join(places)}) or all")
    vkeep = np.isin(vpiece, keep)
    fkeep = vkeep[mesh.faces[:, 0]]
    new = -np.ones(len(vkeep), np.int64)
    new[vkeep] = np.arange(int(vkeep.sum()))
    cut = replace(mesh, vertices=mesh.vertices[vkeep], faces=new[mesh.faces[fkeep]], face_uv=mesh.face_uv[fkeep],
                  face_group=mesh.face_group[fkeep], face_line=mesh.face_line[fkeep],
                  vertex_line=mesh.vertex_line[vkeep])
    return cut, positions[vkeep]
