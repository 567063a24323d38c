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

# pixels across an image side where the charts sharing it are checked for overlap (garment_from_mesh's default)
OVERLAP_RESOLUTION = 512
UV_PADDING = 0.1  # fraction of each side's image left empty at every border (garment.uv_padding's default)


def check_mesh(mesh: ObjMesh, where: str = "<obj>", split_setting: bool = False) -> None:
    """Raise ValueError unless every vertex is used and no edge has more than two faces; ``split_setting``: the
    refusal of non-manifold edges names ``garment.split_nonmanifold=true`` (where the caller reads it) first."""
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
                         "where each edge has one or two faces: "
                         + ("let pbc cut the extra panels apart there as Blender's Edge Split does "
                            "(garment.split_nonmanifold=true), or split them yourself " if split_setting else
                            "split the extra panels apart ")
                         + "(Blender: Select > All by Trait > Non Manifold, then Edge Split)")


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


def outward_side(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) int64 image side per face of a mesh as modelled (any unit: y up, z forward): 0 (front) where its
    outward normal points forward (z > 0), else 1 (back). Outward: the winding whose normals point away from
    the vertical axis through the origin on the whole, so a mesh wound inward is read the other way round."""
    t = vertices[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    away = t.mean(1)
    away[:, 1] = 0.0
    if (n * away).sum() < 0.0:  # wound inward: the outward normal is the other one
        n = -n
    return (n[:, 2] <= 0.0).astype(np.int64)


def projected_charts(mesh: ObjMesh) -> ObjMesh:
    """UVs for a mesh without any (its vertices as modelled, any unit: y up, z forward): the front and back
    projections, as pbc's own shirt is laid out. A face whose outward normal points forward (`outward_side`)
    goes to the ``front`` chart at (x, y), the others to ``back`` at (-x, y); a vertex on the border between them
    keeps one UV in each. The projection never folds (a face's side is the sign of its projected area)."""
    p, f = mesh.vertices, mesh.faces
    side = outward_side(p, f)
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


def chart_overlaps(tri: np.ndarray, chart: np.ndarray, resolution: int = OVERLAP_RESOLUTION,
                   tolerance: float = 0.005) -> dict[tuple[int, int], int]:
    """Every pair of charts whose UV triangles overlap: {(a, b): pixels} with a < b.

    tri (F, 3, 2) UVs in [0, 1]^2 of one image, chart (F,) int. Pixel centres inside triangles of both
    charts count, beyond ``tolerance`` of the smaller chart's pixels (charts that only touch share a few
    boundary pixels).
    """
    masks: dict[int, tuple[slice, slice, np.ndarray]] = {}
    out: dict[tuple[int, int], int] = {}
    for c in np.unique(chart):
        pix = tri[chart == c] * resolution - 0.5
        lo = np.clip(np.floor(pix.reshape(-1, 2).min(0)).astype(int), 0, resolution)
        hi = np.clip(np.ceil(pix.reshape(-1, 2).max(0)).astype(int) + 1, 0, resolution)
        mask = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), bool)
        for t in pix - lo:
            rr, cc = polygon(t[:, 1], t[:, 0], shape=mask.shape)
            mask[rr, cc] = True
        box = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
        for o, (obox, omask) in masks.items():
            r0, r1 = max(box[0].start, obox[0].start), min(box[0].stop, obox[0].stop)
            c0, c1 = max(box[1].start, obox[1].start), min(box[1].stop, obox[1].stop)
            if r0 >= r1 or c0 >= c1:
                continue
            n = int((mask[r0 - lo[1]:r1 - lo[1], c0 - lo[0]:c1 - lo[0]]
                     & omask[r0 - obox[0].start:r1 - obox[0].start, c0 - obox[1].start:c1 - obox[1].start]).sum())
            if n > tolerance * max(1, min(int(mask.sum()), int(omask.sum()))):
                out[(o, int(c))] = n
        masks[int(c)] = (box, mask)
    return out


def overlapping_charts(tri: np.ndarray, chart: np.ndarray, resolution: int = OVERLAP_RESOLUTION,
                       tolerance: float = 0.005) -> tuple[int, int, int] | None:
    """The first pair of charts whose UV triangles overlap (`chart_overlaps`), as (a, b, pixels), else None.

    tri (F, 3, 2) UVs in [0, 1]^2 of one image side, chart (F,).
    """
    pairs = chart_overlaps(tri, chart, resolution, tolerance)
    return next(((a, b, n) for (a, b), n in pairs.items()), None)


# the complete fix for UVs no chart mapping can use (folded islands, overlaps two sides cannot part): the
# mesh unwrapped anew (pbc.geometry.garment.unwrap, read where pbc.geometry.garment.placement reads the OBJ)
UNWRAP_FIX = "garment.uvs=unwrap"


