"""The cage: curves on the garment and the patches they cut it into, each patch's box in the patch image,
and the cage file (``cage.json``). Any garment's cage is checked here (``validate_cage``); the T-shirt's
hand-made cage is built by ``pbc.geometry.garment.tshirt``, any other garment's by ``auto``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbc.core.io import write_text
from pbc.geometry.meshio import SIDE_NAMES

FORMAT_VERSION = 1




@dataclass
class Patch:
    id: int
    name: str
    side: int  # 0 front, 1 back
    vertices: np.ndarray  # (n,) garment vertex ids
    # (row0, col0, row1, col1) pixel box at the patch resolution (512 by default), end exclusive
    box_512: tuple[int, int, int, int]


@dataclass
class Cage:
    curves: dict[str, np.ndarray]  # name -> ordered garment vertex ids
    patches: list[Patch]  # id == index
    resolution: int | None = None  # the patch resolution the boxes were computed at

    def vertex_patch(self, num_vertices: int) -> np.ndarray:
        """(V,) patch id of each vertex (-1 where none)."""
        out = -np.ones(num_vertices, np.int64)
        for p in self.patches:
            out[p.vertices] = p.id
        return out


def uv_box(uv: np.ndarray, resolution: int) -> tuple[int, int, int, int]:
    """Pixel box (row0, col0, row1, col1), end exclusive, of uv points (n, 2) at a resolution.

    Pixel coordinates are uv * resolution (u -> column, v -> row); pixel k covers [k, k+1).
    """
    px = np.asarray(uv, np.float64) * resolution
    col0, row0 = np.floor(px.min(0)).astype(int)
    col1, row1 = np.floor(px.max(0)).astype(int) + 1
    return int(row0), int(col0), int(row1), int(col1)


def crop_origin(box: tuple[int, int, int, int], crop_size: int, resolution: int) -> tuple[int, int]:
    """Top-left (row, col) of the crop_size crop of a patch box: centred on the box (appendix D.7),
    shifted to stay inside the resolution x resolution image (patches at the chart edge)."""
    r0, c0, r1, c1 = box
    row = min(max((r0 + r1 - crop_size) // 2, 0), resolution - crop_size)
    col = min(max((c0 + c1 - crop_size) // 2, 0), resolution - crop_size)
    return int(row), int(col)


def recompute_boxes(cage: Cage, garment, resolution: int) -> None:
    """Set every patch's box from its vertices' vertex_uv at resolution (in place)."""
    vuv = garment.vertex_uv.detach().cpu().numpy()
    for p in cage.patches:
        if len(p.vertices):
            p.box_512 = uv_box(vuv[p.vertices], resolution)


def validate_cage(cage: Cage, garment, resolution: int, crop_size: int, margin: int) -> None:
    """Raise ValueError (naming the offending patch) unless the cage is a valid patch atlas.

    Checks: ids are 0..P-1 in order and names unique; sides are 0/1 and match the vertices' chart
    (vertex_side); patches cover every garment vertex exactly once; each patch's box plus ``margin``
    pixels on every side fits a ``crop_size`` square crop and lies inside the image (so a crop centred
    on the box, then shifted to stay inside the image, holds the box and its margin; see crop_origin).
    """
    nv = garment.num_vertices
    vside = garment.vertex_side.cpu().numpy()
    names = [p.name for p in cage.patches]
    if [p.id for p in cage.patches] != list(range(len(cage.patches))):
        ids = [p.id for p in cage.patches]
        raise ValueError(f"cage: patch ids must be 0..{len(cage.patches) - 1} in order, got {ids}")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"cage: duplicate patch names {dup}")
    owner = -np.ones(nv, np.int64)
    for p in cage.patches:
        tag = f"cage: patch {p.id} '{p.name}'"
        v = np.asarray(p.vertices, np.int64)
        if p.side not in (0, 1):
            raise ValueError(f"{tag}: side must be 0 (front) or 1 (back), got {p.side}")
        if len(v) == 0:
            raise ValueError(f"{tag}: has no vertices")
        if v.min() < 0 or v.max() >= nv:
            raise ValueError(f"{tag}: vertex ids out of range 0..{nv - 1}")
        if len(np.unique(v)) != len(v):
            raise ValueError(f"{tag}: lists a vertex twice")
        wrong = v[vside[v] != p.side]
        if len(wrong):
            raise ValueError(f"{tag}: {len(wrong)} vertices (e.g. {wrong[:5].tolist()}) are sampled from the "
                             f"{SIDE_NAMES[1 - p.side]} chart, not this patch's side")
        taken = v[owner[v] >= 0]
        if len(taken):
            other = cage.patches[owner[taken[0]]]
            raise ValueError(f"{tag}: overlaps patch {other.id} '{other.name}' at {len(taken)} vertices "
                             f"(e.g. {taken[:5].tolist()})")
        owner[v] = p.id
        r0, c0, r1, c1 = p.box_512
        h, w = r1 - r0 + 2 * margin, c1 - c0 + 2 * margin
        if h > crop_size or w > crop_size:
            raise ValueError(f"{tag}: box {p.box_512} plus {margin} px margin is {h}x{w} px, larger than the "
                             f"{crop_size}x{crop_size} crop at resolution {resolution}")
        if r0 - margin < 0 or c0 - margin < 0 or r1 + margin > resolution or c1 + margin > resolution:
            raise ValueError(f"{tag}: box {p.box_512} plus {margin} px margin leaves the "
                             f"{resolution}x{resolution} image")
    missing = np.nonzero(owner < 0)[0]
    if len(missing):
        raise ValueError(f"cage: {len(missing)} garment vertices belong to no patch "
                         f"(e.g. {missing[:10].tolist()})")
    for name, ids in cage.curves.items():
        ids = np.asarray(ids)
        if len(ids) and (ids.min() < 0 or ids.max() >= nv):
            raise ValueError(f"cage: curve '{name}' has vertex ids out of range 0..{nv - 1}")


def cage_to_json(cage: Cage, resolution: int, num_vertices: int) -> str:
    """JSON text of a cage: one patch / curve per line so diffs and hand edits stay readable."""
    lines = ["{", f' "format_version": {FORMAT_VERSION},', f' "resolution": {int(resolution)},',
             f' "num_vertices": {int(num_vertices)},', ' "patches": [']
    for k, p in enumerate(cage.patches):
        d = {"id": int(p.id), "name": p.name, "side": int(p.side), "box_512": [int(x) for x in p.box_512],
             "vertices": [int(x) for x in p.vertices]}
        lines.append("  " + json.dumps(d) + ("," if k < len(cage.patches) - 1 else ""))
    lines.append(" ],")
    lines.append(' "curves": {')
    items = list(cage.curves.items())
    for k, (name, ids) in enumerate(items):
        sep = "," if k < len(items) - 1 else ""
        lines.append(f"  {json.dumps(name)}: {json.dumps([int(x) for x in ids])}{sep}")
    lines += [" }", "}"]
    return "\n".join(lines) + "\n"


def save_cage(cage: Cage, path, num_vertices: int | None = None) -> None:
    """Write the cage JSON atomically (temp file + os.replace); boxes are at cage.resolution."""
    path = Path(path)
    if num_vertices is None:
        num_vertices = 1 + max(int(np.max(p.vertices)) for p in cage.patches if len(p.vertices))
    if cage.resolution is None:
        raise ValueError("save_cage: cage.resolution is unset (the resolution its boxes were computed at)")
    write_text(path, cage_to_json(cage, cage.resolution, num_vertices))


def load_cage(path, garment, resolution: int | None = None, crop_size: int | None = None,
              margin: int | None = None) -> Cage:
    """Read a cage JSON and validate it against the garment.

    Boxes are recomputed from the vertices (so a hand edit of the vertex lists is enough). With
    resolution/crop_size/margin given (the image config values) the crop fit is checked at that
    resolution; without them only the file's own resolution is used and the crop check is skipped.
    Raises ValueError naming the file and the offending patch.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        patches = [Patch(id=int(d["id"]), name=str(d["name"]), side=int(d["side"]),
                         vertices=np.asarray(d["vertices"], np.int64), box_512=tuple(d["box_512"]))
                   for d in data["patches"]]
        curves = {k: np.asarray(v, np.int64) for k, v in data.get("curves", {}).items()}
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a readable cage file ({exc})") from exc
    if int(data.get("num_vertices", garment.num_vertices)) != garment.num_vertices:
        raise ValueError(f"{path}: made for a garment of {data['num_vertices']} vertices, this one has "
                         f"{garment.num_vertices}")
    if resolution is None and "resolution" not in data:
        raise ValueError(f"{path}: no 'resolution' in the file and none given")
    res = int(resolution if resolution is not None else data["resolution"])
    cage = Cage(curves=curves, patches=patches, resolution=res)
    recompute_boxes(cage, garment, res)
    try:
        if crop_size is None or margin is None:
            validate_cage(cage, garment, res, crop_size=res, margin=0)
        else:
            validate_cage(cage, garment, res, crop_size, margin)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return cage
