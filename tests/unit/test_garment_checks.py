"""A garment's checks before any drape (UV unit, sleeves against the rest arms, the shrink-wrap's
stretch, far from the body), `pbc garment inspect`'s table and `split`, and generate's discard summary.
The garments are written here as an asset library would hand them over (tests/helpers/a_pose.py)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.a_pose import IMPORT, _tube, outfit_obj  # noqa: E402

from pbc.cli import COMMANDS  # noqa: E402
from pbc.core.config import load_config  # noqa: E402
from pbc.data.generate import Scene, discard_summary, discarded_faces  # noqa: E402
from pbc.geometry.garment import garment_from_config  # noqa: E402
from pbc.geometry.garment.checks import FaceLimits, LimbCloth, face_cause, face_stretch, sleeve_axes
from pbc.geometry.garment.outfit import split_outfit
from pbc.geometry.inspect import inspect_garment  # noqa: E402
from pbc.geometry.shrinkwrap import shrinkwrap, start_points  # noqa: E402
from pbc.geometry.units import check_uv_unit  # noqa: E402


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def _wrap(body, overrides):
    cfg = load_config(IMPORT + overrides)
    garment, cage = garment_from_config(cfg.garment)
    return shrinkwrap(garment, cage, body, cfg.garment.shrinkwrap)


def test_uv_unit_cm_on_a_unit_atlas_is_refused_at_the_import_naming_the_unit_that_fits(tmp_path):
    path = _write(tmp_path, "shirt.obj", outfit_obj(0.0, trousers=False))
    with pytest.raises(ValueError) as err:
        garment_from_config(load_config(IMPORT + [f"garment.obj={path}", "garment.uv_unit=cm"]).garment)
    msg = str(err.value)
    assert "garment.uv_unit=cm" in msg and "a [0, 1] atlas" in msg and "set garment.uv_unit=auto" in msg
    assert "3.1" in msg and "garment.uv_unit_tolerance = 2x" in msg  # the fitted metres per unit: 3.148
    # within the tolerance: accepted; a named unit is named when it fits
    check_uv_unit(0.01, area_3d=1.5e-4, area_uv=1.0, unit_text="cm", tolerance=2.0, where="x")
    with pytest.raises(ValueError, match=r"the unit that fits is 0.1 m per UV unit: set garment.uv_unit=dm"):
        check_uv_unit(0.01, area_3d=1.0e-2, area_uv=1.0, unit_text="cm", tolerance=2.0, where="x", uv_range=10.0)


def test_a_posed_sleeves_are_refused_with_the_angle_and_the_setting(tmp_path, body):
    path = _write(tmp_path, "a.obj", outfit_obj(40.0, trousers=False))
    with pytest.raises(ValueError) as err:
        _wrap(body, [f"garment.obj={path}"])
    msg = str(err.value)
    assert "sleeve is 37 degrees off the body's rest arm" in msg  # turned 40 about the sleeve root: 37.4 measured
    assert "garment.shrinkwrap.max_sleeve_angle_deg = 20" in msg and "rotate the sleeves 37 degrees up" in msg
    # the T-posed shirt's sleeves lie along the rest arms
    cfg = load_config(IMPORT + [f"garment.obj={_write(tmp_path, 't.obj', outfit_obj(0.0, trousers=False))}"])
    g, _ = garment_from_config(cfg.garment)
    limb = LimbCloth.from_config(cfg.garment.shrinkwrap)
    axes = sleeve_axes(g.vertices.double().numpy(), g.faces.numpy(), body, limb)
    assert set(axes) == {"left", "right"} and max(a["angle_deg"] for a in axes.values()) < 2.0


def test_the_wrap_stretch_is_refused_naming_the_chart_the_stretch_and_the_rest_pose(tmp_path, body):
    path = _write(tmp_path, "a.obj", outfit_obj(40.0, trousers=False))
    with pytest.raises(ValueError) as err:
        _wrap(body, [f"garment.obj={path}", "garment.shrinkwrap.max_sleeve_angle_deg=null"])
    msg = str(err.value)
    assert "the shrink-wrap stretches chart 'default'" in msg and "max_patch_stretch = 2" in msg
    stretch = float(msg.split(") to ")[1].split("x")[0])
    assert stretch > 2.0 and "match the rest pose" in msg
    # the same shirt T-posed wraps within the limit, and its stats say so
    _, stats = _wrap(body, [f"garment.obj={_write(tmp_path, 't.obj', outfit_obj(0.0, trousers=False))}"])
    assert stats["patch_stretch_max"] < 1.0 < stretch


def test_far_from_the_body_names_the_piece_the_distance_and_that_the_body_has_no_legs(tmp_path, body):
    path = _write(tmp_path, "outfit.obj", outfit_obj(0.0))
    with pytest.raises(ValueError) as err:
        _wrap(body, [f"garment.obj={path}"])
    msg = str(err.value)
    assert "chart 'default_3'" in msg and "piece 1 of the 2 separate pieces" in msg
    assert "0.74 m from the body" in msg and "this body has no legs there" in msg and "pbc garment split" in msg


def test_inspect_table_matches_hand_computed_areas(tmp_path, body):
    # two quads: a 0.2 x 0.3 m panel in front of the chest, UVs a unit square (area 1); a 0.1 x 0.1 m panel
    # behind it, UVs 0.5 x 0.5 (area 0.25): uv_unit sqrt(0.06) and sqrt(0.01 / 0.25) = 0.2 m per unit
    obj = """v -0.1 0.1 0.25