def flat_corners(mesh: ObjMesh, island: np.ndarray, names: list[str], where: str) -> np.ndarray:
    """(F, 3, 2) each face's UV corners with every mirrored island turned back (u negated: the rest shape must
    not be inverted). One ValueError naming the file, the line and the fix for an island folded over itself (its
    triangles turn both ways in UV)."""
    corners = mesh.uv[mesh.face_uv]  # a copy: advanced indexing
    area = signed_uv_area(corners)
    for k, name in enumerate(names):
        a = area[island == k]
        sign = 1.0 if a.sum() >= 0 else -1.0
        bad = np.flatnonzero((island == k) & (sign * area <= 0))
        if len(bad):
            raise ValueError(f"{where}: line {mesh.face_line[bad[0]]}: UV island '{name}' is folded over "
                             f"({len(bad)} triangles turn the other way or have zero UV area); unwrap the mesh "
                             f"anew with {UNWRAP_FIX} (or re-unwrap it in your tool so the piece lies flat)")
        if sign < 0:
            corners[island == k, :, 0] *= -1.0
    return corners


def layout_sides(pattern: np.ndarray, face_side: np.ndarray, uv_padding: float) -> tuple[np.ndarray, float]:
    """The pbc image layout of a flat pattern: (uvp (F, 3, 2) in [0, 1]^2 per side, v = 0 at the top, and
    uv_scale, the pattern length one image side spans). pattern (F, 3, 2) any unit, y up; face_side (F,) int.
    One uv_scale for all sides; each side centred in its image with uv_padding left empty at every border."""
    if not 0.0 <= uv_padding < 0.5:
        raise ValueError(f"garment.uv_padding must be in [0, 0.5), got {uv_padding}")
    sides = np.unique(face_side)
    extent = [np.ptp(pattern[face_side == s].reshape(-1, 2), axis=0).max() for s in sides]
    uv_scale = float(max(extent)) / (1.0 - 2.0 * uv_padding)
    uvp = np.empty_like(pattern)
    for s in sides:
        sel = face_side == s
        pts = pattern[sel].reshape(-1, 2)
        centre = 0.5 * (pts.min(0) + pts.max(0))
        uvp[sel, :, 0] = 0.5 + (pattern[sel, :, 0] - centre[0]) / uv_scale
        uvp[sel, :, 1] = 0.5 - (pattern[sel, :, 1] - centre[1]) / uv_scale  # pbc: v = 0 at the top
    return uvp, uv_scale


def side_clash(uvp: np.ndarray, face_side: np.ndarray, chart: np.ndarray,
               resolution: int = OVERLAP_RESOLUTION) -> tuple[int, int, int, int] | None:
    """The first two charts overlapping on one image side, as (side, a, b, pixels at resolution), else None.
    uvp (F, 3, 2) the laid-out UVs (`layout_sides`), face_side (F,), chart (F,)."""
    for s in np.unique(face_side):
        sel = np.flatnonzero(face_side == s)
        clash = overlapping_charts(uvp[sel], chart[sel], resolution)
        if clash is not None:
            return (int(s), *clash)
    return None


def _two_colouring(n: int, edges: set[tuple[int, int]], preferred: np.ndarray) -> np.ndarray | None:
    """(n,) sides 0 / 1 with no edge inside one side, each connected component coloured the way that keeps
    the most of ``preferred`` (n,) (a tie: its lowest node keeps its own), or None when an odd cycle forbids it."""
    adj: list[list[int]] = [[] for _ in range(n)]
    for a, b in edges:
        adj[a].append(b)
        adj[b].append(a)
    colour = -np.ones(n, np.int64)
    for start in range(n):
        if colour[start] >= 0:
            continue
        colour[start], comp, stack = 0, [start], [start]
        while stack:
            k = stack.pop()
            for m in adj[k]:
                if colour[m] < 0:
                    colour[m] = 1 - colour[k]
                    comp.append(m)
                    stack.append(m)
                elif colour[m] == colour[k]:
                    return None
        keep = int((colour[comp] == preferred[comp]).sum())
        if 2 * keep < len(comp) or (2 * keep == len(comp) and colour[start] != preferred[start]):
            colour[comp] = 1 - colour[comp]
    return colour


