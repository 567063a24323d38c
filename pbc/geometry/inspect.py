"""What a user's garment OBJ is, before anything is draped: its charts (where each sits and faces,
its 3D and UV areas, the uv_unit that makes them agree), its distance to the body and the shrink-wrap's
stretch per chart, the sleeves' angle against the body's rest arms, the settings to paste, and two
pictures; and an outfit in one mesh cut into its pieces, one OBJ each, named by where they sit.

    pbc garment inspect my.obj [body=... garment.uv_unit=...] --out figures/
    pbc garment split outfit.obj --out pieces/

The measurements are pbc.geometry.garment.checks's, the ones the import and the shrink-wrap check.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from pathlib import Path

import matplotlib
import numpy as np
import torch
from matplotlib import patheffects
from matplotlib.collections import PolyCollection
from omegaconf import OmegaConf

from pbc.core.io import atomic_path
from pbc.geometry.body.anny import long_sleeves_rest
from pbc.geometry.body.base import Body, body_sdf
from pbc.geometry.cage.auto import auto_cage
from pbc.geometry.garment.checks import (
    FaceLimits,
    LimbCloth,
    body_region,
    droop_deg,
    face_cause,
    face_patches,
    face_stretch,
    faces_past,
    patch_stretch,
    rest_arm_directions,
    sleeve_axes,
)
from pbc.geometry.garment.obj_import import (
    UNWRAP_FIX,
    UV_PADDING,
    chart_names,
    check_mesh,
    garment_from_mesh,
    suggested_charts,
)
from pbc.geometry.garment.placement import Placement, has_rest_turn, placed_mesh, trouser_leg_stance
from pbc.geometry.garment.unwrap import charted_as_asked
from pbc.geometry.meshio import ObjMesh, read_obj
from pbc.geometry.meshops import face_areas, surface_distance, uv_islands
from pbc.geometry.shrinkwrap import REGIONS, wrap_with_regions
from pbc.geometry.units import metres_per_unit, name_unit, uv_unit_from_areas

# a direction whose share of a chart's summed outward normal is below this faces no one way ("all round")
FACING_MIN = 0.35
# the pictures' legend names at most this many charts (the largest): a picture stays under 2,000 px wide
LEGEND_CHARTS = 20
FACES_LISTED = 3  # the faces past the face limit named one by one


@dataclass
class ChartRow:
    id: int
    name: str
    centroid: np.ndarray  # (3,) m, body frame
    facing: str  # front / back / left / right / up / down / all round
    area_3d: float  # m^2
    area_uv: float  # UV units^2 (the file's)
    uv_unit: float  # metres per UV unit that makes the two agree
    distance_max: float  # m, the farthest vertex from the rest body (negative: inside)
    region: str  # the body region at that vertex
    stretch: float | None = None  # the shrink-wrap's largest patch stretch in this chart
    face_stretch: float | None = None  # the shrink-wrap's largest face stretch in this chart (area ratio)
    wrapped_on: str | None = None  # the body part (shrinkwrap.REGIONS) most of its vertices are wrapped on


@dataclass
class Report:
    path: Path
    rows: list[ChartRow]
    sleeves: dict
    arm_droop_deg: float
    uv_range: float
    stated_unit: str
    suggest_charts: dict[str, int] | None  # every chart -> its image side; None: no mapping passes (UNWRAP_FIX)
    suggest_unit: str
    suggest_pose: str
    # the rest pose to make the garment on (garment.made_on_rest, keys of body.rest), where its sleeves or
    # trouser legs are off a turnable rest body's limbs and nothing else is: None when not needed or not possible
    suggest_made_on: dict | None = None
    notes: list[str] = field(default_factory=list)
    # the faces the shrink-wrap stretches past garment.shrinkwrap.max_face_stretch, worst first, at most
    # FACES_LISTED: {face, stretch, principal, chart, patch, where, vertices (1-based), cause}
    bad_faces: list[dict] = field(default_factory=list)
    faces_past: int = 0  # how many faces pass it
    # for the pictures
    positions: np.ndarray | None = None
    faces: np.ndarray | None = None
    face_chart: np.ndarray | None = None
    uv_corners: np.ndarray | None = None
    body_vertices: np.ndarray | None = None
    placement: Placement | None = None  # how a tool's OBJ was put on the body (None: as given)
    mesh: ObjMesh | None = None  # the garment as measured: metres, on the rest body (what fitted.obj holds)


def _facing(normal_sum: np.ndarray, area: float) -> str:
    k = int(np.abs(normal_sum).argmax())
    if np.linalg.norm(normal_sum) < FACING_MIN * area:
        return "all round"
    return (("right", "left"), ("down", "up"), ("back", "front"))[k][int(normal_sum[k] > 0)]


def inspect_garment(path, gcfg, body: Body, wrap: bool = True) -> Report:
    """Measure a garment OBJ against the rest body (see the module docstring). gcfg: the garment config
    node (position_unit / position_offset / uv_unit / charts / shrinkwrap); wrap: also run the shrink-wrap
    (seconds) for its stretch per chart. Nothing is refused here: the numbers are what the checks read."""
    path = Path(path)
    if gcfg.get("kind") == "obj":  # a tool's OBJ as the fit places it, in metres (MakeHuman clothes come fitted)
        mesh, placement = placed_mesh(path, gcfg, body)
        p = mesh.vertices
    else:
        mesh, placement = charted_as_asked(read_obj(path, "garment OBJ", require_uv=False), gcfg, str(path)), None
        unit = gcfg.get("position_unit") or "m"
        p = (mesh.vertices * metres_per_unit("m" if unit == "auto" else unit, "garment.position_unit")
             + np.asarray(gcfg.get("position_offset") or (0.0, 0.0, 0.0)))
    check_mesh(mesh, str(path))
    f = mesh.faces
    corners = mesh.uv[mesh.face_uv]
    island = uv_islands(f, corners)
    names = chart_names(island, mesh.face_group, mesh.groups)
    a3 = face_areas(p, f)
    auv = face_areas(corners.reshape(-1, 2), np.arange(3 * len(f)).reshape(-1, 3))
    # outward normals: away from the body's vertical axis (x = z = 0 in the body frame), whatever way the
    # file winds its faces: right for a panel alone, and a tube's (sleeve, leg) sum to "all round"
    t = p[f]
    n = 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    out = t.mean(1)
    out[:, 1] = 0.0
    n = n * np.sign(np.einsum("fk,fk->f", n, out))[:, None]
    with torch.no_grad():
        gap = body_sdf(body, torch.eye(3).expand(1, body.skeleton.num_joints, 3, 3),
                       torch.as_tensor(p, dtype=torch.float32)[None])[0].double().numpy()
    rows = []
    for c, name in enumerate(names):
        sel = island == c
        vid = np.unique(f[sel])
        k = vid[int(gap[vid].argmax())]
        rows.append(ChartRow(id=c, name=name, centroid=np.average(t[sel].mean(1), axis=0, weights=a3[sel]),
                             facing=_facing(n[sel].sum(0), a3[sel].sum()), area_3d=float(a3[sel].sum()),
                             area_uv=float(auv[sel].sum()), uv_unit=uv_unit_from_areas(a3[sel].sum(), auv[sel].sum()),
                             distance_max=float(gap[k]), region=body_region(body, p[k])))
    uv_range = float(np.ptp(mesh.uv[np.unique(mesh.face_uv)], axis=0).max())
    stated = str(gcfg.get("uv_unit", "auto"))
    fit_all = uv_unit_from_areas(a3.sum(), auv.sum())
    if stated != "auto" and max(metres_per_unit(_number(stated), "garment.uv_unit") / fit_all,
                                fit_all / metres_per_unit(_number(stated), "garment.uv_unit")) <= 1.25:
        unit = stated
    else:
        unit = "auto" if uv_range <= 1.0 else name_unit(fit_all)
    # every chart on a side where no other overlaps it, its facing kept where it can be (back -> 1, front -> 0; a
    # chart facing another way keeps its name's side: back* -> 1, as an unwrap names them)
    padding = gcfg.get("uv_padding")
    prefer = {r.name: int(r.facing == "back") for r in rows if r.facing in ("front", "back")}
    charts = suggested_charts(mesh, prefer,
                              uv_padding=UV_PADDING if padding is None else float(padding), where=str(path))
    sleeves = sleeve_axes(p, f, body, LimbCloth.from_config(gcfg.shrinkwrap))
    # the rest arms as the sleeves are compared with them (their skin there), else the arm bones
    arm_droop = (float(np.mean([a["arm_droop_deg"] for a in sleeves.values()])) if sleeves
                 else droop_deg(rest_arm_directions(body)["left"]))
    if gcfg.get("kind") == "mhclo":
        pose = "MakeHuman clothes are fitted to the body's own rest pose by their binding: keep it"
    elif sleeves:
        droop = float(np.mean([a["droop_deg"] for a in sleeves.values()]))
        pose = (f"the garment's sleeves point {droop:.0f} degrees below the horizontal, the body's rest arms "
                f"{arm_droop:.0f}: " + ("they match (keep the body's rest pose)" if abs(droop - arm_droop) <= 10 else
                                        f"rest pose with the arms {droop:.0f} degrees down (l_arm and r_arm lowered "
                                        f"{droop - arm_droop:.0f} degrees), or rotate the sleeves onto the rest arms"))
    else:
        pose = "no sleeves found beyond the body's arm joints: the body's rest pose does not matter for them"
    made_on = _made_on_rest(gcfg, body, placement, sleeves, p, f)
    if made_on is not None:
        limbs = ("with the arms {arm_angle_deg} degrees down" if "arm_angle_deg" in made_on
                 else "with each thigh {legs_apart_deg} degrees outward").format(**made_on)
        why = ("it sits on the body otherwise" if placement.kept else
               f"placement turned its sleeves {max(placement.arm_turn_deg.values()):.0f} degrees onto the rest arms, "
               "and a drape folds a shirt round lowered arms where re-skinning stretches it")
        pose += f"; {why}, so make it on the body {limbs} and drape it onto the rest: {made_on_override(made_on)}"
    report = Report(path=path, rows=rows, sleeves=sleeves, arm_droop_deg=arm_droop, uv_range=uv_range,
                    stated_unit=stated, suggest_charts=charts, suggest_unit=unit, suggest_pose=pose,
                    suggest_made_on=made_on,
                    positions=p, faces=f, face_chart=island, uv_corners=corners,
                    body_vertices=body.vertices.double().cpu().numpy(), placement=placement,
                    mesh=replace(mesh, vertices=p))
    if placement is not None:
        report.notes += placement.lines()
    if charts is None:
        report.notes.append(f"no garment.charts keeps these UVs apart on two image sides (or an island is folded "
                            f"over): {UNWRAP_FIX} unwraps the mesh anew")
    if wrap and charts is not None:
        _wrap_stretch(report, path, gcfg, body, charts, unit, mesh, island)
    return report


def made_on_override(made_on: dict) -> str:
    """The override of a ``garment.made_on_rest`` node: {arm_angle_deg: 0, ...} -> garment.made_on_rest={...}."""
    return "garment.made_on_rest={" + ",".join(f"{k}:{str(v).lower() if isinstance(v, bool) else v}"
                                                for k, v in made_on.items()) + "}"


def _made_on_rest(gcfg, body: Body, placement: Placement | None, sleeves: dict, points: np.ndarray,
                  faces: np.ndarray) -> dict | None:
    """The rest pose (keys of body.rest) to make a tool's garment on, on a body with a rest turn (Anny's), for a
    garment whose limbs are not the body's: a top placement kept as given whose sleeves are more than the wrap
    allows (garment.shrinkwrap.max_sleeve_angle_deg) off the rest arms (the arm angle its sleeves point at), or
    trousers whose legs lean more than garment.placement.leg_rest_deg away from the thighs (each thigh turned as
    far); and a registered top whose short sleeves placement turned further than that: re-skinning leaves a wide
    shirt's sides round lowered arms, the drape folds them (the README's 5.5x against 1.19x). None otherwise:
    a long sleeve's transfer turns it at the elbow too; with placement off or a position given by hand the garment
    is where the user put it."""
    if (gcfg.get("kind") != "obj" or not has_rest_turn(body) or gcfg.get("made_on_rest") or placement is None):
        return None
    limit = (gcfg.get("shrinkwrap") or {}).get("max_sleeve_angle_deg")
    if not placement.kept:
        turned = placement.arm_turn_deg
        if (limit is None or not turned or placement.forearm_turn_deg or not placement.sleeve_droop_deg
                or max(turned.values()) <= float(limit)):
            return None
        return _straight_arms(placement.sleeve_droop_deg.values())
    if placement.kind == "bottom":
        stance = trouser_leg_stance(points, faces, body, "bottom")
        limit = (gcfg.get("placement") or {}).get("leg_rest_deg")
        if not stance or limit is None or max(abs(s["apart_deg"]) for s in stance.values()) <= float(limit):
            return None
        rest = float((body.config.get("rest") or {}).get("legs_apart_deg") or 0.0)
        return {"legs_apart_deg": int(round(rest + float(np.mean([s["apart_deg"] for s in stance.values()]))))}
    if not sleeves or limit is None or max(a["angle_deg"] for a in sleeves.values()) <= float(limit):
        return None
    return (long_sleeves_rest(body, points, float(gcfg.placement.elbow_reach))
            or _straight_arms(a["droop_deg"] for a in sleeves.values()))


def _straight_arms(droops) -> dict:
    """The rest with the arms at the sleeves' mean angle below the horizontal (degrees), forearms straight."""
    return {"arm_angle_deg": int(round(float(np.mean(list(droops))))), "straight_forearms": True}


