"""The automatic cage, and a garment pbc did not make going through import -> cage -> shrink-wrap -> drape."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.tube_top import CHARTS, tube_top_obj

from pbc.geometry.autocage import _components, _edges, auto_cage
from pbc.geometry.cage import load_cage, save_cage, validate_cage
from pbc.geometry.garment import load_garment_config, make_tshirt
from pbc.geometry.garments import garment_from_config
from pbc.geometry.obj_import import import_garment

IMAGE = (512, 160, 16)


def _check_patches_connected(garment, cage):
    edges = _edges(garment)
    for p in cage.patches:
        assert len(_components(p.vertices, edges, garment.num_vertices)) == 1, p.name


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
    with pytest.raises(ValueError, match=r"past 3 patches"):
        auto_cage(ok, *IMAGE, chart_names=names, face_chart=chart, max_patches=3)


def test_a_garment_pbc_did_not_make_goes_through(foreign):
    """Import -> automatic cage -> shrink-wrap -> drapes, and the dataset reads back with a valid cage."""
    from pbc.config import load_config
    from pbc.data.dataset import load_dataset
    from pbc.data.generate import build_scene

    root, overrides, data_dir = foreign
    cfg = load_config(overrides)
    garment, cage = garment_from_config(cfg.garment)
    _check_patches_connected(garment, cage)
    assert {p.name.rsplit("_", 1)[0] for p in cage.patches} == {"front", "back", "band"}
    # cm read as stated: the front image's widest chart is the band, the tube's perimeter long, 80% of the image
    ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ring = np.stack([0.16 * np.sin(ang), 0.115 * np.cos(ang)], 1)
    perimeter = np.linalg.norm(np.roll(ring, -1, 0) - ring, axis=1).mean() * 16
    assert garment.uv_scale == pytest.approx(perimeter / 0.8, rel=1e-4)
    scene, stats = build_scene(cfg)
    assert stats["max_abs_sdf"] < 0.01 and stats["area_after_min"] > 0.3
    ds = load_dataset(data_dir)
    assert len(ds) >= 1 and ds.verts.shape[1] == garment.num_vertices
    assert np.isfinite(ds.verts).all()
    assert ds.manifest["drape_residual"]["max"] < float(cfg.sim.tolerance)  # static equilibrium reached
    # the dataset's garment (read back from its OBJ) is sampled where the cage was made for
    assert torch.equal(ds.garment.vertex_uv, garment.vertex_uv)
    validate_cage(ds.cage, ds.garment, *IMAGE)
    # far from the body: refused by the shrink-wrap, naming the fix
    far = load_config([*overrides, "garment.position_offset=[0,1.5,0]"])
    with pytest.raises(ValueError, match=r"from the body.*position_offset"):
        build_scene(far)


@pytest.mark.parametrize("exp", ["whole", "patch_03"])
def test_smoke_training_on_a_garment_pbc_did_not_make(foreign, exp):
    """`python -m pbc.train` on its dataset, unchanged: the whole model and one patch model."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root, overrides, data_dir = foreign
    run = root / "runs" / exp
    # the garment overrides the data was made with: training refuses a dataset its config does not describe
    r = subprocess.run([sys.executable, "-m", "pbc.train", *overrides, "trainer=smoke",
                        "image.whole_resolution=64", "image.patch_resolution=128", f"data.dir={data_dir}",
                        f"+experiment={exp}", f"hydra.run.dir={run}"], cwd=Path(__file__).resolve().parents[1],
                       env=dict(os.environ, PBC_ROOT=str(root)), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    from pbc.runs import scoped_name

    error = scoped_name("vertex_error_cm", "patch" if exp.startswith("patch") else "whole")  # its scope in its name
    assert metrics["status"] == "ok" and np.isfinite(metrics["test"][error])


def test_cli_writes_an_editable_cage(tmp_path, capsys):
    from pbc.geometry.garments import main

    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    out = tmp_path / "top.json"
    main(["garment=obj", f"garment.obj={path}", "garment.uv_unit=cm", "garment.charts={front:0,back:1,band:0}",
          "--out", str(out)])
    garment, names, _ = import_garment(path, charts=CHARTS, uv_unit="cm")
    cage = load_cage(out, garment, *IMAGE)
    assert {p.name.rsplit("_", 1)[0] for p in cage.patches} == set(names)
    assert f"wrote {out}" in capsys.readouterr().out


def test_a_cage_file_of_another_garment_is_refused_with_the_fix(tmp_path):
    from pbc.config import load_config

    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    cfg = load_config([f"garment.obj={path}"])  # the shirt's config: its cage file is the shirt's
    with pytest.raises(ValueError, match=r"made for a garment of 3153 vertices.*garment.cage=auto"):
        garment_from_config(cfg.garment)