def chart_sides(corners: np.ndarray, island: np.ndarray, preferred: np.ndarray, resolution: int = OVERLAP_RESOLUTION,
                uv_padding: float = UV_PADDING) -> np.ndarray | None:
    """(C,) image side per chart such that no two charts on one side overlap, as `garment_from_mesh` checks
    them (its layout, its resolution), else None when no two sides can part them: the overlap graph of the
    charts (`chart_overlaps`, all charts laid on one image) 2-coloured, each connected group of charts put the
    way most of them prefer (``preferred`` (C,) 0 / 1), then the layout checked and any pair it still finds
    overlapping joined to the graph. corners (F, 3, 2) flat UVs (`flat_corners`), island (F,) chart per face."""
    n = int(island.max()) + 1
    uvp, _ = layout_sides(corners, np.zeros(len(island), np.int64), uv_padding)
    edges = set(chart_overlaps(uvp, island, resolution))
    while True:
        sides = _two_colouring(n, edges, np.asarray(preferred, np.int64))
        if sides is None:
            return None
        clash = side_clash(layout_sides(corners, sides[island], uv_padding)[0], sides[island], island, resolution)
        if clash is None:
            return sides
        _, a, b, _ = clash
        edges.add((min(a, b), max(a, b)))


def suggested_charts(mesh: ObjMesh, preferred: Mapping[str, int] | None = None, resolution: int = OVERLAP_RESOLUTION,
                     uv_padding: float = UV_PADDING, where: str = "<obj>") -> dict[str, int] | None:
    """A complete ``garment.charts`` (every chart name -> image side) that `garment_from_mesh` takes without an
    overlap, keeping each chart's side in ``preferred`` where it can (missing names, or None: charts named
    back* prefer 1, the others 0); None when none exists (an island folded over, or overlaps no two sides can
    part): then the fix is `UNWRAP_FIX`."""
    island = uv_islands(mesh.faces, mesh.uv[mesh.face_uv])
    names = chart_names(island, mesh.face_group, mesh.groups)
    try:
        corners = flat_corners(mesh, island, names, where)
    except ValueError:
        return None
    given = dict(preferred or {})
    want = np.array([int(given.get(n, n.lower().startswith("back"))) for n in names], np.int64)
    sides = chart_sides(corners, island, want, resolution, uv_padding)
    return None if sides is None else {n: int(s) for n, s in zip(names, sides, strict=True)}


def charts_fix(suggestion: dict[str, int] | None) -> str:
    """The overrides that make a garment's charts pass the overlap check, in words: the complete
    ``garment.charts={...}`` of `suggested_charts` or `UNWRAP_FIX`, or `UNWRAP_FIX` alone when it found none."""
    if suggestion is None:
        return f"{UNWRAP_FIX} (no two image sides keep these UVs apart: the mesh is unwrapped anew)"
    mapping = "garment.charts={" + ",".join(f"{k}:{v}" for k, v in suggestion.items()) + "}"
    return f"{mapping} (every chart on a side that keeps it apart), or {UNWRAP_FIX} (the mesh unwrapped anew)"


def import_garment(path, charts: Mapping[str, int] | None = None, uv_unit="auto", position_unit="m",
                   position_offset=(0.0, 0.0, 0.0), uv_padding: float = UV_PADDING,
                   overlap_resolution: int = OVERLAP_RESOLUTION, uv_unit_tolerance: float | None = None):
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
                      position_unit="m", position_offset=(0.0, 0.0, 0.0), uv_padding: float = UV_PADDING,
                      overlap_resolution: int = OVERLAP_RESOLUTION, uv_unit_tolerance: float | None = None):
    """`import_garment` of an OBJ already parsed (`where` names it in errors): a garment whose positions
    come from elsewhere (pbc.geometry.garment.mhclo fits them to the body) or a piece cut from an outfit."""
    check_mesh(mesh, where)
    island = uv_islands(mesh.faces, mesh.uv[mesh.face_uv])
    names = chart_names(island, mesh.face_group, mesh.groups)
    # each island is one flat piece: its triangles all turn the same way in UV; mixed signs are a fold
    corners = flat_corners(mesh, island, names, where)
    area = signed_uv_area(corners)
    # chart -> image side
    if charts is None:
        side_of = {n: int(n.lower().startswith("back")) for n in names}
    else:
        side_of = {str(k): int(v) for k, v in dict(charts).items()}
        missing = [n for n in names if n not in side_of]
        if missing:
            fix = charts_fix(suggested_charts(mesh, side_of, overlap_resolution, uv_padding, where))
            raise ValueError(f"{where}: chart(s) {missing} have no image side; the charts are {names} "
                             f"(named by their `g` group, numbered when a group has several UV islands): "
                             f"map every one, e.g. {fix}")
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
    uvp, uv_scale = layout_sides(corners * scale, face_side, uv_padding)
    clash = side_clash(uvp, face_side, island, overlap_resolution)
    if clash is not None:
        s, a, b, n = clash
        fix = charts_fix(suggested_charts(mesh, side_of, overlap_resolution, uv_padding, where))
        raise ValueError(f"{where}: UV islands '{names[a]}' and '{names[b]}' overlap ({n} px at "
                         f"{overlap_resolution}) on image side {s}; fix: {fix}")

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