v 0.1 0.1 0.25
v 0.1 0.4 0.25
v -0.1 0.4 0.25
v -0.05 0.2 -0.2
v 0.05 0.2 -0.2
v 0.05 0.3 -0.2
v -0.05 0.3 -0.2
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 2 0
vt 2.5 0
vt 2.5 0.5
vt 2 0.5
g front
f 1/1 2/2 3/3 4/4
g back
f 5/5 8/8 7/7 6/6
"""
    path = _write(tmp_path, "two.obj", obj)
    report = inspect_garment(path, load_config(["garment=obj", f"garment.obj={path}"]).garment, body, wrap=False)
    front, back = report.rows
    assert (front.name, back.name) == ("front", "back") and (front.facing, back.facing) == ("front", "back")
    assert front.area_3d == pytest.approx(0.06) and front.area_uv == pytest.approx(1.0)
    assert back.area_3d == pytest.approx(0.01) and back.area_uv == pytest.approx(0.25)
    assert front.uv_unit == pytest.approx(np.sqrt(0.06)) and back.uv_unit == pytest.approx(0.2)
    np.testing.assert_allclose(front.centroid, [0.0, 0.25, 0.25], atol=1e-9)
    assert report.suggest_charts == {"front": 0, "back": 1} and report.sleeves == {}
    assert front.distance_max > 0.0 and "torso" in front.region


def test_split_cuts_an_outfit_into_pieces_named_by_where_they_sit(tmp_path, body):
    path = _write(tmp_path, "outfit.obj", outfit_obj(40.0))
    pieces = split_outfit(path, tmp_path / "pieces", position_unit="dm")
    assert [(n, p.name) for n, p, _ in pieces] == [("top", "top.obj"), ("bottom", "bottom.obj")]
    assert pieces[1][2] == 480  # the trousers' 480 triangles
    # the top alone imports and meets the next check (its A-posed sleeves), not "far from the body"
    with pytest.raises(ValueError, match="sleeve is 37 degrees off"):
        _wrap(body, [f"garment.obj={pieces[0][1]}"])
    bottom = load_config(IMPORT + [f"garment.obj={pieces[1][1]}"]).garment
    g, _ = garment_from_config(bottom)
    assert g.faces.shape[0] == 480


# the tube's face squashed in the pattern (`_tube_obj`): the triangle of its ring ROWS // 2, column COLS // 2
ROWS, COLS = 8, 24
SLIVER_FACE = 2 * ((ROWS // 2) * COLS + COLS // 2)


def _tube_obj(squash: float | None = None) -> str:
    """A tube round the mannequin's chest as an OBJ in decimetres, its pattern the tube cut open at the back (one
    chart); with ``squash``, one face's pattern triangle (SLIVER_FACE) flattened to that fraction of its area by
    moving one corner's UV towards the opposite edge (its neighbours keep their orientation: no fold)."""
    pts, faces, uv, fuv = _tube(0.32, 0.04, 0.17, COLS, ROWS)
    if squash is not None:
        v0, v2, v1 = fuv[SLIVER_FACE]
        mid = 0.5 * (uv[v0] + uv[v2])
        uv[v1] = mid + squash * (uv[v1] - mid)
    lines = [f"v {10 * x:.6f} {10 * y:.6f} {10 * z:.6f}" for x, y, z in pts]
    lines += [f"vt {u:.9f} {v:.9f}" for u, v in uv]
    lines += [f"f {a + 1}/{ta + 1} {b + 1}/{tb + 1} {c + 1}/{tc + 1}"
              for (a, b, c), (ta, tb, tc) in zip(faces, fuv, strict=True)]
    return "\n".join(lines) + "\n"


