"""The one mesh writer: garment meshes (OBJ with UVs and normals, or PLY) and plain meshes (the body);
and :func:`read_obj`, the reader that gives a textured OBJ back as written.

Every mesh pbc writes for people to open (dataset previews, the training run's ``meshes/``, pbc.evaluate,
pbc.predict) goes through :func:`write_garment_mesh` or :func:`write_mesh`, atomically. The dataset's own
``garment.obj`` (``pbc.geometry.garment.base.save_garment_obj``) is another format built from the same
:func:`obj_text`: exact floats, the pattern's raw UVs, no normals, read back bit-exact.

The garment OBJ, what a viewer (Blender, MeshLab, ``trimesh.load(path, process=False)``) needs:

    v x y z          metres, one per garment vertex, in the garment's vertex order
    vt u v           one per UV corner of the garment (seams are cut: more vt than v), an atlas
                     of both charts: the front chart in u [0, 0.5], the back chart in u [0.5, 1], v up
                     (the OBJ convention); pbc's cloth image row r, column c of chart s sits at
                     ((c / W + s) / 2, 1 - r / H)
    vn x y z         unit area-weighted vertex normals, pointing out of the garment
    g front / back   the two charts
    f v/vt/vn        triangles, counter-clockwise seen from outside

To read one back in Python: :func:`read_obj` gives the V vertices in the file's order and the face-indexed
UVs (``uv`` (T, 2), ``face_uv`` (F, 3)), so a seam vertex keeps both its charts' UVs. trimesh cannot give
both at once: ``trimesh.load(path, process=False, maintain_order=True)`` keeps the order but holds one UV
per vertex, so a seam vertex keeps one chart's UV and the faces at the seams get a corner UV from the other
chart (234 of the full shirt's 6,160 faces straddle the two charts); ``process=False`` alone splits the
seams (one vertex per (v, vt) pair, as a renderer needs); without ``process=False`` trimesh also merges
and reorders vertices. A PLY holds positions, normals and faces (binary; no UVs: PLY has one UV per
vertex and the charts are cut at the seams).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbc.core.io import atomic_path, write_text
from pbc.geometry.meshops import vertex_normals

FORMATS = (".obj", ".ply")


# the two sides of a garment's cloth image (each UV chart lies on one): `Garment.face_side` 0 and 1, and the
# OBJ groups of pbc's garment files
SIDE_NAMES = ("front", "back")


def _np(x) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def _fixed(x: float) -> str:
    return f"{x:.6f}"


def obj_text(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray | None = None,
             face_uv: np.ndarray | None = None, normals: np.ndarray | None = None,
             groups: Sequence[tuple[str, np.ndarray]] | None = None, header: Sequence[str] = (),
             number: Callable[[float], str] = _fixed) -> str:
    """Wavefront OBJ text. vertices (V, 3), faces (F, 3) 0-based, uv (T, 2) with face_uv (F, 3) into it,
    normals (V, 3) (vn i belongs to v i), groups [(name, face mask (F,) bool)] written in that order
    (faces in no group are not written), header lines written as ``# line``; ``number`` formats floats."""
    lines = [f"# {h}" for h in header]
    lines += ["v " + " ".join(map(number, p)) for p in np.asarray(vertices).tolist()]
    if uv is not None:
        lines += ["vt " + " ".join(map(number, t)) for t in np.asarray(uv).tolist()]
    if normals is not None:
        lines += ["vn " + " ".join(map(number, n)) for n in np.asarray(normals).tolist()]
    f = np.asarray(faces, dtype=np.int64) + 1
    ft = None if face_uv is None else np.asarray(face_uv, dtype=np.int64) + 1
    if normals is None:
        corner = (lambda a, t: f"{a}/{t}") if ft is not None else (lambda a, t: f"{a}")
    else:
        corner = (lambda a, t: f"{a}/{t}/{a}") if ft is not None else (lambda a, t: f"{a}//{a}")
    fts = ft.tolist() if ft is not None else [(None,) * 3] * len(f)
    for name, mask in groups or [(None, np.ones(len(f), dtype=bool))]:
        if name is not None:
            lines.append(f"g {name}")
        sel = np.flatnonzero(np.asarray(mask))
        fl = f[sel].tolist()
        for i, (a, b, c) in zip(sel.tolist(), fl, strict=True):
            ta, tb, tc = fts[i]
            lines.append(f"f {corner(a, ta)} {corner(b, tb)} {corner(c, tc)}")
    return "\n".join(lines) + "\n"


