"""The garment type and pbc's own garment file (``garment.obj``: v, vt, ``g front`` / ``g back`` groups,
``uv_scale`` and ``vertex_side`` in header comments, written so a round trip is bit exact). The builders of
each kind live beside it; ``pbc.geometry.garment`` is the door (``garment_from_config``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pbc.core.io import write_text
from pbc.geometry.garment.patterns import sample_corners
from pbc.geometry.meshio import SIDE_NAMES, obj_text
from pbc.geometry.meshops import uv_islands


@dataclass
class Garment:
    """A garment mesh with two UV charts (see docs/interfaces.md)."""

    vertices: Tensor  # (V, 3) sewn rest shape in 3D (T-pose frame)
    faces: Tensor  # (F, 3) long
    uv: Tensor  # (T, 2) in [0, 1]^2 of their chart; u -> column, v -> row (v = 0 top)
    face_uv: Tensor  # (F, 3) long, indices into uv per face corner
    face_side: Tensor  # (F,) long, 0 front, 1 back
    vertex_uv: Tensor  # (V, 2)
    vertex_side: Tensor  # (V,) long, front for seam vertices
    uv_scale: float  # metres per uv unit

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def pattern(self) -> Tensor:
        """Flat pattern corner positions (F, 3, 2) in metres: the cloth's rest shape."""
        return self.uv[self.face_uv] * self.uv_scale




def save_garment_obj(garment: Garment, path) -> None:
    """Write the garment as OBJ: v, vt, `g front`/`g back` groups of `f v/vt`; uv_scale in a header
    comment, vertex_side in `# vs` comments. Floats are written with repr so a round trip is exact.
    The dataset's format (byte-stable across versions); meshes for viewers: pbc.geometry.meshio."""
    path = Path(path)
    v = garment.vertices.detach().cpu().double().numpy()
    uv = garment.uv.detach().cpu().double().numpy()
    f = garment.faces.cpu().numpy()
    fuv = garment.face_uv.cpu().numpy()
    side = garment.face_side.cpu().numpy()
    header = ["pbc garment", f"uv_scale {float(garment.uv_scale)!r}",
              "vertex_side " + " ".join(str(int(s)) for s in garment.vertex_side.cpu().numpy())]
    # float32 values are exactly representable as float64 reprs: the round trip is bit exact
    groups = [(name, side == s) for s, name in enumerate(SIDE_NAMES)]
    write_text(path, obj_text(v, f, uv, fuv, groups=groups, header=header, number=repr))


def is_pbc_obj(path: Path) -> bool:
    """A file save_garment_obj wrote: its header states uv_scale, and its UVs are already pbc's."""
    try:
        with open(path) as fh:
            head = [fh.readline() for _ in range(3)]
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the garment OBJ ({exc})") from None
    return any(ln.split()[:2] == ["#", "uv_scale"] for ln in head)


def load_garment_obj(path) -> Garment:
    """Read a garment OBJ.

    A file save_garment_obj wrote (its `# uv_scale` header) is read exactly as written (`f v/vt`
    triangles, `g front` / `g back`); another tool's OBJ is refused with a pointer to
    pbc.geometry.garment.load_any_obj (the importer). Raises ValueError naming the file (and the line)
    if UVs are missing, faces reference missing vt, etc.
    """
    path = Path(path)
    if not is_pbc_obj(path):
        raise ValueError(f"{path} is not a garment file pbc wrote (no '# uv_scale' header): import another "
                         "tool's OBJ with pbc.geometry.garment.load_any_obj, or from a config with "
                         "garment=obj garment.obj=<path>")
    verts, uvs, faces, fuvs, sides = [], [], [], [], []
    uv_scale = None
    vertex_side = None
    side = 0
    with open(path) as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            if key == "#" and len(parts) >= 3 and parts[1] == "uv_scale":
                uv_scale = float(parts[2])
            elif key == "#" and len(parts) >= 2 and parts[1] == "vertex_side":
                vertex_side = np.array([int(s) for s in parts[2:]], dtype=np.int64)
            elif key == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif key == "vt":
                uvs.append([float(x) for x in parts[1:3]])
            elif key == "g":
                name = parts[1] if len(parts) > 1 else ""
                if name not in SIDE_NAMES:
                    raise ValueError(f"{path}: line {lineno}: group {name!r} is not one of {SIDE_NAMES}")
                side = SIDE_NAMES.index(name)
            elif key == "f":
                if len(parts) != 4:
                    raise ValueError(f"{path}: line {lineno}: only triangles are supported")
                fv, ft = [], []
                for corner in parts[1:]:
                    idx = corner.split("/")
                    if len(idx) < 2 or not idx[1]:
                        raise ValueError(f"{path}: line {lineno}: face corner {corner!r} has no vt index "
                                         "(a garment OBJ needs UVs)")
                    fv.append(int(idx[0]) - 1)
                    ft.append(int(idx[1]) - 1)
                faces.append(fv)
                fuvs.append(ft)
                sides.append(side)
    if not uvs:
        raise ValueError(f"{path}: no texture coordinates (vt); a garment OBJ needs UVs")
    if not faces:
        raise ValueError(f"{path}: no faces")
    faces = np.asarray(faces, np.int64)
    fuvs = np.asarray(fuvs, np.int64)
    if faces.min() < 0 or faces.max() >= len(verts):
        raise ValueError(f"{path}: faces reference missing vertices (v has {len(verts)} entries)")
    if fuvs.min() < 0 or fuvs.max() >= len(uvs):
        raise ValueError(f"{path}: faces reference missing texture coordinates (vt has {len(uvs)} entries)")
    if uv_scale is None:
        raise ValueError(f"{path}: missing '# uv_scale <metres per uv unit>' header comment")
    uv = np.asarray(uvs, np.float64)
    sides = np.asarray(sides, np.int64)
    nv = len(verts)
    if vertex_side is None or len(vertex_side) != nv:
        vertex_side = None  # the lowest side each vertex appears on (front for seam vertices)
    # the corner each vertex is sampled at: the rule the importer and the necktie use, so that a vertex
    # with two uvs on one side (a seam between two charts of one image, or within one chart) reads back
    # at the uv it was made with
    chart = uv_islands(faces, uv[fuvs] + 2.0 * sides[:, None, None])
    vertex_tex, vertex_side = sample_corners(faces, fuvs, sides, chart, vertex_side)
    return Garment(
        vertices=torch.tensor(np.asarray(verts), dtype=torch.float32),
        faces=torch.tensor(faces),
        uv=torch.tensor(uv, dtype=torch.float32),
        face_uv=torch.tensor(fuvs),
        face_side=torch.tensor(sides),
        vertex_uv=torch.tensor(uv[vertex_tex], dtype=torch.float32),
        vertex_side=torch.tensor(vertex_side),
        uv_scale=float(uv_scale),
    )


# `kind: procedural`: the T-shirt's kind in configs recorded before it was named `tshirt`
KIND_ALIASES = {"procedural": "tshirt"}


def garment_kind(gcfg) -> str:
    """Which builder a garment config node asks for: ``mhclo``; ``obj`` whenever a file is given
    (``garment.obj=PATH`` on any preset); else its ``kind`` (default ``tshirt``)."""
    kind = str(gcfg.get("kind", "tshirt"))
    if kind == "mhclo":
        return kind
    if gcfg.get("obj"):
        return "obj"
    return KIND_ALIASES.get(kind, kind)
