"""Reading a garment OBJ back with its UVs (pbc.geometry.meshio.read_obj): vertices in order, seam vertices
keeping both charts' UVs, where trimesh's one-UV-per-vertex load puts faces across the two charts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from pbc.core.config import load_garment_config
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.meshio import read_obj, write_garment_mesh

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shirt_obj(tmp_path_factory):
    """The full shirt (3,153 vertices, two charts sewn at the side seams), written by pbc's writer."""
    garment, _ = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt.yaml", ROOT / "conf/image/default.yaml"))
    path = write_garment_mesh(tmp_path_factory.mktemp("uv") / "shirt.obj", garment)
    return garment, path


def _written_order(garment) -> np.ndarray:
    # the writer groups the faces by chart (g front, then g back), keeping their order within a chart
    return np.argsort(garment.face_side.numpy(), kind="stable")


def _straddling(face_u: np.ndarray, face_side: np.ndarray) -> int:
    """Faces with a corner outside their own chart's half of the atlas (front u <= 0.5, back u >= 0.5)."""
    outside = np.where(face_side[:, None] == 0, face_u > 0.5 + 1e-9, face_u < 0.5 - 1e-9)
    return int(outside.any(1).sum())


def test_read_obj_keeps_vertex_order_and_every_corner_uv(shirt_obj):
    g, path = shirt_obj
    mesh = read_obj(path)
    order = _written_order(g)
    assert mesh.vertices.shape == (len(g.vertices), 3)
    # %.6f in the file: equal to the written precision, vertex i is garment vertex i
    np.testing.assert_allclose(mesh.vertices, g.vertices.numpy(), atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, g.faces.numpy()[order])
    assert len(mesh.uv) == len(g.uv) > len(g.vertices)  # the seams are cut: more UVs than vertices
    # what the writer put at each face corner: pbc's chart uv in the atlas (charts side by side, v up)
    uv, fuv, side = g.uv.numpy(), g.face_uv.numpy()[order], g.face_side.numpy()[order]
    expected = np.stack([(uv[fuv][..., 0] + side[:, None]) / 2, 1 - uv[fuv][..., 1]], -1)
    np.testing.assert_allclose(mesh.uv[mesh.face_uv], expected, atol=1e-6)


def test_face_uvs_stay_in_their_chart_where_trimesh_per_vertex_uvs_do_not(shirt_obj):
    g, path = shirt_obj
    side = g.face_side.numpy()[_written_order(g)]
    mesh = read_obj(path)
    assert _straddling(mesh.uv[mesh.face_uv][..., 0], side) == 0
    # seam vertices really have two UVs, one in each chart: the case the per-vertex load cannot hold
    corner_u = mesh.uv[mesh.face_uv][..., 0]
    seam = np.intersect1d(mesh.faces[side == 0][corner_u[side == 0] < 0.5],
                          mesh.faces[side == 1][corner_u[side == 1] > 0.5])
    assert len(seam) > 0
    tm = trimesh.load(path, process=False, maintain_order=True)
    np.testing.assert_allclose(tm.vertices, mesh.vertices)  # same vertices, same order ...
    np.testing.assert_array_equal(tm.faces, mesh.faces)
    straddle = _straddling(tm.visual.uv[tm.faces][..., 0], side)  # ... but one UV per vertex
    assert straddle > 0, "trimesh kept both UVs of a seam vertex: the README's warning is stale"


def test_read_obj_fans_polygons_and_resolves_negative_indices(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
                    "vn 0 0 1\ng a\nf 1/4/1 2/3/1 3/2/1 4/1/1\nf -4/-1 -2/-2 -1/-3\n")
    mesh = read_obj(path)
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 2, 3]])
    np.testing.assert_array_equal(mesh.face_uv, [[3, 2, 1], [3, 1, 0], [4, 3, 2]])
    assert mesh.uv.shape == (5, 2) and mesh.vertices.shape == (4, 3)


@pytest.mark.parametrize("text, message", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 4: face corner '1' has no texture coordinate"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 4/1\n", "line 5: vertex index 4 refers to no vertex"),
    ("v 0 0 0\nvt 0 0\n", "no faces"),
])
def test_read_obj_names_the_line_of_bad_input(tmp_path, text, message):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        read_obj(path)