def _check_path(path: Path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in FORMATS:
        raise ValueError(f"{path}: unknown mesh format {path.suffix!r}; write one of {FORMATS}")
    return path


def _check_vertices(vertices: np.ndarray, num: int, what: str) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape != (num, 3):
        raise ValueError(f"{what}: vertices of shape {tuple(v.shape)}, expected ({num}, 3)")
    if not np.isfinite(v).all():
        raise ValueError(f"{what}: {int((~np.isfinite(v)).any(1).sum())} vertices are not finite (NaN/inf)")
    return v


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> None:
    import trimesh  # noqa: PLC0415 - trimesh loads in ~0.4 s; only a PLY export (not the default OBJ) needs it

    mesh = trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)
    with atomic_path(path) as tmp:
        tmp.write_bytes(mesh.export(file_type="ply", encoding="binary", vertex_normal=True))


def submesh(faces: np.ndarray, vertex_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces with all three corners in ``vertex_ids``: (face indices (F',), faces renumbered into
    ``vertex_ids`` order (F', 3), vertex_ids as given (V',))."""
    ids = np.asarray(vertex_ids, dtype=np.int64)
    f = np.asarray(faces, dtype=np.int64)
    where = np.full(int(max(f.max(), ids.max())) + 1, -1, dtype=np.int64)
    where[ids] = np.arange(len(ids))
    keep = np.flatnonzero((where[f] >= 0).all(1))
    return keep, where[f[keep]], ids


def write_garment_mesh(path: str | Path, garment, vertices=None, vertex_ids=None,
                       header: Sequence[str] = ()) -> Path:
    """Write a garment shape as OBJ (v, vt, vn, ``f v/vt/vn``, see the module doc) or PLY, by suffix.

    garment: a ``pbc.geometry.garment.base.Garment`` (faces, uv, face_uv, face_side); vertices (V, 3) its
    shape (default: the rest shape), a tensor or array; vertex_ids: write only the submesh of these
    vertices (a patch: its faces with all three corners inside; v in vertex_ids order, and the file's
    header lists the ids). Raises ValueError for a shape that does not fit the garment or NaNs."""
    path = _check_path(path)
    faces, uv, face_uv = _np(garment.faces), _np(garment.uv), _np(garment.face_uv)
    side = _np(garment.face_side)
    v = _check_vertices(_np(garment.vertices if vertices is None else vertices), len(_np(garment.vertices)),
                        str(path))
    normals = vertex_normals(v, faces)  # on the whole shirt: a patch's border normals stay the shirt's
    head = ["pbc garment mesh (pbc.geometry.meshio): metres; vt atlas: front u in [0, 0.5], back in [0.5, 1]",
            *header]
    if vertex_ids is not None:
        keep, faces, ids = submesh(faces, _np(vertex_ids))
        v, normals, face_uv, side = v[ids], normals[ids], face_uv[keep], side[keep]
        head.append(f"patch submesh: {len(ids)} of the garment's {len(_np(garment.vertices))} vertices, "
                    f"garment vertex ids " + " ".join(map(str, ids.tolist())))
    if path.suffix.lower() == ".ply":
        _write_ply(path, v, faces, normals)
        return path
    # one atlas: charts side by side, v flipped from pbc's image rows (v = 0 top) to OBJ's (v = 0 bottom)
    uv_side = np.zeros(len(uv), dtype=np.int64)
    uv_side[np.asarray(face_uv).reshape(-1)] = np.repeat(side, 3)
    atlas = np.stack([(uv[:, 0] + uv_side) / 2, 1 - uv[:, 1]], 1)
    groups = [(name, side == s) for s, name in enumerate(SIDE_NAMES)]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, obj_text(v, faces, atlas, face_uv, normals, groups, head))
    return path


def write_mesh(path: str | Path, vertices, faces, header: Sequence[str] = ()) -> Path:
    """Write any triangle mesh (the posed body): OBJ (v, vn, ``f v//vn``) or PLY, by suffix.
    vertices (V, 3), faces (F, 3) 0-based; tensors or arrays."""
    path = _check_path(path)
    f = _np(faces).astype(np.int64)
    v = _check_vertices(_np(vertices), len(_np(vertices)), str(path))
    normals = vertex_normals(v, f)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".ply":
        _write_ply(path, v, f, normals)
    else:
        write_text(path, obj_text(v, f, normals=normals, header=header))
    return path


# OBJ statements that carry nothing a garment needs (materials, smoothing, normals, objects, lines)
IGNORED = {"usemtl", "mtllib", "s", "o", "vn", "vp", "l", "p", "#"}
# an OBJ statement's keyword; one that is not (a number, a control byte, text of another file) is junk refused by
# its line, and so is a data keyword run into its first number (`v1.0 2 3`), which would drop a vertex unseen
STATEMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
MISTYPED = re.compile(r"(v|vt|vn|f)[0-9+-]")


@dataclass
class ObjMesh:
    """The polygons of an OBJ, triangulated; indices 0-based. Lines are 1-based, for error messages."""

    vertices: np.ndarray  # (V, 3) float64, file units
    uv: np.ndarray  # (T, 2) float64, file convention (v up)
    faces: np.ndarray  # (F, 3) int64 vertex ids
    face_uv: np.ndarray  # (F, 3) int64 vt ids
    face_group: np.ndarray  # (F,) int64 index into groups
    face_line: np.ndarray  # (F,) int64 the `f` line each triangle came from
    groups: list[str]
    vertex_line: np.ndarray  # (V,) int64 the `v` line of each vertex
    comments: list[str] = field(default_factory=list)  # the text of each whole-line `#` comment, in order


def _index(token: str, count: int, kind: str, lineno: int, where: str) -> int:
    """A 1-based (or negative, relative) OBJ index -> 0-based, with an error naming the line."""
    try:
        k = int(token)
    except ValueError:
        raise ValueError(f"{where}: line {lineno}: {kind} index {token!r} is not an integer") from None
    if k == 0 or k > count or k < -count:
        raise ValueError(f"{where}: line {lineno}: {kind} index {k} refers to no {kind} "
                         f"({count} defined so far; OBJ indices start at 1, negative ones count back)")
    return k - 1 if k > 0 else count + k


def finite_numbers(tokens: list[str], what: str, lineno: int, where: str) -> list[float]:
    """The numbers of one OBJ statement; a token that is no number, NaN or infinite is one ValueError naming
    the file and the line (a NaN vertex otherwise passes as a garment with NaN areas and charts)."""
    try:
        values = [float(x) for x in tokens]
    except ValueError:
        raise ValueError(f"{where}: line {lineno}: a {what} needs numbers, got {' '.join(tokens)!r}") from None
    if not all(math.isfinite(x) for x in values):
        raise ValueError(f"{where}: line {lineno}: the {what} {' '.join(tokens)} is not finite (NaN or inf); "
                         "fix or remove that line in the tool that exported the file and export it again")
    return values


def parse_obj(text: str, where: str = "<obj>", require_uv: bool = True) -> ObjMesh:
    """Parse OBJ text into triangles (fan triangulation of each polygon, corners keep their vt): the one OBJ
    parser of pbc (``read_obj`` reads a file through it, pbc's garment file and the importers are views of it).

    Vertices stay in the file's order, one per ``v`` line, and every face corner keeps its own ``vt``: a
    vertex on a UV seam has one UV in each chart's faces. ``where`` names the source in error messages (the
    file path); a bad statement's error names its line. ``require_uv=False`` reads a mesh with no texture
    coordinates at all (``uv`` (0, 2), ``face_uv`` all -1: the importer makes its charts); a mesh with UVs on
    some corners only is refused either way.
    """
    verts, vlines, uvs = [], [], []
    faces, fuvs, fgroups, flines = [], [], [], []
    groups: list[str] = ["default"]
    group = 0
    comments: list[str] = []
    lines = text.splitlines()
    lineno = 0
    pending = ""
    for raw_no, raw in enumerate(lines, 1):
        if raw.rstrip().endswith("\\"):  # a continued statement
            pending += raw.rstrip()[:-1] + " "
            continue
        line, pending = pending + raw, ""
        lineno = raw_no
        if line.lstrip().startswith("#"):
            comments.append(line.lstrip()[1:].strip())
            continue
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key = parts[0]
        if key == "v":
            if len(parts) < 4:
                raise ValueError(f"{where}: line {lineno}: a vertex needs x y z, got {line.strip()!r}")
            verts.append(finite_numbers(parts[1:4], "vertex", lineno, where))
            vlines.append(lineno)
        elif key == "vt":
            if len(parts) < 3:
                raise ValueError(f"{where}: line {lineno}: a texture coordinate needs u v, got {line.strip()!r}")
            uvs.append(finite_numbers(parts[1:3], "texture coordinate", lineno, where))
        elif key == "vn":  # not kept (pbc computes its normals), but a NaN there is a broken export all the same
            finite_numbers(parts[1:4], "normal", lineno, where)
        elif key == "g":
            name = parts[1] if len(parts) > 1 else "default"
            if name not in groups:
                groups.append(name)
            group = groups.index(name)
        elif key == "f":
            if len(parts) < 4:
                raise ValueError(f"{where}: line {lineno}: a face needs at least 3 corners, got {len(parts) - 1}")
            fv, ft = [], []
            for corner in parts[1:]:
                idx = corner.split("/")
                if (len(idx) < 2 or not idx[1]) and not require_uv and not uvs:
                    fv.append(_index(idx[0], len(verts), "vertex", lineno, where))
                    ft.append(-1)
                    continue
                if len(idx) < 2 or not idx[1]:
                    raise ValueError(
                        f"{where}: line {lineno}: face corner {corner!r} has no texture coordinate (no vt index); "
                        "a garment needs UVs: unwrap it and export with UVs (Blender: 'Include UVs', "
                        "Marvelous Designer / CLO: export with the 2D pattern as UV)")
                fv.append(_index(idx[0], len(verts), "vertex", lineno, where))
                ft.append(_index(idx[1], len(uvs), "texture coordinate", lineno, where))
            if len(set(fv)) != len(fv):
                raise ValueError(f"{where}: line {lineno}: the face uses a vertex twice; "
                                 "remove degenerate faces (Blender: Mesh > Clean Up > Degenerate Dissolve)")
            for k in range(1, len(fv) - 1):  # fan: every triangle keeps its corners' own vt
                faces.append((fv[0], fv[k], fv[k + 1]))
                fuvs.append((ft[0], ft[k], ft[k + 1]))
                fgroups.append(group)
                flines.append(lineno)
        elif key in IGNORED or key.startswith("#"):
            continue
        elif not STATEMENT.fullmatch(key) or MISTYPED.match(key):
            raise ValueError(f"{where}: line {lineno}: {line.strip()[:60]!r} is not an OBJ statement (a line starts "
                             "with a keyword: v, vt, vn, f, g, o, usemtl, ..., or # for a comment); fix or remove "
                             "that line and read the file again")
        # other statements (curves, surfaces, display attributes, a tool's own keywords) carry nothing a
        # garment needs
    if not verts:
        raise ValueError(f"{where}: no vertices (v lines)")
    if not faces:
        raise ValueError(f"{where}: no faces (f lines)")
    if uvs and any(-1 in t for t in fuvs):
        raise ValueError(f"{where}: some faces have texture coordinates and some have none; export every face "
                         "with UVs, or none (pbc then makes the charts)")
    if not uvs and require_uv:
        raise ValueError(f"{where}: no texture coordinates (vt lines); a garment needs UVs: unwrap it "
                         "(one island per pattern piece) and export with UVs")
    used = sorted(set(fgroups))
    remap = {g: k for k, g in enumerate(used)}
    return ObjMesh(
        vertices=np.asarray(verts, np.float64),
        uv=np.asarray(uvs, np.float64).reshape(-1, 2),
        faces=np.asarray(faces, np.int64),
        face_uv=np.asarray(fuvs, np.int64),
        face_group=np.asarray([remap[g] for g in fgroups], np.int64),
        face_line=np.asarray(flines, np.int64),
        groups=[groups[g] for g in used],
        vertex_line=np.asarray(vlines, np.int64),
        comments=comments,
    )


def not_an_obj_file(path: str | os.PathLike, what: str = "OBJ") -> str | None:
    """Why `path` is no file to read as an OBJ, in one line naming it and what to give instead: missing, or a
    folder (its OBJ files named); None for a file."""
    path = Path(path)
    if path.is_file():
        return None
    if path.is_dir():
        objs = sorted(p.name for p in path.iterdir() if p.suffix.lower() == ".obj" and p.is_file())
        inside = (f"it holds {', '.join(objs[:8])}{', ...' if len(objs) > 8 else ''}: give one of them"
                  if objs else "it holds no .obj file: give the OBJ file itself")
        return f"{path} is a folder, not a file; {inside}"
    return f"{path}: no such {what} file"


def other_mesh_format(data: bytes) -> str | None:
    """The mesh format of a file's bytes when its header says it is one an OBJ is often confused with: "PLY",
    "STL" (text `solid ...` or binary, by its triangle count), "GLB", "FBX"; None otherwise."""
    head = data[:256].lstrip()
    if head[:3].lower() == b"ply" and head[3:4] in (b"\n", b"\r"):
        return "PLY"
    if head[:5].lower() == b"solid" and head[5:6] in (b" ", b"\t", b"\n", b"\r") and b"facet" in data[:4096]:
        return "STL"
    if len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        return "STL"
    if data[:4] == b"glTF":
        return "GLB"
    if data[:18] == b"Kaydara FBX Binary":
        return "FBX"
    return None


def _lenient_text(data: bytes) -> str:
    """An OBJ's bytes as text: UTF-8 (a BOM dropped), and any line that is not UTF-8 (a Latin-1 comment, an
    object name from an old exporter) read as Latin-1, so one such byte does not refuse the file; a statement
    pbc reads is still checked by the parser, naming its line."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        pass
    lines = []
    for raw in data.split(b"\n"):
        try:
            lines.append(raw.decode("utf-8"))
        except UnicodeDecodeError:
            lines.append(raw.decode("latin-1"))
    return "\n".join(lines).removeprefix("\ufeff")


def read_obj(path: str | os.PathLike, what: str = "OBJ", require_uv: bool = True) -> ObjMesh:
    """An OBJ file parsed (``parse_obj``): any pbc garment mesh, any tool's textured OBJ. One ValueError naming
    the file and ``what`` it was read as for a file that is missing or a folder (its OBJ files named), another
    mesh format (PLY, STL, GLB, FBX: with the command that converts it) or binary (a NUL byte); a line that is
    not UTF-8 is read as Latin-1 (a comment's accent is no reason to refuse a file)."""
    path = Path(path)
    problem = not_an_obj_file(path, what)
    if problem is not None:
        raise ValueError(problem)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the {what} ({exc.strerror}); check its permissions") from None
    kind = other_mesh_format(data)
    if kind is not None:
        raise ValueError(other_format_message(path, kind))
    nul = data.find(b"\0")
    if nul >= 0:
        raise ValueError(f"{path}: the {what} is not a text OBJ file (byte {nul} is NUL: binary content): export "
                         "it as OBJ (text), not a binary format")
    return parse_obj(_lenient_text(data), str(path), require_uv)


def other_format_message(path: Path, kind: str) -> str:
    """One line for a `kind` mesh file given as an OBJ: what it is, whether trimesh reads it (its vertex and face
    counts), and the command that converts it."""
    named = path.suffix.lower() == f".{kind.lower()}"  # trimesh picks its reader by the suffix
    target = path.with_suffix(".obj") if named else path.with_name(f"{path.stem}_converted.obj")
    file_type = "" if named else f", file_type='{kind.lower()}'"
    convert = f"python -c \"import trimesh; trimesh.load('{path}'{file_type}).export('{target}')\""
    try:
        import trimesh  # noqa: PLC0415 - trimesh loads in ~0.4 s; only a mesh of another format needs it

        mesh = trimesh.load(path, file_type=kind.lower(), force="mesh", process=False)
        reads = f"trimesh reads it: {len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces" if len(
            mesh.vertices) else ""
    except Exception:  # noqa: BLE001 - any reader failure only means the line promises no conversion
        reads = ""
    article = "an" if kind in ("STL", "FBX") else "a"
    if kind == "STL":  # triangles alone: a conversion cannot give the UVs a garment needs
        return (f"{path}: this is an STL file, not an OBJ, and an STL holds no UVs, which a garment needs: "
                f"export an OBJ with UVs from the tool that made it (`{convert}` converts its shape alone"
                f"{'; ' + reads if reads else ''})")
    how = f"{reads}, so convert it" if reads else "convert it in the tool that made it, or"
    return f"{path}: this is {article} {kind} file, not an OBJ: {how} with `{convert}`"


def obj_mesh_text(mesh, header: str) -> str:
    """An OBJ of a parsed mesh (pbc.geometry.garment.obj_import.ObjMesh): its vertices, UVs, triangles and `g` groups,
    so a re-import names the same charts (`pbc garment fit` inspects a MakeHuman garment fitted to the body)."""
    lines = [f"# {header}"]
    lines += ["v " + " ".join(f"{x:.6g}" for x in v) for v in mesh.vertices]
    lines += ["vt " + " ".join(f"{x:.6g}" for x in t) for t in mesh.uv]
    group = None
    for fv, ft, g in zip(mesh.faces, mesh.face_uv, mesh.face_group, strict=True):
        if g != group:
            lines.append(f"g {mesh.groups[g]}")
            group = g
        lines.append("f " + " ".join(f"{int(a) + 1}/{int(b) + 1}" for a, b in zip(fv, ft, strict=True)))
    return "\n".join(lines) + "\n"
