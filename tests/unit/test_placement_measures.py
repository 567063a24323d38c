"""What the placement measures before it places (pbc.geometry.garment.placement): the unit from the
hem's girth confirmed by the chest's (a garment whose two girths say different sizes is refused naming both, and
placed once its unit is given), a sheet lying beside the body refused for not surrounding the torso, and a file
whose faces are wound against their neighbours read and placed as its consistently wound twin. The corpus's
garments are placed in tests/integration/test_corpus_garments.py."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.ecosystems import shirt

from pbc.core.config import load_config
from pbc.geometry.garment.placement import _landmarks, hem, openings, placed_mesh, torso_cover_deg, unit_measures
from pbc.geometry.meshops import boundary_loops, consistent_winding


def _write(path, p, f):
    path.write_text("\n".join([f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in p]
                              + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]) + "\n")
    return path


def _gcfg(path, *more):
    return load_config(["body=anny", "garment=obj", f"garment.obj={path}", *more]).garment


def test_a_hem_cut_for_another_size_than_the_chest_is_refused_naming_both(anny_body, tmp_path):
    p, f, _, _ = shirt()
    p = p * 10.0  # decimetres: registered (not kept as given)
    ok = _write(tmp_path / "shirt_dm.obj", p, f)
    mesh, placement = placed_mesh(ok, _gcfg(ok), anny_body)
    assert placement.unit_name == "dm"
    measures = unit_measures(p, f, "top", _landmarks(anny_body), _gcfg(ok).placement)
    assert set(measures) == {"hem girth", "chest girth"}
    assert max(measures.values()) / min(measures.values()) < float(_gcfg(ok).placement.unit_agreement)
    # the last decimetre above the hem bulged 3x front to back: its girth says a garment about 2x smaller than
    # the chest's
    flared = p.copy()
    low = flared[:, 1] < flared[hem(openings(p, f))["ids"], 1].max() + 1.0
    flared[low, 2] = p[low, 2].mean() + 3.0 * (p[low, 2] - p[low, 2].mean())
    bad = _write(tmp_path / "flared.obj", flared, f)
    with pytest.raises(ValueError, match=r"flared.obj: the garment's size does not tell its unit: its hem girth "
                                         r"says .* its chest girth says .*garment.position_unit=") as err:
        placed_mesh(bad, _gcfg(bad), anny_body)
    assert "\n" not in str(err.value)
    _, placement = placed_mesh(bad, _gcfg(bad, "garment.position_unit=dm"), anny_body)  # the fix it names works
    assert placement.unit_name == "dm"


def test_a_sheet_beside_the_body_is_refused_for_not_surrounding_the_torso(anny_body, tmp_path):
    p, f, _, _ = shirt()
    lm = _landmarks(anny_body)
    dm = _write(tmp_path / "shirt_dm.obj", 10.0 * p, f)
    placed, _ = placed_mesh(dm, _gcfg(dm), anny_body)
    worn = torso_cover_deg(placed.vertices, placed.faces, anny_body, lm)
    flat = placed.vertices.copy()  # squashed into a sheet 20 cm in front of the body
    flat[:, 2] = 0.2 + 0.05 * (flat[:, 2] - flat[:, 2].mean())
    assert worn > 300 and torso_cover_deg(flat, f, anny_body, lm) < 240
    path = _write(tmp_path / "sheet.obj", flat, f)
    with pytest.raises(ValueError, match=r"sheet.obj: .* reaches \d+ degrees round the body's torso .*y up") as err:
        placed_mesh(path, _gcfg(path), anny_body)
    assert "\n" not in str(err.value)


def test_faces_wound_against_their_neighbours_are_turned_to_match(anny_body, tmp_path):
    p, f, _, _ = shirt()
    rng = np.random.default_rng(0)
    flip = rng.random(len(f)) < 0.1
    mixed = f.copy()
    mixed[flip] = mixed[flip][:, [0, 2, 1]]
    fixed, flipped = consistent_winding(mixed)
    assert np.array_equal(flipped, flip)  # most faces keep their winding, the others turn back
    assert np.array_equal(fixed, f)
    # boundary loops read the same openings whichever way the faces turn
    assert sorted(len(loop) for loop in boundary_loops(mixed)) == sorted(len(loop) for loop in boundary_loops(f))
    a = _write(tmp_path / "wound.obj", 10.0 * p, f)
    b = _write(tmp_path / "mixed.obj", 10.0 * p, mixed)
    mesh_a, _ = placed_mesh(a, _gcfg(a), anny_body)
    mesh_b, _ = placed_mesh(b, _gcfg(b), anny_body)
    assert np.array_equal(mesh_b.faces, mesh_a.faces)
    assert np.allclose(mesh_b.vertices, mesh_a.vertices, atol=1e-9)


def test_non_manifold_edges_are_refused_naming_the_setting_that_cuts_them_apart(tmp_path, anny_body):
    from pbc.geometry.meshops import mesh_pieces, split_nonmanifold

    p, f, _, _ = shirt()
    flap = len(p)  # one triangle hung on an edge two of the shirt's faces share: that edge has three faces
    a, b = (int(v) for v in f[0, :2])
    faces = np.concatenate([f, [[a, b, flap]]])
    cut, source = split_nonmanifold(faces)
    edges, count = np.unique(np.sort(np.concatenate([cut[:, [0, 1]], cut[:, [1, 2]], cut[:, [2, 0]]]), 1), axis=0,
                             return_counts=True)
    assert count.max() == 2 and np.array_equal(source[cut], faces)  # every edge manifold, the same corners
    assert mesh_pieces(cut, len(source)).max() == 1  # the flap is a piece of its own
    assert np.array_equal(split_nonmanifold(f)[0], f)  # a manifold mesh comes back as it is
    vertices = np.concatenate([10.0 * p, [10.0 * (p[a] + p[b]) / 2 + [0.0, 0.0, 0.3]]])
    path = _write(tmp_path / "flap.obj", vertices, faces)
    with pytest.raises(ValueError, match=r"flap.obj: .*non-manifold edges.*garment.split_nonmanifold=true") as err:
        placed_mesh(path, _gcfg(path), anny_body)
    assert "\n" not in str(err.value)
    mesh, _ = placed_mesh(path, _gcfg(path, "garment.split_nonmanifold=true"), anny_body)
    # the flap cut off and dropped; the shirt's two faces on that edge are cut apart along it too, as Edge Split
    # cuts every face of a non-manifold edge, which copies each end of it at most once
    assert len(mesh.faces) == len(f) and len(p) <= len(mesh.vertices) <= len(p) + 2
