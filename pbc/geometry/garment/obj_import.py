"""A user's garment from an OBJ file as other tools export it (Blender, Marvelous Designer, CLO, ...).

One job: turn the text of a real OBJ into a :class:`~pbc.geometry.garment.base.Garment`: polygons of any
size triangulated (each corner keeps its own ``vt``, so UV seams survive), relative (negative)
indices resolved, ``usemtl``/``mtllib``/``s``/``o``/``vn``/``l`` lines ignored, UV charts found as
connected UV islands and named by their ``g`` group, each chart mapped to an image side by the
config (``garment.charts``), and the UVs scaled to the flat sewing pattern with a stated unit
(``garment.uv_unit``), then laid out in the pbc convention (v = 0 at the top, one uniform
``uv_scale``, ``uv_padding`` of each side left empty).

Bad input gets one ValueError naming the file, the line where it can be seen and the fix: no UVs, a
loose vertex, a non-manifold edge, folded or overlapping UV islands, an unmapped chart.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from skimage.draw import polygon

from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.patterns import sample_corners
from pbc.geometry.meshio import ObjMesh, read_obj
from pbc.geometry.meshops import signed_uv_area, uv_islands
from pbc.geometry.units import check_uv_unit, metres_per_unit, uv_unit_from_areas


def check_mesh(mesh: ObjMesh, where: str = "<obj>") -> None:
    """Raise ValueError unless every vertex is used and no edge has more than two faces."""
    nv = len(mesh.vertices)
    used = np.zeros(nv, bool)
    used[mesh.faces.ravel()] = True
    if not used.all():
        k = int(np.flatnonzero(~used)[0])
        raise ValueError(f"{where}: line {mesh.vertex_line[k]}: vertex {k + 1} is used by no face "
                         f"({int((~used).sum())} loose vertices); delete loose vertices "
                         "(Blender: Mesh > Clean Up > Delete Loose)")
    f = mesh.faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv, count = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    bad = np.flatnonzero(count > 2)
    if len(bad):
        a, b = uniq[bad[0]]
        lines = mesh.face_line[np.tile(np.arange(len(f)), 3)[inv.ravel() == bad[0]]]
        raise ValueError(f"{where}: lines {sorted(set(lines.tolist()))}: the edge between vertices {a + 1} and {b + 1} "
                         f"has {count[bad[0]]} faces ({len(bad)} non-manifold edges); a garment is a surface "
                         "where each edge has one or two faces: split the extra panels apart "
                         "(Blender: Select > All by Trait > Non Manifold, then Edge Split)")


def drop_loose(mesh: ObjMesh) -> tuple[ObjMesh, int]:
    """The mesh without its loose vertices (used by no face: construction points, a pattern tool's pins), and
    how many were dropped. Faces keep their order; vertex ids are renumbered."""
    used = np.zeros(len(mesh.vertices), bool)
    used[mesh.faces.ravel()] = True
    if used.all():
        return mesh, 0
    new_id = np.cumsum(used) - 1
    return replace(mesh, vertices=mesh.vertices[used], faces=new_id[mesh.faces],
                   vertex_line=mesh.vertex_line[used]), int((~used).sum())


def projected_charts(mesh: ObjMesh) -> ObjMesh:
    """UVs for a mesh without any (its vertices as modelled, any unit: y up, z forward): the front and back
    projections, as pbc's own shirt is laid out. A face whose outward normal points forward goes to the
    ``front`` chart at (x, y), the others to ``back`` at (-x, y); a vertex on the border between them keeps one
    UV in each. The projection never folds (a face's side is the sign of its projected area)."""
    p, f = mesh.vertices, mesh.faces
    t = p[f]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    away = t.mean(1)
    away[:, 1] = 0.0
    if (n * away).sum() < 0.0:  # wound inward: the outward normal is the other one
        n = -n
    side = (n[:, 2] <= 0.0).astype(np.int64)  # 0 front, 1 back
    key = f * 2 + side[:, None]  # one UV per (vertex, side)
    ids, face_uv = np.unique(key.ravel(), return_inverse=True)
    vid, vside = ids // 2, ids % 2
    uv = np.stack([np.where(vside == 1, -p[vid, 0], p[vid, 0]), p[vid, 1]], 1)
    return replace(mesh, uv=uv, face_uv=face_uv.reshape(-1, 3), face_group=side, groups=["front", "back"])


def chart_names(island: np.ndarray, face_group: np.ndarray, groups: list[str]) -> list[str]:
    """A name per island: its group's name (the group of most of its faces), numbered when a group
    holds several islands (``sleeve``, ``sleeve_2``)."""
    n = int(island.max()) + 1
    base = [groups[int(np.bincount(face_group[island == k]).argmax())] for k in range(n)]
    names, seen = [], {}
    for b in base:
        seen[b] = seen.get(b, 0) + 1
        names.append(b if seen[b] == 1 else f"{b}_{seen[b]}")
    return names


def overlapping_charts(tri: np.ndarray, chart: np.ndarray, resolution: int = 512,
                       tolerance: float = 0.005) -> tuple[int, int, int] | None:
    """The first pair of charts whose UV triangles overlap, as (a, b, pixels), else None.

    tri (F, 3, 2) UVs in [0, 1]^2 of one image side, chart (F,). Pixel centres inside triangles of two
    charts count, beyond ``tolerance`` of the smaller chart's pixels (charts that only touch share
    a few boundary pixels).
    """
    owner = -np.ones((resolution, resolution), np.int64)
    count = np.zeros((resolution, resolution), np.int64)
    hits: dict[tuple[int, int], int] = {}
    sizes: dict[int, int] = {}
    for c in np.unique(chart):
        mask = np.zeros((resolution, resolution), bool)
        for t in tri[chart == c] * resolution - 0.5:
            rr, cc = polygon(t[:, 1], t[:, 0], shape=mask.shape)
            mask[rr, cc] = True
        sizes[int(c)] = int(mask.sum())
        clash = mask & (owner >= 0)
        for o in np.unique(owner[clash]):
            hits[(int(o), int(c))] = int((clash & (owner == o)).sum())
        owner[mask & (owner < 0)] = c
        count += mask
    for (a, b), n in hits.items():
        if n > tolerance * max(1, min(sizes[a], sizes[b])):
            return a, b, n
    return None


def import_garment(path, charts: Mapping[str, int] | None = None, uv_unit="auto", position_unit="m",
                   position_offset=(0.0, 0.0, 0.0), uv_padding: float = 0.1, overlap_resolution: int = 512,
                   uv_unit_tolerance: float | None = None):
    """Read a garment OBJ exported by another tool into a Garment (see the module docstring).

    path: the OBJ file. charts: chart name -> image side (0 front image, 1 back image); None maps
    charts whose name starts with ``back`` to 1 and all others to 0. Charts sharing a side share its
    image, so their UVs must not overlap. uv_unit: what one UV unit is on the flat pattern (``m``,
    ``cm``, ``mm``, ``in``, metres per unit as a number, or ``auto``: from the 3D surface area, for
    UVs normalised to [0, 1] as Blender writes them). position_unit / position_offset: the unit of
    the ``v`` lines and a shift (m) placing the garment on the T-posed mannequin (root at the waist,
    y up, x the body's left). uv_padding: fraction of each side's image left empty at every border.
    uv_unit_tolerance: a stated uv_unit whose pattern area is off the 3D area by more than this factor
    is refused, naming the unit that fits (the config's ``garment.uv_unit_tolerance``; None: not checked).
    Returns (Garment, chart_names list, face_chart (F,) int64).
    """

    path = Path(path)
    return garment_from_mesh(read_obj(path, "garment OBJ"), str(path), charts, uv_unit, position_unit, position_offset,
                             uv_padding, overlap_resolution, uv_unit_tolerance)


def garment_from_mesh(mesh: ObjMesh, where: str, charts: Mapping[str, int] | None = None, uv_unit="auto",
                      position_unit="m", position_offset=(0.0, 0.0, 0.0), uv_padding: float = 0.1,
                      overlap_resolution: int = 512, uv_unit_tolerance: float | None = None):
    """`import_garment` of an OBJ already parsed (`where` names it in errors): a garment whose positions
    come from elsewhere (pbc.geometry.garment.mhclo fits them to the body) or a piece cut from an outfit."""
    check_mesh(mesh, where)
    corners = mesh.uv[mesh.face_uv]  # (F, 3, 2) file convention, v up
    island = uv_islands(mesh.faces, corners)
    names = chart_names(island, mesh.face_group, mesh.groups)
    area = signed_uv_area(corners)
    # each island is one flat piece: its triangles all turn the same way in UV (a mirrored island
    # is flipped back, since the rest shape must not be inverted); mixed signs are a fold
    for k, name in enumerate(names):
        a = area[island == k]
        sign = 1.0 if a.sum() >= 0 else -1.0
        bad = np.flatnonzero((island == k) & (sign * area <= 0))
        if len(bad):
            raise ValueError(f"{where}: line {mesh.face_line[bad[0]]}: UV island '{name}' is folded over "
                             f"({len(bad)} triangles turn the other way or have zero UV area); re-unwrap it "
                             "so the piece lies flat without overlapping itself")
        if sign < 0:
            corners[island == k, :, 0] *= -1.0
    # chart -> image side
    if charts is None:
        side_of = {n: int(n.lower().startswith("back")) for n in names}
    else:
        side_of = {str(k): int(v) for k, v in dict(charts).items()}
        missing = [n for n in names if n not in side_of]
        if missing:
            example = ",".join(f"{n}:0" for n in names)
            raise ValueError(f"{where}: chart(s) {missing} have no image side; the charts are {names} "
                             f"(named by their `g` group, numbered when a group has several UV islands): "
                             f"map every one, e.g. garment.charts={{{example}}}")
    sides = np.asarray([side_of[n] for n in names], np.int64)
    if not set(sides.tolist()) <= {0, 1}:
        raise ValueError(f"{where}: garment.charts sides must be 0 (front image) or 1 (back image), got {side_of}")
    face_side = sides[island]

    # UV -> metres on the pattern, y up
    p3 = mesh.vertices[mesh.faces] * metres_per_unit(position_unit, "garment.position_unit")
    a3 = 0.5 * np.linalg.norm(np.cross(p3[:, 1] - p3[:, 0], p3[:, 2] - p3[:, 0]), axis=1).sum()
    if uv_unit == "auto":
        scale = uv_unit_from_areas(a3, np.abs(area).sum())
    else:
        scale = metres_per_unit(uv_unit, "garment.uv_unit")
        if uv_unit_tolerance is not None:  # both areas are at hand: a wrong unit is named here, not after drapes
            check_uv_unit(scale, a3, np.abs(area).sum(), str(uv_unit), float(uv_unit_tolerance), where,
                          float(np.ptp(mesh.uv[np.unique(mesh.face_uv)], axis=0).max()))
    pattern = corners * scale
    # one uv_scale for all sides; each side centred in its image with uv_padding left empty
    extent = []
    for s in np.unique(face_side):
        pts = pattern[face_side == s].reshape(-1, 2)
        extent.append(np.ptp(pts, axis=0).max())
    if not 0.0 <= uv_padding < 0.5:
        raise ValueError(f"garment.uv_padding must be in [0, 0.5), got {uv_padding}")
    uv_scale = float(max(extent)) / (1.0 - 2.0 * uv_padding)
    uvp = np.empty_like(pattern)
    for s in np.unique(face_side):
        sel = face_side == s
        pts = pattern[sel].reshape(-1, 2)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        uvp[sel, :, 0] = 0.5 + (pattern[sel, :, 0] - centre[0]) / uv_scale
        uvp[sel, :, 1] = 0.5 - (pattern[sel, :, 1] - centre[1]) / uv_scale  # pbc: v = 0 at the top
    for s in np.unique(face_side):
        sel = np.flatnonzero(face_side == s)
        clash = overlapping_charts(uvp[sel], island[sel], overlap_resolution)
        if clash is not None:
            a, b, n = clash
            raise ValueError(f"{where}: UV islands '{names[a]}' and '{names[b]}' overlap ({n} px at "
                             f"{overlap_resolution}) on image side {s}; move them apart in the UV layout, or "
                             f"put them on different sides (garment.charts={{{names[a]}:0,{names[b]}:1}})")

    # one uv entry per (vt, island): an exporter may share a vt between islands we flipped apart
    key = np.stack([mesh.face_uv.ravel(), np.repeat(island, 3)], 1)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    uv = uvp.reshape(-1, 2)[first]
    face_uv = inv.reshape(-1, 3)
    # a vertex is sampled from its first chart on the lowest side (the front for front/back seams)
    vertex_tex, vertex_side = sample_corners(mesh.faces, face_uv, face_side, island)
    pos = mesh.vertices * metres_per_unit(position_unit, "garment.position_unit") + np.asarray(position_offset)
    garment = Garment(
        vertices=torch.tensor(pos, dtype=torch.float32),
        faces=torch.tensor(mesh.faces),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(face_uv, dtype=torch.long),
        face_side=torch.tensor(face_side),
        vertex_uv=torch.tensor(uv[vertex_tex], dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side),
        uv_scale=uv_scale,
    )
    return garment, names, island