def test_one_face_stretched_past_the_limit_is_refused_at_the_wrap_naming_it_its_place_and_cause(tmp_path, body):
    path = _write(tmp_path, "sliver.obj", _tube_obj(0.001))
    with pytest.raises(ValueError) as err:
        _wrap(body, [f"garment.obj={path}"])
    msg = str(err.value)
    assert len(msg.splitlines()) == 1
    limit = load_config(IMPORT).garment.shrinkwrap.max_face_stretch
    assert f"stretches 1 face past garment.shrinkwrap.max_face_stretch = {limit:g}x" in msg
    ids = ", ".join(str(v + 1) for v in garment_from_config(load_config(IMPORT + [f"garment.obj={path}"]).garment)[0]
                    .faces[SLIVER_FACE].tolist())
    assert f"the worst face {SLIVER_FACE} (vertices {ids}) to " in msg and "chart 'default', patch default_" in msg
    assert "nearest body part: torso" in msg and "it is a sliver in the pattern" in msg
    assert float(msg.split(") to ")[1].split("x")[0]) > 50.0
    # every patch is within its limit: the per-patch check alone passes it, and says so in the stats
    _, stats = _wrap(body, [f"garment.obj={path}", "garment.shrinkwrap.max_face_stretch=null"])
    assert stats["patch_stretch_max"] < 1.0 and stats["face_stretch_max"] > 50.0
    assert stats["face_stretch_worst"] == SLIVER_FACE
    # the same tube without the squashed face wraps within both limits
    _, stats = _wrap(body, [f"garment.obj={_write(tmp_path, 'tube.obj', _tube_obj())}"])
    assert stats["face_stretch_max"] < 2.0 and stats["faces_past_limit"] == 0


def test_face_stretch_is_the_area_ratio_and_the_principal_stretches_of_the_deformation():
    pattern = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    ratio, principal = face_stretch(np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.5]]),
                                    np.array([[0, 1, 2]]), pattern)
    np.testing.assert_allclose(ratio, [1.5]) and np.testing.assert_allclose(principal, [[3.0, 0.5]])
    ratio, _ = face_stretch(np.eye(3), np.array([[0, 1, 2]]), np.zeros((1, 3, 2)))
    assert np.isinf(ratio[0])  # a pattern triangle of no area


def test_the_face_cause_is_measured_first_the_body_parts_then_the_start_then_a_sliver():
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    limits = FaceLimits(limit=50.0, sliver=0.05, far=0.1)
    area = np.array([1.0, 1.0])
    split = face_cause(0, faces, ["left leg", "torso", "torso", "torso"], area, np.zeros(4), limits)
    assert "wrapped on different body parts (vertices 1, 2, 3 on the left leg, torso, torso)" in split
    assert "between the left leg and the torso" in split
    far = face_cause(1, faces, ["torso"] * 4, area, np.array([0.0, 0.0, 0.0, 0.25]), limits)
    assert "started 0.25 m from the body (vertex 4" in far
    sliver = face_cause(1, faces, ["torso"] * 4, np.array([1.0, 0.01]), np.zeros(4), limits)
    assert "sliver in the pattern" in sliver
    assert "place the garment closer" in face_cause(1, faces, ["torso"] * 4, area, np.zeros(4), limits)


