"""The automatic cage, and a garment pbc did not make going through import -> cage -> shrink-wrap -> drape."""

from __future__ import annotations

import pytest
from helpers.autocage_runs import IMAGE, _check_patches_connected
from helpers.tube_top import CHARTS, tube_top_obj

from pbc.core.config import load_garment_config
from pbc.geometry.cage.auto import auto_cage
from pbc.geometry.cage.base import load_cage, save_cage
from pbc.geometry.garment import garment_from_config
from pbc.geometry.garment.obj_import import import_garment
from pbc.geometry.garment.tshirt import make_tshirt


def test_auto_cage_of_the_shirt_is_valid_connected_and_editable(tmp_path):
    cfg = load_garment_config("conf/garment/tshirt_coarse.yaml")
    garment, hand = make_tshirt(cfg)
    cage = auto_cage(garment, *IMAGE)  # validated inside: cover, sides, box + margin fits the crop
    _check_patches_connected(garment, cage)
    assert {p.side for p in cage.patches} == {0, 1}
    assert all(p.name.startswith(("front_", "back_")) for p in cage.patches)
    # as JSON in the patches/ format: it loads back identically (so a person can edit it)
    save_cage(cage, tmp_path / "auto.json", garment.num_vertices)
    back = load_cage(tmp_path / "auto.json", garment, *IMAGE)
    assert [p.vertices.tolist() for p in back.patches] == [p.vertices.tolist() for p in cage.patches]
    assert [p.box_512 for p in back.patches] == [p.box_512 for p in cage.patches]
    # a smaller crop needs more, smaller patches
    small = auto_cage(garment, 512, 96, 16)
    assert len(small.patches) > len(cage.patches)
    assert max(max(p.box_512[2] - p.box_512[0], p.box_512[3] - p.box_512[1]) for p in small.patches) <= 96 - 32


def test_a_chart_that_cannot_be_covered_is_refused(tmp_path):
    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    tight, _, _ = import_garment(path, charts=CHARTS, uv_unit="cm", uv_padding=0.01)
    with pytest.raises(ValueError, match=r"chart 'front' .*within the 16 px margin.*uv_padding"):
        auto_cage(tight, *IMAGE, chart_names=["front", "back", "band"])
    ok, names, chart = import_garment(path, charts=CHARTS, uv_unit="cm")
    with pytest.raises(ValueError, match=r"crop of 30 px cannot hold a 16 px margin"):
        auto_cage(ok, 512, 30, 16)
    with pytest.raises(ValueError, match=r"past garment.autocage.max_patches = 3 patches .*max_patches=6"):
        auto_cage(ok, *IMAGE, chart_names=names, face_chart=chart, max_patches=3)


def test_cli_writes_an_editable_cage(tmp_path, capsys):
    from pbc.cli.cage import run

    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    out = tmp_path / "top.json"
    run(["garment=obj", f"garment.obj={path}", "garment.uv_unit=cm", "garment.charts={front:0,back:1,band:0}",
          "--out", str(out)])
    garment, names, _ = import_garment(path, charts=CHARTS, uv_unit="cm")
    cage = load_cage(out, garment, *IMAGE)
    assert {p.name.rsplit("_", 1)[0] for p in cage.patches} == set(names)
    assert f"wrote {out}" in capsys.readouterr().out


def test_a_cage_file_of_another_garment_is_refused_with_the_fix(tmp_path):
    from pbc.core.config import load_config

    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    cfg = load_config([f"garment.obj={path}"])  # the shirt's config: its cage file is the shirt's
    with pytest.raises(ValueError, match=r"made for a garment of 3153 vertices.*garment.cage=auto"):
        garment_from_config(cfg.garment)