def _number(unit: str):
    try:
        return float(unit)
    except ValueError:
        return unit


def _wrap_stretch(report: Report, path: Path, gcfg, body: Body, charts: dict, unit: str, mesh, island) -> None:
    """The shrink-wrap's largest patch and face stretch per chart, and the faces past
    garment.shrinkwrap.max_face_stretch with their place and cause (report.bad_faces), with the suggested charts
    and unit and every check off (inspect reports; the import and the wrap refuse)."""
    g = (OmegaConf.create(OmegaConf.to_container(gcfg, resolve=True)) if OmegaConf.is_config(gcfg)
         else copy.deepcopy(gcfg))
    try:
        garment, _, face_chart = garment_from_mesh(report.mesh, str(path), charts=charts, uv_unit=_number(unit),
                                                   uv_padding=float(g.get("uv_padding", 0.1)))
        cage = auto_cage(garment, int(g.patch_resolution), int(g.crop_size), int(g.margin),
                         chart_names=[r.name for r in report.rows], face_chart=face_chart,
                         **dict(g.get("autocage") or {}))
        sw = dict(g.shrinkwrap)
        sw.update(max_start_distance=None, max_sleeve_angle_deg=None, max_patch_stretch=None, max_face_stretch=None)
        x, region, _ = wrap_with_regions(garment, cage, body, OmegaConf.create(sw))
    except ValueError as err:
        report.notes.append(f"shrink-wrap stretch not measured: {err}")
        return
    f = garment.faces.cpu().numpy()
    pattern = garment.pattern().double().cpu().numpy().reshape(-1, 2)
    fp = face_patches(cage, f)
    pattern_area = face_areas(pattern, np.arange(len(pattern)).reshape(-1, 3))
    stretch = patch_stretch(face_areas(x, f), pattern_area, fp, len(cage.patches))
    ratio, principal = face_stretch(x, f, pattern.reshape(-1, 3, 2))
    # a patch belongs to the chart of most of its faces (a seam face can sit in the other chart's patch)
    owner = np.array([np.bincount(face_chart[fp == k]).argmax() if (fp == k).any() else -1
                      for k in range(len(cage.patches))])
    corner = np.repeat(face_chart, 3)
    # a part lying on the garment's own cloth is wrapped on top of it, off the skin (garment_layers)
    off_skin = surface_distance(x, body.vertices.double().cpu().numpy(), body.faces.cpu().numpy())[0] > 0.5 * float(
        g.shrinkwrap.layer_min_gap)
    for r in report.rows:
        mine = np.flatnonzero(owner == r.id)
        r.stretch = float(stretch[mine].max()) if len(mine) else None
        own = face_chart == r.id
        r.face_stretch = float(np.nan_to_num(ratio[own], nan=np.inf).max()) if own.any() else None
        verts = f.ravel()[corner == r.id]
        r.wrapped_on = REGIONS[int(np.bincount(region[verts]).argmax())] if len(verts) else None
        if len(verts) and off_skin[verts].mean() > 0.5:
            r.wrapped_on += ", on top of the garment's cloth there (a layer: collar, cuff, pocket)"
    limits = FaceLimits.from_config(g.shrinkwrap)
    if limits.limit is None:
        return
    bad = faces_past(ratio, limits.limit)
    report.faces_past = int(len(bad))
    if not len(bad):
        return
    with torch.no_grad():
        start_gap = body_sdf(body, torch.eye(3).expand(1, body.skeleton.num_joints, 3, 3),
                             garment.vertices.float()[None])[0].double().numpy()
    names = [r.name for r in report.rows]
    on = [REGIONS[int(v)] for v in region]
    for k in (int(i) for i in bad[:FACES_LISTED]):
        report.bad_faces.append({
            "face": k, "stretch": float(ratio[k]), "principal": [float(v) for v in principal[k]],
            "chart": names[int(face_chart[k])], "patch": cage.patches[int(fp[k])].name if fp[k] >= 0 else "none",
            "where": body_region(body, x[f[k]].mean(0)), "vertices": [int(v) + 1 for v in f[k]],
            "cause": face_cause(k, f, on, pattern_area, start_gap, limits)})


