"""MakeHuman-format clothes (pbc/geometry/garment/mhclo.py) on hand-made base meshes: the parser (real-world quirks and
each corrupt input), the fit against a hand computation, the push-out of what sits inside the body, an outfit's
pieces, and the refusals before anything is built (no Anny here: tests/integration/test_mhclo_jobs.py fits to it)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.mhclo_assets import grid_faces, hand_fit, write_mhclo  # noqa: E402

from pbc.core.config import load_config  # noqa: E402
from pbc.geometry.garment import garment_from_config, garment_needs_body  # noqa: E402
from pbc.geometry.garment.mhclo import (
    BASE_UNIT,
    bound_mesh,
    bound_positions,
    check_anny_body,
    parse_mhclo,
    read_garment_obj,
    read_mhclo,
)
from pbc.geometry.garment.outfit import name_pieces, select_piece
from pbc.geometry.meshio import parse_obj  # noqa: E402
from pbc.geometry.meshops import push_out, surface_distance

# a tiny base mesh (metres, pbc frame): 6 vertices, the scale pairs 0-1 (x), 0-2 (y), 0-3 (z)
BASE = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.3, 0.0], [0.0, 0.0, 0.4], [0.1, 0.1, 0.1],
                 [-0.1, 0.2, 0.05]])
SCALES = {"x": (0, 1, 1.0), "y": (0, 2, 2.0), "z": (0, 3, 8.0)}  # sx = 0.2, sy = 0.15, sz = 0.05 m per unit

TEXT = """# This is a clothes file for MakeHuman Community, exported by MakeClothes 2\r
# author: someone\r
basemesh hm08\r
name tiny\r
obj_file tiny.obj\r
material tiny.mhmat\r
texture tiny_diffuse.png\r
uuid 1234\r
x_scale 0 1 1.0000\r
y_scale 0 2 2.0000   # a comment after the value\r
z_scale 0 3 8.0000\r
z_depth 50\r
\r
verts 0\r
0 1 2 0.5 0.3 0.2 1.0 -2.0 0.5\r
4\r
\r
3 4 5 0.2 0.2 0.6 0.0 0.0 -1.0\r
delete_verts\r
 2 - 4 7\r
