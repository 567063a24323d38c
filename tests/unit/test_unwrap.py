"""UVs for garments without usable ones (pbc.geometry.garment.unwrap) and chart mappings that always pass
(pbc.geometry.garment.obj_import.suggested_charts): tiny meshes made here, pbc's shirt without UVs, and the
corpus's hospital gown (no UVs, ../shared/corpus)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.ecosystems import no_uv_shirt_obj
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.core.paths import CONF_DIR
from pbc.core.validate import check_config
from pbc.geometry.garment.obj_import import drop_loose, garment_from_mesh, suggested_charts
from pbc.geometry.garment.placement import placed_mesh
from pbc.geometry.garment.unwrap import (
    UV_SOURCES,
    UnwrapSettings,
    charted_mesh,
    distortion_numbers,
    face_distortion,
    unwrap_settings_from_config,
    unwrapped_charts,
)
from pbc.geometry.meshio import parse_obj, read_obj
from pbc.geometry.meshops import face_areas, uv_islands

SETTINGS = UnwrapSettings()


def tube(cols: int = 16, rows: int = 6, radius: float = 0.2, height: float = 0.5) -> str:
    """A skirt-like tube (metres, y up) of triangles with no `vt` at all."""
    ang = np.linspace(0.0, 2 * np.pi, cols, endpoint=False)
    lines = [f"v {radius * np.sin(a):.9f} {-r * height / rows:.9f} {radius * np.cos(a):.9f}"
             for r in range(rows + 1) for a in ang]
    for r in range(rows):
        for c in range(cols):
            a, b = r * cols + c + 1, r * cols + (c + 1) % cols + 1
            lines += [f"f {a + cols} {b + cols} {b}", f"f {a + cols} {b} {a}"]  # outward, seen from outside
    return "\n".join(lines) + "\n"


def squares(count: int, shift: float = 0.0) -> str:
    """`count` unit squares side by side in 3D (groups a, b, c, ...), their UVs laid over each other (each
    square's UV box moved by `shift` from the last)."""
    lines, faces = [], []
    for k in range(count):
        lines += [f"v {2 * k + x} {y} 0" for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))]
        lines += [f"vt {k * shift + u} {v}" for u, v in ((0, 0), (1, 0), (1, 1), (0, 1))]
        n = 4 * k
        faces += [f"g {'abc'[k]}", f"f {n + 1}/{n + 1} {n + 2}/{n + 2} {n + 3}/{n + 3}",
                  f"f {n + 1}/{n + 1} {n + 3}/{n + 3} {n + 4}/{n + 4}"]
    return "\n".join(lines + faces) + "\n"


def _chart_ratio(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(C,) each chart's UV/3D area ratio and (C,) its image side (face_group)."""
    corners = mesh.uv[mesh.face_uv]
    island = uv_islands(mesh.faces, corners)
    a3 = face_areas(mesh.vertices, mesh.faces)
    auv = face_areas(corners.reshape(-1, 2), np.arange(3 * len(mesh.faces)).reshape(-1, 3))
    n = int(island.max()) + 1
    side = np.zeros(n, np.int64)
    side[island] = mesh.face_group
    return np.bincount(island, auv, n) / np.bincount(island, a3, n), side


def test_face_distortion_reads_area_and_angle():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 3)
    uv = np.array([[[0.0, 0], [1, 0], [0, 1]], [[0.0, 0], [2, 0], [0, 1]], [[0.0, 0], [2, 0], [0, 2]]])
    area, aniso = face_distortion(tri, uv)
    # the layout's scale (7/3 the 3D area) is divided out; the middle face is stretched along one axis only
    np.testing.assert_allclose(area, np.array([1.0, 2.0, 4.0]) * 3 / 7)
    np.testing.assert_allclose(aniso, [1.0, 2.0, 1.0])
    flat = np.array([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]])  # no 3D area: left out
    assert np.isnan(face_distortion(flat, uv[:1])).all()


