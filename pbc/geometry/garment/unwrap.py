"""UVs for a garment mesh: xatlas charts laid out on pbc's two image sides, and the choice between them and the
front/back projection.

One job: a mesh without usable UVs (none in the file, or ``garment.uvs=unwrap``) gets charts the importer
takes. Each face goes to the front or the back image side by its outward normal (`outward_side`, as the
projection decides), and each side is unwrapped and packed by xatlas on its own at one texel density
(``garment.unwrap.texels_across`` over the square root of the whole mesh's area), so the two sides share one
``uv_scale`` and no two charts of a side overlap. The cloth's rest shape is its flat pattern, so a layout's
distortion against the 3D mesh is rest-shape error: `face_distortion` measures it per face, and
`charted_mesh` keeps the projection only where it is no worse and its charts do not overlap on a side.
Every number comes from ``garment.unwrap`` (conf/garment/obj.yaml), read into `UnwrapSettings`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

import numpy as np
import xatlas

from pbc.geometry.garment.obj_import import (
    OVERLAP_RESOLUTION,
    UV_PADDING,
    layout_sides,
    outward_side,
    projected_charts,
    side_clash,
)
from pbc.geometry.meshio import ObjMesh
from pbc.geometry.meshops import signed_uv_area, uv_islands

# garment.uvs: where a garment OBJ's UVs come from (pbc.core.validate checks the setting against the same two)
UV_SOURCES = ("file", "unwrap")

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class UnwrapSettings:
    """The ``unwrap`` block of conf/garment/obj.yaml (defaults mirror it; a test keeps them equal)."""

    texels_across: int = 1024  # texel density: the square root of the mesh's 3D area spans this many texels
    padding: int = 4  # texels left empty round every chart
    max_iterations: int = 4  # xatlas chart-growing passes (more merge small charts into their neighbours)
    max_cost: float = 2.0  # xatlas: a chart stops growing where adding a face costs more
    normal_deviation_weight: float = 2.0  # xatlas: cost of a face turned away from its chart's normal
    percentile: float = 95.0  # the distortion compared: this percentile of the faces' |log area ratio|


def unwrap_settings_from_config(cfg: Mapping | None) -> UnwrapSettings:
    """UnwrapSettings from a ``garment.unwrap`` config node (missing keys, or None: the defaults)."""
    cfg = dict(cfg or {})
    known = {f.name for f in fields(UnwrapSettings)}
    unknown = set(cfg) - known
    if unknown:
        raise ValueError(f"unknown garment.unwrap settings {sorted(unknown)}; known: {sorted(known)} "
                         "(conf/garment/obj.yaml)")
    return UnwrapSettings(**cfg)


def face_distortion(points: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How each face's UV triangle differs from its 3D one, past one scale for the whole layout.

    points (F, 3, 3) the faces' corners in 3D, uv (F, 3, 2) the same corners in UV, any units. Returns
    (area_ratio (F,), anisotropy (F,)): each face's UV/3D area ratio over the whole mesh's (1 everywhere for a
    layout that keeps areas up to one scale, as ``garment.uv_unit=auto`` scales it), and the ratio of the larger
    to the smaller singular value of its 3D->UV map (1: angles kept; inf: the face flattened onto a line). A face
    with no 3D area gets nan in both.
    """
    e1, e2 = points[:, 1] - points[:, 0], points[:, 2] - points[:, 0]
    n1 = np.linalg.norm(e1, axis=1)
    x = e1 / np.where(n1 > 0, n1, 1.0)[:, None]
    y = e2 - (e2 * x).sum(1, keepdims=True) * x
    ny = np.linalg.norm(y, axis=1)
    y = y / np.where(ny > 0, ny, 1.0)[:, None]
    # the 3D triangle in its own plane (columns e1, e2) and in UV: (F, 2, 2)
    p2 = np.stack([np.stack([(e1 * x).sum(1), (e1 * y).sum(1)], 1), np.stack([(e2 * x).sum(1), (e2 * y).sum(1)], 1)],
                  2)
    u2 = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], 2)
    det_p = np.linalg.det(p2)
    ok = np.abs(det_p) > 0
    jac = np.full_like(p2, np.nan)
    jac[ok] = u2[ok] @ np.linalg.inv(p2[ok])
    s = np.full((len(points), 2), np.nan)
    s[ok] = np.linalg.svd(jac[ok], compute_uv=False)
    a3, auv = 0.5 * np.abs(det_p), 0.5 * np.abs(np.linalg.det(u2))
    with np.errstate(divide="ignore", invalid="ignore"):
        area_ratio = np.where(ok, auv / np.where(ok, a3, 1.0), np.nan) / (auv[ok].sum() / a3[ok].sum())
        anisotropy = s[:, 0] / s[:, 1]
    return area_ratio, anisotropy


