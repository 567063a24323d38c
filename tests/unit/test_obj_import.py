"""Real OBJ files in (pbc.geometry.garment.obj_import): small hand-written OBJ strings, as other tools write them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pbc.geometry.garment import load_any_obj
from pbc.geometry.garment.base import load_garment_obj
from pbc.geometry.garment.obj_import import import_garment
from pbc.geometry.meshio import parse_obj
from pbc.geometry.meshops import signed_uv_area


def tube_obj(cols: int = 8, rows: int = 3, radius: float = 0.2, height: float = 0.3, relative: bool = False,
             groups: bool = True, uv_cm: bool = False) -> str:
    """A skirt-like tube of quads, as Blender exports it: `o`, `mtllib`, `usemtl`, `s off`, normals,
    `f v/vt/vn`; its UVs cut into a front and a back island (two seams), v up, in metres (or cm)."""
    ang = np.linspace(0.0, 2 * np.pi, cols, endpoint=False)
    chord = 2 * radius * np.sin(np.pi / cols)
    lines = ["# exported by another tool", "mtllib skirt.mtl", "o Skirt"]
    for r in range(rows + 1):
        for a in ang:
            lines.append(f"v {radius * np.sin(a):.9f} {-r * height / rows:.9f} {radius * np.cos(a):.9f}")
    unit = 100.0 if uv_cm else 1.0
    half = cols // 2
    # front island: columns 0..half (u grows with the column), back island: half..cols, placed apart in u
    vt_index = {}
    for name, c0, u0 in (("front", 0, 0.0), ("back", half, (half + 1) * chord)):
        for r in range(rows + 1):
            for c in range(c0, c0 + half + 1):
                vt_index[(name, r, c)] = len(vt_index) + 1
                u = u0 + (c - c0) * chord
                lines.append(f"vt {u * unit:.9f} {(height - r * height / rows) * unit:.9f}")
    lines += ["vn 0 0 1", "usemtl Cloth", "s off"]
    nv, nt = (rows + 1) * cols, len(vt_index)
    for name, c0, _ in (("front", 0, 0.0), ("back", half, 0.0)):
        if groups:
            lines.append(f"g {name}")
        for r in range(rows):
            for c in range(c0, c0 + half):
                quad = [(r + 1, c), (r + 1, c + 1), (r, c + 1), (r, c)]  # counter-clockwise seen from outside
                corners = []
                for rr, cc in quad:
                    v = rr * cols + cc % cols + 1
                    t = vt_index[(name, rr, cc)]
                    if relative:
                        v, t = v - nv - 1, t - nt - 1
                    corners.append(f"{v}/{t}/1")
                lines.append("f " + " ".join(corners))
    return "\n".join(lines) + "\n"


def _write(tmp_path, text, name="g.obj"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _edge_lengths(points, faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.linalg.norm(points[e[:, 0]] - points[e[:, 1]], axis=-1)


def test_quads_are_triangulated_keeping_the_uv_seams(tmp_path):
    path = _write(tmp_path, tube_obj())
    g, names, chart = import_garment(path, uv_unit="m")
    assert names == ["front", "back"]
    assert g.faces.shape == (2 * 8 * 3, 3) and g.num_vertices == 8 * 4
    assert g.face_side.tolist() == [0] * 24 + [1] * 24
    # the two seams: 2 x 4 vertices appear in both charts with different uvs, the back one sampled front
    f, fuv = g.faces.numpy(), g.face_uv.numpy()
    uvs_of = {}
    for v, t in zip(f.ravel(), fuv.ravel(), strict=True):
        uvs_of.setdefault(int(v), set()).add(int(t))
    assert sum(len(t) == 2 for t in uvs_of.values()) == 8
    assert (g.vertex_side.numpy() == 0).sum() == 4 * 5
    # the flat pattern is the cut-open tube: every pattern edge has its 3D length (developable)
    pat = (g.uv[g.face_uv] * g.uv_scale).double().numpy()
    flat = np.concatenate([np.linalg.norm(pat[:, a] - pat[:, b], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))])
    np.testing.assert_allclose(flat, _edge_lengths(g.vertices.double().numpy(), f), atol=1e-6)
    # pbc's orientation (v = 0 at the top; the same turn as the procedural shirt's charts)
    assert (signed_uv_area(g.uv[g.face_uv].double().numpy()) < 0).all()
    top = g.vertices[:, 1] > -1e-6  # the waist row (y = 0) has the smallest v
    assert g.vertex_uv[top, 1].max() < g.vertex_uv[~top, 1].min()
    # each side is centred with the padding left empty
    for s in (0, 1):
        uv = g.uv[g.face_uv[g.face_side == s]].reshape(-1, 2)
        assert uv.min() >= 0.1 - 1e-6 and uv.max() <= 0.9 + 1e-6
        assert abs(float(uv.max(0).values.max() - uv.min(0).values.min())) > 0.79


def test_relative_indices_read_like_absolute_ones(tmp_path):
    a = import_garment(_write(tmp_path, tube_obj(), "abs.obj"), uv_unit="m")[0]
    b = import_garment(_write(tmp_path, tube_obj(relative=True), "rel.obj"), uv_unit="m")[0]
    for field in ("vertices", "faces", "uv", "face_uv", "face_side", "vertex_uv", "vertex_side"):
        assert torch.equal(getattr(a, field), getattr(b, field)), field


def test_uv_units_scale_to_the_pattern(tmp_path):
    m = import_garment(_write(tmp_path, tube_obj(), "m.obj"), uv_unit="m")[0]
    cm = import_garment(_write(tmp_path, tube_obj(uv_cm=True), "cm.obj"), uv_unit="cm")[0]
    auto = import_garment(_write(tmp_path, tube_obj(uv_cm=True), "auto.obj"), uv_unit="auto")[0]
    assert cm.uv_scale == pytest.approx(m.uv_scale, rel=1e-6)
    # auto: the pattern has the 3D surface's area (exact here: the tube is developable)
    assert auto.uv_scale == pytest.approx(m.uv_scale, rel=1e-6)
    torch.testing.assert_close(cm.uv, m.uv, atol=1e-6, rtol=0)
    wrong = import_garment(_write(tmp_path, tube_obj(uv_cm=True), "w.obj"), uv_unit="m")[0]
    assert wrong.uv_scale == pytest.approx(100 * m.uv_scale, rel=1e-6)


def test_ngon_and_islands_without_groups(tmp_path):
    text = ("v 0 0 0\nv 1 0 0\nv 1.3 1 0\nv 0.5 1.6 0\nv -0.3 1 0\n"
            "v 3 0 0\nv 4 0 0\nv 3 1 0\n"
            "vt 0 0\nvt 1 0\nvt 1.3 1\nvt 0.5 1.6\nvt -0.3 1\nvt 2 0\nvt 3 0\nvt 2 1\n"
            "f 1/1 2/2 3/3 4/4 5/5\nf 6/6 7/7 8/8\n")
    g, names, chart = import_garment(_write(tmp_path, text), uv_unit="m")
    assert g.faces.shape == (4, 3)  # pentagon -> 3 triangles, plus one
    assert names == ["default", "default_2"] and chart.tolist() == [0, 0, 0, 1]
    g2, _, _ = import_garment(_write(tmp_path, text, "b.obj"), uv_unit="m", charts={"default": 0, "default_2": 1})
    assert g2.face_side.tolist() == [0, 0, 0, 1]
    with pytest.raises(ValueError, match=r"default_2.*garment.charts=\{default:0,default_2:0\}"):
        import_garment(_write(tmp_path, text, "c.obj"), uv_unit="m", charts={"default": 0})


def test_mirrored_island_is_turned_back(tmp_path):
    text = tube_obj()
    lines = [(f"vt {-float(ln.split()[1]):.9f} {ln.split()[2]}" if ln.startswith("vt ") else ln)
             for ln in text.splitlines()]
    g = import_garment(_write(tmp_path, "\n".join(lines) + "\n"), uv_unit="m")[0]
    assert (signed_uv_area(g.uv[g.face_uv].double().numpy()) < 0).all()


def test_the_garment_door_reads_foreign_files(tmp_path):
    path = _write(tmp_path, tube_obj())
    a = load_any_obj(path, uv_unit="m")
    b = import_garment(path, uv_unit="m")[0]
    assert torch.equal(a.uv, b.uv) and torch.equal(a.faces, b.faces)


@pytest.mark.parametrize("text, match", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 4: face corner '1' has no texture coordinate.*export with UVs"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 4/1\n", r"line 5: vertex index 4 refers to no vertex"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/-4\n", r"line 7: texture coordinate index -4"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n", r"line 4: vertex 4.*loose"),
    # three triangles on one edge (a fin)
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0 -1\nvt 0.5 0.5\n"
     "f 1/1 2/2 3/3\nf 2/2 1/1 4/4\nf 1/1 2/2 5/5\n", r"edge between vertices 1 and 2 has 3 faces.*non-manifold"),
    # one island folded over itself: the second triangle turns the other way in UV
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.2 0.2\n"
     "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n", r"line 10: UV island 'default' is folded"),
])
def test_bad_input_gets_one_clear_error(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        import_garment(_write(tmp_path, text), uv_unit="m")


def test_no_uvs_and_overlapping_islands_are_refused(tmp_path):
    # as Blender writes a mesh without UVs: normals but no vt
    with pytest.raises(ValueError, match=r"g.obj: line 5: face corner '1//1' has no texture coordinate.*UVs"):
        import_garment(_write(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n"))
    # both tube islands on the front image, laid over each other
    text = tube_obj()
    half = 5 * 4
    lines, k = [], 0
    for ln in text.splitlines():
        if ln.startswith("vt "):
            u, v = float(ln.split()[1]), float(ln.split()[2])
            if k >= half:
                u -= 5 * 2 * 0.2 * np.sin(np.pi / 8) - 0.02
            k += 1
            ln = f"vt {u:.9f} {v:.9f}"
        lines.append(ln)
    with pytest.raises(ValueError, match=r"UV islands 'front' and 'back' overlap.*garment.charts=\{front:0,back:1\}"):
        import_garment(_write(tmp_path, "\n".join(lines) + "\n", "ov.obj"), uv_unit="m", charts={"front": 0, "back": 0})
    # the same layout on two sides is fine
    g = import_garment(_write(tmp_path, "\n".join(lines) + "\n", "ok.obj"), uv_unit="m")[0]
    assert set(g.face_side.tolist()) == {0, 1}


def test_parse_ignores_materials_smoothing_objects_and_continuations():
    mesh = parse_obj("mtllib a.mtl\no A\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\ns 1\n"
                     "l 1 2\nf 1/1 \\\n 2/2 3/3\n")
    assert mesh.faces.tolist() == [[0, 1, 2]] and mesh.face_line.tolist() == [13]


def test_pbc_round_trip_keeps_where_vertices_are_sampled(tmp_path):
    """A vertex with two uvs on one side (two charts sharing an image, or a seam inside one chart) reads
    back at the uv it was imported with, so a cage made for the import fits the dataset's garment."""
    from pbc.geometry.garment.base import save_garment_obj

    text = tube_obj()
    # both islands on the front image (they are placed apart in UV), the back seam inside one chart too
    g = import_garment(_write(tmp_path, text), uv_unit="m", charts={"front": 0, "back": 0})[0]
    assert (g.vertex_side == 0).all()
    save_garment_obj(g, tmp_path / "pbc.obj")
    h = load_garment_obj(tmp_path / "pbc.obj")
    assert torch.equal(h.vertex_uv, g.vertex_uv) and torch.equal(h.vertex_side, g.vertex_side)
    assert h.uv_scale == g.uv_scale