def test_a_tube_without_uvs_unwraps_to_charts_that_import_on_two_sides():
    mesh = parse_obj(tube(), "tube.obj", require_uv=False)
    charted, how = charted_mesh(mesh, SETTINGS)
    assert how.kept == "xatlas" and how.projection_area > how.xatlas_area  # a round tube: the projection squeezes
    garment, names, _ = garment_from_mesh(charted, "tube.obj", uv_unit="m")  # no overlap on either side
    assert {n.split("_")[0] for n in names} == {"front", "back"}
    assert set(garment.face_side.tolist()) == {0, 1}
    # the UVs are in the mesh's metres: the pattern's area is the 3D area, face by face near enough
    pattern = garment.pattern().double().numpy()
    a3 = face_areas(charted.vertices, charted.faces).sum()
    assert abs(face_areas(pattern.reshape(-1, 2), np.arange(pattern.size // 2).reshape(-1, 3)).sum() / a3 - 1) < 0.05
    area, aniso = face_distortion(charted.vertices[charted.faces], charted.uv[charted.face_uv])
    assert np.abs(np.log(area)).max() < 0.1 and np.log(aniso).max() < 0.1
    # one texel density on both sides: every chart's UV/3D area ratio is the same
    ratio, side = _chart_ratio(charted)
    assert set(side.tolist()) == {0, 1} and np.abs(ratio - 1.0).max() < 0.05


def test_a_flat_panel_keeps_its_projection():
    mesh = parse_obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n", "panel.obj", require_uv=False)
    charted, how = charted_mesh(mesh, SETTINGS)
    assert how.kept == "projection" and how.projection_area == pytest.approx(0.0, abs=1e-9)
    assert "projection distorts no more" in how.line(SETTINGS.percentile)
    np.testing.assert_allclose(charted.uv[charted.face_uv], mesh.vertices[mesh.faces][..., :2])


def test_pbcs_shirt_without_uvs_imports(tmp_path):
    path = tmp_path / "shirt.obj"
    path.write_text(no_uv_shirt_obj())
    mesh, _ = placed_mesh(path, load_config(["garment=obj", f"garment.obj={path}"]).garment, None)
    ratio, side = _chart_ratio(mesh)
    assert set(side.tolist()) == {0, 1} and np.ptp(ratio) < 0.05 * ratio.mean()
    garment, names, _ = garment_from_mesh(mesh, str(path))
    assert len(names) == len(ratio)


def test_the_hospital_gown_unwraps_to_charts_that_import(corpus):
    mesh, _ = drop_loose(read_obj(corpus / "garments/assistive_gym/hospitalgown_reduced.obj", require_uv=False))
    unwrapped = unwrapped_charts(mesh, SETTINGS)
    garment, names, _ = garment_from_mesh(unwrapped, "gown", uv_unit="m")
    ratio, side = _chart_ratio(unwrapped)
    assert set(side.tolist()) == {0, 1} and np.abs(ratio - 1.0).max() < 0.05
    area, _ = distortion_numbers(mesh.vertices[mesh.faces], unwrapped.uv[unwrapped.face_uv], SETTINGS.percentile)
    assert area < 0.2  # the projection: 2.3 (and its 40 charts overlap)


def test_no_two_sides_part_three_charts_laid_over_each_other(tmp_path):
    mesh = parse_obj(squares(3), "three.obj")
    assert suggested_charts(mesh) is None
    with pytest.raises(ValueError, match=r"three.obj: UV islands 'a' and 'b' overlap.*fix: garment.uvs=unwrap"):
        garment_from_mesh(mesh, "three.obj", uv_unit="m")
    # the fix named works: the same file with garment.uvs=unwrap imports
    path = tmp_path / "three.obj"
    path.write_text(squares(3))
    gcfg = load_config(["garment=obj", f"garment.obj={path}", "garment.uvs=unwrap"]).garment
    garment_from_mesh(placed_mesh(path, gcfg, None)[0], str(path))


def test_two_overlapping_charts_get_a_complete_mapping_that_imports():
    mesh = parse_obj(squares(2, shift=0.5), "two.obj")
    with pytest.raises(ValueError, match=r"overlap .*fix: garment.charts=\{a:0,b:1\} .*or garment.uvs=unwrap"):
        garment_from_mesh(mesh, "two.obj", uv_unit="m")
    charts = suggested_charts(mesh)
    assert charts == {"a": 0, "b": 1}
    garment_from_mesh(mesh, "two.obj", charts=charts, uv_unit="m")
    # a chain a-b-c (a and c only touch): each group of charts goes the way most of it prefers
    chain = parse_obj(squares(3, shift=0.5), "chain.obj")
    assert suggested_charts(chain, {"a": 1, "b": 1, "c": 1}) == {"a": 1, "b": 0, "c": 1}


def test_a_folded_island_is_refused_naming_the_unwrap_and_imports_with_it(tmp_path):
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.2 0.2\n"
            "f 1/1 2/2 3/3\nf 2/2 4/4 3/3\n")
    with pytest.raises(ValueError, match=r"UV island 'default' is folded over.*garment.uvs=unwrap"):
        garment_from_mesh(parse_obj(text, "fold.obj"), "fold.obj")
    path = tmp_path / "fold.obj"
    path.write_text(text)
    gcfg = load_config(["garment=obj", f"garment.obj={path}", "garment.uvs=unwrap"]).garment
    garment, names, _ = garment_from_mesh(placed_mesh(path, gcfg, None)[0], str(path))
    assert names == ["front"]


def test_garment_uvs_takes_only_its_two_values(tmp_path):
    path = tmp_path / "tube.obj"
    path.write_text(tube())
    cfg = load_config(["garment=obj", f"garment.obj={path}", "garment.uvs=unwarp"])
    with pytest.raises(ValueError, match=r"garment.uvs='unwarp'.*one of \['file', 'unwrap'\]"):
        placed_mesh(path, cfg.garment, None)
    with pytest.raises(ValueError, match=r"garment.uvs='unwarp'.*one of \['file', 'unwrap'\]"):
        check_config(cfg)
    assert UV_SOURCES == ("file", "unwrap")


def test_unwrap_settings_mirror_the_config():
    node = OmegaConf.load(CONF_DIR / "garment" / "obj.yaml").unwrap
    assert unwrap_settings_from_config(node) == UnwrapSettings()
    with pytest.raises(ValueError, match="unknown garment.unwrap settings"):
        unwrap_settings_from_config({"texels": 3})
