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
from pbc.geometry.meshio import SIDE_NAMES, obj_text, read_obj
from pbc.geometry.meshops import uv_islands


@dataclass
class Garment:
    """A garment mesh whose UV charts lie on the two sides of its cloth image (front, back; one chart a side for
    the paper's T-shirt, any number for other garments; see docs/interfaces.md)."""

    vertices: Tensor  # (V, 3) sewn rest shape in 3D, on the body's rest pose, root frame
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
    """Read a garment file pbc wrote (``save_garment_obj``: its ``# uv_scale`` header) exactly as written:
    the OBJ parsed by ``pbc.geometry.meshio.read_obj``, its ``g front`` / ``g back`` groups the faces' image
    sides, the header comments its scale and vertex sides. Another tool's OBJ is refused with a pointer to
    pbc.geometry.garment.load_any_obj (the importer). Raises ValueError naming the file (and the line)."""
    path = Path(path)
    if not is_pbc_obj(path):
        raise ValueError(f"{path} is not a garment file pbc wrote (no '# uv_scale' header): import another "
                         "tool's OBJ with pbc.geometry.garment.load_any_obj, or from a config with "
                         "garment=obj garment.obj=<path>")
    mesh = read_obj(path, "garment OBJ")
    uv_scale, vertex_side = None, None
    for comment in mesh.comments:
        words = comment.split()
        if words[:1] == ["uv_scale"] and len(words) >= 2:
            uv_scale = float(words[1])
        elif words[:1] == ["vertex_side"]:
            vertex_side = np.array([int(s) for s in words[1:]], dtype=np.int64)
    if uv_scale is None:
        raise ValueError(f"{path}: missing '# uv_scale <metres per uv unit>' header comment")
    # faces before any `g` line are on the front (the parser's "default" group)
    side_of = {"default": 0, **{name: s for s, name in enumerate(SIDE_NAMES)}}
    unknown = [g for g in mesh.groups if g not in side_of]
    if unknown:
        line = int(mesh.face_line[np.flatnonzero(mesh.face_group == mesh.groups.index(unknown[0]))[0]])
        raise ValueError(f"{path}: line {line}: faces of group {unknown[0]!r}, not one of {SIDE_NAMES}")
    faces, fuvs, uv = mesh.faces, mesh.face_uv, mesh.uv
    sides = np.asarray([side_of[g] for g in mesh.groups], np.int64)[mesh.face_group]
    nv = len(mesh.vertices)
    if vertex_side is None or len(vertex_side) != nv:
        vertex_side = None  # the lowest side each vertex appears on (front for seam vertices)
    # the corner each vertex is sampled at: the rule the importer and the necktie use, so that a vertex
    # with two uvs on one side (a seam between two charts of one image, or within one chart) reads back
    # at the uv it was made with
    chart = uv_islands(faces, uv[fuvs] + 2.0 * sides[:, None, None])
    vertex_tex, vertex_side = sample_corners(faces, fuvs, sides, chart, vertex_side)
    verts = mesh.vertices
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
