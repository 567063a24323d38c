"""The one mesh writer (pbc.geometry.meshio): garment OBJ with UVs and normals, PLY, patch submeshes, body."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from pbc.core.config import load_garment_config
from pbc.geometry.garment.base import load_garment_obj, save_garment_obj
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.meshio import submesh, write_garment_mesh, write_mesh
from pbc.geometry.meshops import vertex_normals

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shirt():
    cfg = load_garment_config(ROOT / "conf/garment/tshirt_coarse.yaml", ROOT / "conf/image/default.yaml")
    return make_tshirt(cfg)


def _lines(path: Path, key: str) -> list[list[str]]:
    return [ln.split()[1:] for ln in path.read_text().splitlines() if ln.split()[:1] == [key]]


def test_garment_obj_has_uvs_normals_and_faces(shirt, tmp_path):
    g, _ = shirt
    V, T, F = len(g.vertices), len(g.uv), len(g.faces)
    assert T > V  # the seams are cut in UV: the test means something only if vt != v
    moved = g.vertices + torch.tensor([0.0, 0.1, 0.0])
    path = write_garment_mesh(tmp_path / "a.obj", g, moved)
    v, vt, vn, f = (_lines(path, k) for k in ("v", "vt", "vn", "f"))
    assert (len(v), len(vt), len(vn), len(f)) == (V, T, V, F)
    np.testing.assert_allclose(np.array(v, float), moved.numpy(), atol=1e-6)
    corners = np.array([[c.split("/") for c in face] for face in f], dtype=np.int64) - 1  # (F, 3, 3)
    # faces are the garment's (grouped front then back), each corner v/vt/vn with vn == v
    order = np.argsort(g.face_side.numpy(), kind="stable")
    np.testing.assert_array_equal(corners[..., 0], g.faces.numpy()[order])
    np.testing.assert_array_equal(corners[..., 1], g.face_uv.numpy()[order])
    np.testing.assert_array_equal(corners[..., 2], corners[..., 0])
    # the atlas: front chart in u [0, .5], back in [.5, 1], v flipped to OBJ's v-up
    uv = np.array(vt, float)
    fuv, side = g.face_uv.numpy(), g.face_side.numpy()
    assert uv[fuv[side == 0]].max(axis=(0, 1))[0] <= 0.5 and uv[fuv[side == 1]].min(axis=(0, 1))[0] >= 0.5
    np.testing.assert_allclose(uv[:, 1], 1 - g.uv.numpy()[:, 1], atol=1e-6)

    # trimesh reads it: order kept with maintain_order, seams split (one vertex per v/vt pair) without
    kept = trimesh.load(path, process=False, maintain_order=True)
    assert kept.vertices.shape == (V, 3) and kept.faces.shape == (F, 3) and kept.visual.uv.shape == (V, 2)
    np.testing.assert_allclose(kept.vertices, moved.numpy(), atol=1e-6)
    split = trimesh.load(path, process=False)
    assert split.vertices.shape == (T, 3) and split.visual.uv.shape == (T, 2) and len(split.faces) == F


def test_normals_are_unit_and_point_outward(shirt):
    g, _ = shirt
    v, f = g.vertices.numpy(), g.faces.numpy()
    n = vertex_normals(v, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    # the rest shirt's front panel faces +z (towards the viewer), the back panel -z: away from the body
    vs = g.vertex_side.numpy()
    front_only = np.setdiff1d(np.unique(f[g.face_side.numpy() == 0]), np.unique(f[g.face_side.numpy() == 1]))
    back_only = np.setdiff1d(np.unique(f[g.face_side.numpy() == 1]), np.unique(f[g.face_side.numpy() == 0]))
    assert len(front_only) > 50 and len(back_only) > 50 and (vs[back_only] == 1).all()
    assert (n[front_only, 2] > 0).all() and (n[back_only, 2] < 0).all()
    assert n[front_only, 2].mean() > 0.8 and n[back_only, 2].mean() < -0.8
    # a mesh flipped inside out flips every normal (the writer follows the winding, does not guess)
    np.testing.assert_allclose(vertex_normals(v, f[:, ::-1]), -n, atol=1e-12)


def test_ply_and_body_mesh(shirt, tmp_path):
    g, _ = shirt
    ply = trimesh.load(write_garment_mesh(tmp_path / "a.ply", g), process=False)
    assert ply.vertices.shape == (len(g.vertices), 3) and ply.faces.shape == tuple(g.faces.shape)
    np.testing.assert_allclose(ply.vertex_normals, vertex_normals(g.vertices.numpy(), g.faces.numpy()), atol=1e-6)
    # a plain mesh (the posed body): v, vn, f v//vn
    verts, faces = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), np.array([[0, 2, 1], [0, 1, 3]])
    body = write_mesh(tmp_path / "body.obj", torch.tensor(verts), torch.tensor(faces))
    assert _lines(body, "f")[0] == ["1//1", "3//3", "2//2"] and len(_lines(body, "vn")) == 4
    m = trimesh.load(body, process=False)
    assert m.vertices.shape == (4, 3) and m.faces.shape == (2, 3)


def test_patch_submesh(shirt, tmp_path):
    g, cage = shirt
    patch = cage.patches[7]
    ids = np.asarray(patch.vertices)
    path = write_garment_mesh(tmp_path / "pred_val0_patch07.obj", g, vertex_ids=ids)
    keep, faces, _ = submesh(g.faces.numpy(), ids)
    assert len(_lines(path, "v")) == len(ids) and len(_lines(path, "vn")) == len(ids)
    assert len(_lines(path, "f")) == len(keep) > 0
    assert "patch submesh" in path.read_text().splitlines()[1]
    m = trimesh.load(path, process=False, maintain_order=True)
    np.testing.assert_allclose(m.vertices, g.vertices.numpy()[ids], atol=1e-6)
    # every kept face lies inside the patch, and every face inside the patch is kept
    inside = np.isin(g.faces.numpy(), ids).all(1)
    assert inside.sum() == len(keep)


def test_bad_input_is_refused(shirt, tmp_path):
    g, _ = shirt
    with pytest.raises(ValueError, match="expected"):
        write_garment_mesh(tmp_path / "a.obj", g, torch.zeros(3, 3))
    bad = g.vertices.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(ValueError, match="not finite"):
        write_garment_mesh(tmp_path / "a.obj", g, bad)
    with pytest.raises(ValueError, match="format"):
        write_garment_mesh(tmp_path / "a.stl", g)
    assert not any(tmp_path.iterdir())  # nothing half-written


def test_dataset_garment_file_still_round_trips(shirt, tmp_path):
    """save_garment_obj shares obj_text: the dataset format still reads back bit-exact."""
    g, _ = shirt
    save_garment_obj(g, tmp_path / "garment.obj")
    h = load_garment_obj(tmp_path / "garment.obj")
    assert torch.equal(h.vertices, g.vertices) and torch.equal(h.uv, g.uv) and torch.equal(h.faces, g.faces)
    assert "vn " not in (tmp_path / "garment.obj").read_text()
