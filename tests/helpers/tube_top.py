"""A garment pbc did not make, for tests: a tube top exported as another tool would (quads, three UV
islands, UVs in cm), and the config overrides that import it, cage it automatically and drape it on the
coarse body (tests/test_autocage.py, tests/test_any_cage.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

# its islands -> the image side each is drawn on (the band, cut open at the back, lies on the front image)
CHARTS = {"front": 0, "back": 1, "band": 0}
# tiny data on the coarse body; the drape is the cost, so three samples
OVERRIDES = ["data=tshirt_tiny", "garment=obj", "garment.charts={front:0,back:1,band:0}", "garment.uv_unit=cm",
             "data.num_samples=3", "data.workers=1", "body.mesh.voxel_size=0.03"]


def tube_top_obj(cols: int = 16, rows: int = 6, band_rows: int = 2, rx: float = 0.16, rz: float = 0.115) -> str:
    """A tube top round the torso as another tool would export it: quads, three UV islands (groups front,
    back, band: the waistband, cut open at the back), v up, UVs in cm, `mtllib`/`o`/`usemtl`/`s` lines,
    and relative indices in the band's faces."""
    y_top, y_mid, y_bot = 0.30, 0.0, -0.06
    ang = np.linspace(0, 2 * np.pi, cols, endpoint=False) + np.pi / cols
    ys = np.concatenate([np.linspace(y_top, y_mid, rows + 1), np.linspace(y_mid, y_bot, band_rows + 1)[1:]])
    pts = np.array([[rx * np.sin(a), y, -0.01 + rz * np.cos(a)] for y in ys for a in ang])
    step = np.linalg.norm(np.roll(pts[:cols, [0, 2]], -1, 0) - pts[:cols, [0, 2]], axis=1).mean()
    lines = ["# Exported from SomeCAD", "mtllib top.mtl", "o TubeTop"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts]
    vt: dict = {}

    def add(key, u, v):
        vt[key] = len(vt) + 1
        lines.append(f"vt {u * 100:.5f} {v * 100:.5f}")

    h = cols // 2
    front_cols = [c % cols for c in range(-h // 2, h // 2 + 1)]
    back_cols = [c % cols for c in range(h // 2, h // 2 + h + 1)]
    for name, cl, u0 in (("front", front_cols, 0.0), ("back", back_cols, (h + 2) * step)):
        for r in range(rows + 1):
            for k in range(len(cl)):
                add((name, r, k), u0 + k * step, ys[r])
    for r in range(rows, len(ys)):
        for k in range(cols + 1):
            add(("band", r, k), k * step, ys[r] - 0.08)
    lines += ["usemtl Fabric", "s 1"]
    for name, cl in (("front", front_cols), ("back", back_cols)):
        lines.append(f"g {name}")
        for r in range(rows):
            for k in range(h):
                q = [(r + 1, k), (r + 1, k + 1), (r, k + 1), (r, k)]
                lines.append("f " + " ".join(f"{rr * cols + cl[kk] + 1}/{vt[(name, rr, kk)]}" for rr, kk in q))
    lines.append("g band")
    nv, nt = len(pts), len(vt)
    for r in range(rows, len(ys) - 1):
        for k in range(cols):
            q = [(r + 1, k), (r + 1, k + 1), (r, k + 1), (r, k)]
            lines.append("f " + " ".join(f"{rr * cols + kk % cols - nv}/{vt[('band', rr, kk)] - nt - 1}"
                                         for rr, kk in q))
    return "\n".join(lines) + "\n"


def tube_top_dataset(root: Path) -> tuple[Path, list[str], Path]:
    """Write the tube top's OBJ under `root` and make its dataset (import -> automatic cage -> shrink-wrap ->
    three drapes on the coarse body) -> (root, the config overrides it was made with, the dataset dir)."""
    from pbc.core.config import load_config
    from pbc.data.generate import generate

    path = root / "top.obj"
    path.write_text(tube_top_obj())
    overrides = [*OVERRIDES, f"garment.obj={path}", f"paths.data_dir={root}"]
    return root, overrides, generate(load_config(overrides))