"""


def test_parser_reads_makeclothes_output_with_its_quirks():
    m = parse_mhclo(TEXT, "/x/tiny.mhclo")
    assert m.name == "tiny" and m.obj_file == Path("/x/tiny.obj")
    np.testing.assert_array_equal(m.refs, [[0, 1, 2], [4, 4, 4], [3, 4, 5]])  # a single index is rigid
    np.testing.assert_array_equal(m.weights[1], [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(m.offsets[0], [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(m.lines, [15, 16, 18])  # a blank line inside `verts` ends nothing
    assert [s[:3] for s in m.scales] == [(0, 1, 1.0), (0, 2, 2.0), (0, 3, 8.0)]
    np.testing.assert_array_equal(m.delete_verts, [2, 3, 4, 7])


def test_fit_is_the_weighted_sum_plus_the_scaled_offset():
    m = parse_mhclo(TEXT, "/x/tiny.mhclo")
    got = bound_positions(m, BASE)
    # by hand: sx = 0.2 / 1, sy = 0.3 / 2, sz = 0.4 / 8
    want0 = 0.5 * BASE[0] + 0.3 * BASE[1] + 0.2 * BASE[2] + np.array([0.2 * 1.0, 0.15 * -2.0, 0.05 * 0.5])
    want2 = 0.2 * BASE[3] + 0.2 * BASE[4] + 0.6 * BASE[5] + np.array([0.0, 0.0, 0.05 * -1.0])
    np.testing.assert_allclose(got, [want0, BASE[4], want2], atol=1e-12)
    np.testing.assert_allclose(got, hand_fit(BASE, m.refs, m.weights, m.offsets, SCALES), atol=1e-12)
    # a body twice as large: the weighted part and the offsets both double
    np.testing.assert_allclose(bound_positions(m, 2 * BASE), 2 * got, atol=1e-12)


def test_missing_scale_lines_keep_the_base_mesh_size():
    text = "\n".join(line for line in TEXT.splitlines() if "_scale" not in line)
    m = parse_mhclo(text, "tiny.mhclo")
    got = bound_positions(m, BASE)
    np.testing.assert_allclose(got[0], 0.5 * BASE[0] + 0.3 * BASE[1] + 0.2 * BASE[2] + BASE_UNIT * m.offsets[0])


@pytest.mark.parametrize("text, message", [
    ("name x\nobj_file x.obj\n", "no `verts` section"),
    ("verts 0\n1 2 3 0.5 0.5\n", "line 2: a binding is"),
    ("verts 0\n1 2 x 0.5 0.3 0.2 0 0 0\n", "line 2: vertex 'x' is not an integer"),
    ("verts 0\n1 2 3 0.5 nan 0.2 0 0 0\n", "line 2: weight 'nan' is not a finite number"),
    ("x_scale 1 2\nverts 0\n1\n", "line 1: `x_scale a b distance` needs three values"),
    ("y_scale 1 2 0\nverts 0\n1\n", "line 1: y_scale distance must be positive"),
    ("name x\n1 2 3\n", "line 2: numbers outside a `verts`"),
    ("basemesh hm05\nverts 0\n1\n", "made for base mesh 'hm05'"),
    ("verts 0\n1\nverts 0\n2\n", "line 3: a second `verts` section"),
])
def test_corrupt_mhclo_is_one_error_naming_the_line(text, message):
    with pytest.raises(ValueError, match="garment.mhclo") as e:
        parse_mhclo(text, "garment.mhclo")
    assert message in str(e.value) and "\n" not in str(e.value)


def test_vertex_beyond_the_base_mesh_is_refused_naming_the_line():
    m = parse_mhclo("verts 0\n0 1 2 0.3 0.3 0.4 0 0 0\n1 9 2 0.3 0.3 0.4 0 0 0\n", "g.mhclo")
    with pytest.raises(ValueError, match=r"g.mhclo: line 3: base-mesh vertex 9 is beyond the base mesh \(6 vertices"):
        bound_positions(m, BASE)
    m = parse_mhclo("z_scale 0 60 1.0\nverts 0\n1\n", "g.mhclo")
    with pytest.raises(ValueError, match="line 1: base-mesh vertex 60 is beyond"):
        bound_positions(m, BASE)


def test_missing_files_and_a_vertex_count_mismatch(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such MakeHuman clothes file"):
        read_mhclo(tmp_path / "none.mhclo")
    refs = np.zeros((9, 3), np.int64)
    w = np.tile([1.0, 0.0, 0.0], (9, 1))
    path = write_mhclo(tmp_path, refs, w, np.zeros((9, 3)), np.zeros((9, 3)), 3)
    (tmp_path / "patch.obj").unlink()
    with pytest.raises(FileNotFoundError, match="patch.obj does not exist"):
        read_mhclo(path)
    path = write_mhclo(tmp_path, refs, w, np.zeros((9, 3)), np.zeros((9, 3)), 3, extra_obj_vertices=2)
    with pytest.raises(ValueError, match="has 11 vertices but .*binds 9"):
        read_garment_obj(read_mhclo(path))


def _sphere(radius=0.1):
    s = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return np.asarray(s.vertices, np.float64), np.asarray(s.faces, np.int64)


def test_surface_distance_and_push_out_on_a_sphere():
    v, f = _sphere()
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radius = np.where(np.arange(200) < 30, 0.092, 0.104)  # 30 points 8 mm inside, the rest 4 mm outside
    pts = dirs * radius[:, None]
    dist, _, normal = surface_distance(pts, v, f)
    exact = trimesh.Trimesh(v, f).vertices  # the polyhedron's radius is within 0.2 mm of 0.1 at this subdivision
    assert np.allclose(np.linalg.norm(exact, axis=1), 0.1)
    np.testing.assert_allclose(dist, radius - 0.1, atol=3e-4)
    np.testing.assert_allclose((normal * dirs).sum(1), 1.0, atol=1e-2)
    out, stats = push_out(pts, v, f, margin=0.002)
    assert stats["inside"] == 30 and stats["inside_fraction"] == pytest.approx(0.15)
    assert 7.7 < stats["inside_depth_max_mm"] < 8.3
    np.testing.assert_array_equal(out[30:], pts[30:])  # outside: untouched
    # along the smooth normal, not the face's: the margin to a micrometre
    np.testing.assert_allclose(surface_distance(out[:30], v, f)[0], 0.002, atol=2e-6)
    with pytest.raises(ValueError, match="push_out.margin must be >= 0"):
        push_out(pts, v, f, margin=-0.001)


def _outfit_mesh():
    """Two 3 x 3 grids with UVs: one at y = 0.3 (a top), one at y = -0.5 (a bottom), and a 2 x 2 button on the top."""
    lines, k = [], 0
    for y0, n in ((0.3, 3), (-0.5, 3), (0.35, 2)):
        lines += [f"v {0.1 * i} {y0 - 0.1 * j} 0.1" for j in range(n) for i in range(n)]
        lines += [f"vt {i / (n - 1)} {1 - j / (n - 1)}" for j in range(n) for i in range(n)]
        lines += ["f " + " ".join(f"{k + a + 1}/{k + a + 1}" for a in q) for q in grid_faces(n)]
        k += n * n
    return parse_obj("\n".join(lines), "outfit.obj")


def test_outfit_pieces_are_named_where_they_sit_and_chosen():
    mesh = _outfit_mesh()
    pos = mesh.vertices
    piece, names = name_pieces(pos, mesh.faces)
    assert sorted(names) == ["bottom", "top", "top_2"]  # the larger top piece is `top`, the button `top_2`
    assert names[piece[0]] == "top" and names[piece[9]] == "bottom" and names[piece[18]] == "top_2"
    with pytest.raises(ValueError, match=r"an outfit of 3 pieces: .*bottom \(9 vertices\).*garment.piece=bottom or "
                                         r"garment.piece=top \(every piece"):
        select_piece(mesh, pos, None, "outfit.mhclo")
    top, top_pos = select_piece(mesh, pos, "top", "outfit.mhclo")  # a place: the shirt and its button
    assert len(top_pos) == 13 and len(top.faces) == 8 + 2 and top.faces.max() == 12
    one, one_pos = select_piece(mesh, pos, "bottom", "outfit.mhclo")
    np.testing.assert_array_equal(one_pos, pos[9:18])
    assert len(select_piece(mesh, pos, "all", "outfit.mhclo")[1]) == 22
    with pytest.raises(ValueError, match="garment.piece=feet is none of its pieces"):
        select_piece(mesh, pos, "feet", "outfit.mhclo")


def test_fitted_mesh_places_pushes_and_cuts(tmp_path):
    """The whole fit on a hand-made body: a unit-ish sphere as the base mesh's skin, a garment bound to its
    vertices with an inward offset on some of them (they end inside and are pushed out)."""
    v, f = _sphere(0.1)
    n = 3
    refs = np.stack([np.arange(n * n)] * 3, 1)  # each garment vertex on one sphere vertex (weights 1, 0, 0)
    w = np.tile([1.0, 0.0, 0.0], (n * n, 1))
    offsets = np.zeros((n * n, 3))
    offsets[:4] = -v[:4] / np.linalg.norm(v[:4], axis=1, keepdims=True) * 0.05  # 0.05 units = 5 mm inwards
    path = write_mhclo(tmp_path, refs, w, offsets, v[:n * n] * 10, n, scales={})
    m = read_mhclo(path)
    mesh, stats = bound_mesh(m, v, v, f, margin=0.002, candidates=12)
    assert stats["inside"] == 4 and stats["vertices"] == 9
    dist = surface_distance(mesh.vertices, v, f)[0]
    np.testing.assert_allclose(dist[:4], 0.002, atol=2e-6)
    np.testing.assert_allclose(mesh.vertices[4:], v[4:9], atol=1e-12)


def test_the_body_must_be_anny(tmp_path, body):
    for b in (None, body):  # none, and the mannequin (built without a config of kind anny)
        with pytest.raises(ValueError, match="the body must be Anny .*add body=anny"):
            check_anny_body(b)
    cfg = load_config(["garment=mhclo", f"garment.path={tmp_path / 'x.mhclo'}"])
    assert garment_needs_body(cfg.garment)
    with pytest.raises(ValueError, match="add body=anny"):
        garment_from_config(cfg.garment, body)