def format_report(report: Report, limits: dict) -> str:
    """The table and the settings to paste, as `pbc garment inspect` prints them."""
    head = (f"{'id':>3}  {'chart':<14} {'centroid (m)':<22} {'faces':<9} {'3D m^2':>8} {'UV u^2':>9} "
            f"{'uv_unit':>9} {'dist m':>7} {'stretch':>7} {'face':>7}  body region at the farthest vertex")
    lines = [f"{report.path}: {len(report.rows)} charts (UV islands), UVs span {report.uv_range:.3g} units", head]
    for r in report.rows:
        c = "[" + ", ".join(f"{v:+.2f}" for v in r.centroid) + "]"
        st = "-" if r.stretch is None else f"{r.stretch:.2f}x"
        fs = "-" if r.face_stretch is None else f"{r.face_stretch:.3g}x"
        lines.append(f"{r.id:>3}  {r.name:<14} {c:<22} {r.facing:<9} {r.area_3d:>8.4f} {r.area_uv:>9.4g} "
                     f"{r.uv_unit:>9.4g} {r.distance_max:>7.2f} {st:>7} {fs:>7}  {r.region}"
                     + ("" if r.wrapped_on is None else f"; wrapped on the {r.wrapped_on}"))
    sleeve_limit = limits.get("max_sleeve_angle_deg")
    sleeve_limit = "null (no check)" if sleeve_limit is None else sleeve_limit
    for side, a in sorted(report.sleeves.items()):
        lines.append(f"{side} sleeve: {a['angle_deg']:.1f} degrees off the body's rest arm (sleeve "
                     f"{a['droop_deg']:.1f} below the horizontal, arm {a['arm_droop_deg']:.1f}); limit "
                     f"garment.shrinkwrap.max_sleeve_angle_deg = {sleeve_limit}")
    far = [r for r in report.rows if limits.get("max_start_distance") is not None
           and r.distance_max > float(limits["max_start_distance"])]
    for r in far:
        lines.append(f"chart {r.id} '{r.name}' is {r.distance_max:.2f} m from the body (limit "
                     f"garment.shrinkwrap.max_start_distance = {limits['max_start_distance']}): {r.region}")
    if report.bad_faces:
        worst = "; ".join(
            f"face {b['face']} {b['stretch']:.1f}x (principal {b['principal'][0]:.1f} x {b['principal'][1]:.2f}), "
            f"chart '{b['chart']}', patch {b['patch']}, vertices {', '.join(map(str, b['vertices']))}, at {b['where']}"
            for b in report.bad_faces)
        lines.append(f"{report.faces_past} face{'s' if report.faces_past > 1 else ''} past "
                     f"garment.shrinkwrap.max_face_stretch = {limits.get('max_face_stretch')}x (the wrap refuses "
                     f"them: every drape would be discarded): {worst}; likely cause: {report.bad_faces[0]['cause']}")
    lines += report.notes
    charts = (UNWRAP_FIX if report.suggest_charts is None else
              "'garment.charts={" + ",".join(f"{k}:{v}" for k, v in report.suggest_charts.items()) + "}'")
    lines += ["", "suggested settings:", f"  {charts}", f"  garment.uv_unit={report.suggest_unit}",
              f"  body rest pose: {report.suggest_pose}"]
    return "\n".join(lines)