def _tube_scene(tmp_path, body, squash):
    """The tube wrapped (the face check off) as a generation Scene, and its start positions (V, 3)."""
    cfg = load_config(IMPORT + [f"garment.obj={_write(tmp_path, 'g.obj', _tube_obj(squash))}",
                                "garment.shrinkwrap.max_face_stretch=null"])
    garment, cage = garment_from_config(cfg.garment)
    emb, stats = shrinkwrap(garment, cage, body, cfg.garment.shrinkwrap)
    scene = Scene(body=body, garment=garment, cage=cage, embedding=emb, sim=cfg.sim)
    return scene, start_points(body.vertices[None].double(), body.faces, emb)[0].numpy(), stats


def test_the_discard_summary_names_the_faces_their_place_and_the_measured_cause(tmp_path, body):
    # the wrap stretched the squashed face: every drape starting there has it past 2x
    scene, start, stats = _tube_scene(tmp_path, body, 0.001)
    drapes = [start + 1e-4 * k for k in range(4)]
    faces = discarded_faces(scene, drapes, stats)
    text = discard_summary({"area_stretched": 4}, scene.sim, faces)
    assert f"face {SLIVER_FACE} (chart 'default'" in text and "stretched past the limit in 4 of 4" in text
    assert "nearest body part: torso" in text and "already by the shrink-wrap" in text
    assert "uv_unit" not in text and "sleeve" not in text and "rest pose" not in text
    # a face the wrap left within the limits, stretched by the drapes: no unit, no wrap, no sleeve named
    scene, start, stats = _tube_scene(tmp_path, body, None)
    pulled = start.copy()
    pulled[scene.garment.faces[SLIVER_FACE, 1]] += [0.0, 0.0, 0.2]
    text = discard_summary({"area_stretched": 3, "nan": 1}, scene.sim, discarded_faces(scene, [pulled] * 3, stats))
    assert "in 3 of 3 discarded drapes" in text and "within the limits, so the drapes stretched them" in text
    assert "uv_unit" not in text and "shrink-wrap" not in text and "sleeve" not in text
    # the whole pattern too small (a wrong unit): the unit is named
    small = replace(scene.garment, uv_scale=0.5 * scene.garment.uv_scale)
    text = discard_summary({"area_stretched": 2}, scene.sim,
                           discarded_faces(replace(scene, garment=small), [start] * 2, stats))
    assert "whole garment's wrapped area is" in text and "garment.uv_unit" in text


def test_discard_summary_names_the_dominant_reason_what_it_measures_and_the_cause():
    sim = OmegaConf.create({"discard": {"max_area_compression": 0.75, "max_area_expansion": 1.0}})
    text = discard_summary({"area_stretched": 5, "nan": 1}, sim)
    assert text.startswith("area_stretched 5, nan 1; mostly area_stretched")
    assert "max_area_expansion (2x)" in text and "garment.uv_unit" in text and "rest pose" in text
    text = discard_summary({"not_converged": 2, "area_compressed": 3}, sim)
    assert "mostly area_compressed" in text and "(0.25x)" in text


def test_the_garment_command_is_on_the_entry_floor():
    assert COMMANDS["garment"][0] == "garment"


def test_a_whole_garment_stretched_by_the_wrap_names_the_wrap_when_its_unit_is_right():
    from pbc.geometry.garment.checks import check_stretch

    stretch = np.array([1.0, 40.0])
    args = (stretch, ["a_00", "b_00"], ["a", "b"], 2.0, {}, ["torso", "torso"], ["torso", "torso"], 30.0)
    with pytest.raises(ValueError) as wrap:
        check_stretch(*args, given=1.02)  # as given, its cloth is its pattern's size: the wrap blew it up
    assert "the UV unit is right" in str(wrap.value) and "check garment.uv_unit" not in str(wrap.value)
    with pytest.raises(ValueError) as unit:
        check_stretch(*args, given=29.0)  # as given already 29x its pattern: the pattern's unit is wrong
    assert "check garment.uv_unit" in str(unit.value)