def distortion_numbers(points: np.ndarray, uv: np.ndarray, percentile: float) -> tuple[float, float]:
    """(area, angle): the ``percentile`` of the faces' |log area_ratio| and of their log anisotropy
    (`face_distortion` of points (F, 3, 3) and uv (F, 3, 2)); faces without 3D area left out."""
    area_ratio, anisotropy = face_distortion(points, uv)
    with np.errstate(divide="ignore"):
        return (float(np.nanpercentile(np.abs(np.log(area_ratio)), percentile)),
                float(np.nanpercentile(np.log(anisotropy), percentile)))


def _side_atlas(points: np.ndarray, faces: np.ndarray, settings: UnwrapSettings, texels_per_unit: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """One side unwrapped and packed by xatlas: (uv (T, 2) in the mesh's length units, face_uv (F, 3) into uv),
    every chart turning the way its faces are wound (none mirrored). points (V, 3), faces (F, 3) of the side.

    xatlas flattens some charts mirrored and packs by swapping u and v (a mirror too), and its flattening keeps a
    chart's area only roughly, so the charts are flattened first, the mirrored ones turned back, each scaled to its
    3D area, packed without quarter turns, and each put where the packer put it unscaled."""
    chart = xatlas.ChartOptions()
    chart.max_iterations = int(settings.max_iterations)
    chart.max_cost = float(settings.max_cost)
    chart.normal_deviation_weight = float(settings.normal_deviation_weight)
    pack = xatlas.PackOptions()
    pack.texels_per_unit = float(texels_per_unit)
    pack.padding = int(settings.padding)
    pack.resolution = 0  # one atlas as large as the charts need at that density

    def units(atlas: xatlas.Atlas) -> tuple[np.ndarray, np.ndarray]:
        # xatlas writes UVs over its atlas's width and height: back to texels, then to the mesh's units
        _, face_uv, uv = atlas.get_mesh(0)
        return (uv.astype(np.float64) * np.array([atlas.width, atlas.height], np.float64) / texels_per_unit,
                face_uv.astype(np.int64))

    flat = xatlas.Atlas()
    flat.add_mesh(points.astype(np.float32), faces.astype(np.uint32))
    flat.generate(chart, pack)
    uv, face_uv = units(flat)
    corners = uv[face_uv]
    island = uv_islands(faces, corners)
    signed = np.bincount(island, weights=signed_uv_area(corners))
    t = points[faces]
    area = np.bincount(island, weights=0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1))
    for k in range(len(signed)):
        ids = np.unique(face_uv[island == k])
        if signed[k] < 0:
            uv[ids, 0] *= -1.0
        if abs(signed[k]) > 0:  # each chart's UV area its 3D area: one density on every chart of both sides
            uv[ids] *= np.sqrt(area[k] / abs(signed[k]))
    pack.rotate_charts = False  # a quarter turn is a swap of u and v: a mirror
    packed = xatlas.Atlas()
    packed.add_uv_mesh(uv.astype(np.float32), face_uv.astype(np.uint32))
    packed.generate(xatlas.ChartOptions(), pack)
    placed, placed_face_uv = units(packed)
    if not np.array_equal(placed_face_uv, face_uv):
        raise AssertionError("xatlas packed a UV mesh into other vertices than it was given")
    # the packer fits each chart to whole texels (up to one texel off in each direction): each chart is put where
    # it was packed by the turn and shift that fit best (no scale), so every chart keeps its own area
    for k in range(len(signed)):
        ids = np.unique(face_uv[island == k])
        a, b = uv[ids] - uv[ids].mean(0), placed[ids] - placed[ids].mean(0)
        u, _, vt = np.linalg.svd(a.T @ b)
        turn = u @ vt
        if np.linalg.det(turn) < 0:  # the packer never mirrors (rotate_charts off): the nearest turn
            turn = u @ np.diag([1.0, -1.0]) @ vt
        placed[ids] = a @ turn + placed[ids].mean(0)
    return placed, face_uv


def unwrapped_charts(mesh: ObjMesh, settings: UnwrapSettings) -> ObjMesh:
    """The mesh (its vertices as modelled, any unit: y up, z forward) with xatlas UVs in its own length units:
    the faces of each image side (`outward_side`) unwrapped and packed apart at one texel density, so a chart's
    UV area is its 3D area on both sides and no two charts of a side overlap. Groups ``front`` and ``back`` (the
    charts are named front, front_2, ..., back, back_2, ...: the default ``garment.charts`` puts back* on the back
    image); no chart is mirrored (the importer would turn it back about u = 0, onto another). Returns the ObjMesh
    with uv (T, 2), face_uv (F, 3) and face_group (F,) replaced."""
    p, f = mesh.vertices, mesh.faces
    side = outward_side(p, f)
    t = p[f]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
    texels_per_unit = float(settings.texels_across) / max(float(np.sqrt(area)), np.finfo(float).tiny)
    uv_parts, face_uv = [], np.zeros_like(f)
    count = 0
    for s in (0, 1):
        sel = np.flatnonzero(side == s)
        if not len(sel):
            continue
        used, local = np.unique(f[sel], return_inverse=True)
        uv, fuv = _side_atlas(p[used], local.reshape(-1, 3), settings, texels_per_unit)
        uv_parts.append(uv)
        face_uv[sel] = fuv + count
        count += len(uv)
    uv = np.concatenate(uv_parts)
    return replace(mesh, uv=uv, face_uv=face_uv, face_group=side, groups=["front", "back"])