def _colours(n: int):
    return matplotlib.colormaps["tab20"](np.arange(n) % 20)


def _legend(fig, report: Report, col) -> None:
    """The legend of the LEGEND_CHARTS largest charts (3D area), "id name" beside its colour, right of the
    figure: a picture of 90 charts stays as wide as one of 4."""
    from matplotlib.patches import Patch  # noqa: PLC0415 - only the pictures need it

    rows = sorted(sorted(report.rows, key=lambda r: -r.area_3d)[:LEGEND_CHARTS], key=lambda r: r.id)
    title = "charts" if len(rows) == len(report.rows) else f"the {len(rows)} largest of {len(report.rows)} charts"
    fig.legend(handles=[Patch(color=col[r.id], label=f"{r.id} {r.name}") for r in rows], loc="center left",
               bbox_to_anchor=(1.0, 0.5), fontsize=8, title=title, title_fontsize=8, frameon=False)


def _id_label(ax, x: float, y: float, text: str, size: int) -> None:
    """A chart's id drawn on it, white-edged so it reads on any fill."""
    ax.text(x, y, text, ha="center", va="center", fontsize=size, weight="bold", zorder=3,
            path_effects=[patheffects.withStroke(linewidth=2, foreground="white")])


def save_uv_picture(report: Report, path) -> Path:
    """The UV layout (the file's UVs, v up) with each chart filled in its colour and its id on it: one panel per
    image side of the suggested charts (one panel when none passes), the title naming the chart count and a
    legend the largest (`_legend`), so the picture is as wide for 90 charts as for 4."""
    import matplotlib.pyplot as plt  # noqa: PLC0415 - pyplot is heavy; only the pictures need it

    col = _colours(len(report.rows))
    side = np.zeros(len(report.rows), np.int64)
    if report.suggest_charts is not None:
        side = np.array([report.suggest_charts.get(r.name, 0) for r in report.rows], np.int64)
    panels = sorted(set(side.tolist()))
    fig, axes = plt.subplots(1, len(panels), figsize=(7 * len(panels), 7), squeeze=False)
    named = len(report.rows) <= LEGEND_CHARTS  # few charts: each is labelled with its name too
    for ax, s in zip(axes[0], panels, strict=True):
        mine = side[report.face_chart] == s
        ax.add_collection(PolyCollection(report.uv_corners[mine], facecolors=col[report.face_chart[mine]],
                                         edgecolors="none"))
        for r in report.rows:
            if side[r.id] == s:
                c = report.uv_corners[report.face_chart == r.id].reshape(-1, 2).mean(0)
                _id_label(ax, c[0], c[1], f"{r.id} {r.name}" if named else str(r.id), 9 if named else 7)
        ax.autoscale()
        ax.set_aspect("equal")
        ax.set_xlabel("u")
        ax.set_ylabel("v")
        # the title above the panels (a figure title would stand above the whitespace of equal-aspect panels)
        where = f"image side {s} ({('front', 'back')[s]}), " if len(panels) > 1 else ""
        ax.set_title(f"{report.path.name}: UV layout, {where}{int((side == s).sum())} of {len(report.rows)} charts, "
                     "ids on them", fontsize=10)
    _legend(fig, report, col)
    return _save(fig, path)


def save_body_picture(report: Report, path) -> Path:
    """The garment on the rest body from the front and the back, coloured by chart, ids at the centroids; the
    title names the chart count, a legend the largest charts (`_legend`): as wide for 90 charts as for 4."""
    import matplotlib.pyplot as plt  # noqa: PLC0415 - pyplot is heavy; only the pictures need it

    col = _colours(len(report.rows))
    t = report.positions[report.faces]
    fig, axes = plt.subplots(1, 2, figsize=(12, 8))
    for ax, sgn, title in ((axes[0], 1.0, "front (+z towards you)"), (axes[1], -1.0, "back")):
        b = report.body_vertices
        ax.scatter(sgn * b[:, 0], b[:, 1], s=0.3, c="0.75", zorder=0)
        order = np.argsort(sgn * t.mean(1)[:, 2])  # far faces first, near faces painted over them
        poly = np.stack([sgn * t[order][..., 0], t[order][..., 1]], -1)
        ax.add_collection(PolyCollection(poly, facecolors=col[report.face_chart[order]], edgecolors="none",
                                         alpha=0.9, zorder=1))
        for r in report.rows:
            _id_label(ax, sgn * r.centroid[0], r.centroid[1], str(r.id), 10 if len(report.rows) <= LEGEND_CHARTS
                      else 7)
        ax.autoscale()
        ax.set_aspect("equal")
        # the title above the panels (a figure title would stand above the whitespace of equal-aspect panels)
        ax.set_title((f"{report.path.name} on the rest body, {len(report.rows)} charts\n" if sgn > 0 else "\n")
                     + title + " (x mirrored)" * (sgn < 0), fontsize=10)
    _legend(fig, report, col)
    return _save(fig, path)


def _save(fig, path) -> Path:
    import matplotlib.pyplot as plt  # noqa: PLC0415 - pyplot is heavy; only the pictures need it

    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