@dataclass
class Charting:
    """Which layout `charted_mesh` kept, and the numbers it chose by."""

    kept: str  # "projection" or "xatlas"
    projection_area: float  # the percentile of |log area ratio| of the projection (UnwrapSettings.percentile)
    xatlas_area: float  # the same of xatlas's layout
    projection_angle: float  # the same percentile of log anisotropy
    xatlas_angle: float
    projection_clash: str | None  # two projected charts overlapping on a side, in words, else None
    charts: dict  # side name -> chart count of the kept layout
    seconds: float = 0.0  # time taken for both layouts and their measures

    def line(self, percentile: float) -> str:
        why = (f"the projection's charts overlap ({self.projection_clash})" if self.projection_clash else
               "the projection distorts no more" if self.kept == "projection" else "the projection distorts more")
        counts = ", ".join(f"{n} {k} side" for k, n in self.charts.items())
        return (f"charts by {self.kept} ({counts}): {why}; p{percentile:g} |log area ratio| projection "
                f"{self.projection_area:.3f}, xatlas {self.xatlas_area:.3f} (log anisotropy "
                f"{self.projection_angle:.3f}, {self.xatlas_angle:.3f}); {self.seconds:.1f} s")


def _side_counts(mesh: ObjMesh) -> dict:
    island = uv_islands(mesh.faces, mesh.uv[mesh.face_uv])
    side_of = np.zeros(int(island.max()) + 1, np.int64)
    side_of[island] = mesh.face_group
    return {"front": int((side_of == 0).sum()), "back": int((side_of == 1).sum())}


def charted_mesh(mesh: ObjMesh, settings: UnwrapSettings, uv_padding: float = UV_PADDING,
                 overlap_resolution: int = OVERLAP_RESOLUTION) -> tuple[ObjMesh, Charting]:
    """The mesh (as modelled, its own UVs ignored) charted for the importer: its front/back projection
    (`projected_charts`) when no two of its charts overlap on a side (laid out as the importer lays them:
    ``uv_padding``, checked at ``overlap_resolution``) and its area distortion (`distortion_numbers`) is no worse
    than xatlas's (`unwrapped_charts`), else xatlas's charts. Returns the charted ObjMesh and what was chosen and
    why (`Charting`)."""
    start = time.perf_counter()
    t = mesh.vertices[mesh.faces]
    projected = projected_charts(mesh)
    unwrapped = unwrapped_charts(mesh, settings)
    pa, pg = distortion_numbers(t, projected.uv[projected.face_uv], settings.percentile)
    xa, xg = distortion_numbers(t, unwrapped.uv[unwrapped.face_uv], settings.percentile)
    island = uv_islands(projected.faces, projected.uv[projected.face_uv])
    uvp, _ = layout_sides(projected.uv[projected.face_uv], projected.face_group, uv_padding)
    clash = side_clash(uvp, projected.face_group, island, overlap_resolution)
    said = None if clash is None else f"{clash[3]} px on the {('front', 'back')[clash[0]]} side"
    kept = projected if clash is None and pa <= xa else unwrapped
    how = Charting("projection" if kept is projected else "xatlas", pa, xa, pg, xg, said, _side_counts(kept))
    how.seconds = time.perf_counter() - start
    return kept, how


def charted_as_asked(mesh: ObjMesh, gcfg, where: str) -> ObjMesh:
    """The mesh with the UVs ``garment.uvs`` asks for: the file's (``file``, the default), or, when it has none or
    ``unwrap`` is asked, `charted_mesh`'s (settings ``garment.unwrap``, ``garment.uv_padding``), said in the log. A
    ``garment.uvs`` of another value is one ValueError naming the two."""
    uvs = gcfg.get("uvs") or "file"
    if uvs not in UV_SOURCES:
        raise ValueError(f"{where}: garment.uvs={uvs!r}: expected one of {list(UV_SOURCES)} (file: the OBJ's own UVs, "
                         "unwrapped only when it has none; unwrap: the mesh unwrapped anew)")
    if uvs == "file" and len(mesh.uv):
        return mesh
    # charted as modelled (the garment's own pose: an A-posed sleeve would cover the side in a projection)
    why = "garment.uvs=unwrap, the file's UVs ignored" if len(mesh.uv) else "no UVs"
    settings = unwrap_settings_from_config(gcfg.get("unwrap"))
    padding = gcfg.get("uv_padding")
    charted, how = charted_mesh(mesh, settings, UV_PADDING if padding is None else float(padding))
    log.info("%s: %s: %s", where, why, how.line(settings.percentile))
    return charted
