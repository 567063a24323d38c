"""The automatic cage, and a garment pbc did not make going through import -> cage -> shrink-wrap -> drape."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.autocage_runs import IMAGE, _check_patches_connected

from pbc.geometry.cage.base import validate_cage
from pbc.geometry.garment import garment_from_config


def test_a_garment_pbc_did_not_make_goes_through(foreign):
    """Import -> automatic cage -> shrink-wrap -> drapes, and the dataset reads back with a valid cage."""
    from pbc.core.config import load_config
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
                        f"+experiment={exp}", f"hydra.run.dir={run}"], cwd=Path(__file__).resolve().parents[2],
                       env=dict(os.environ, PBC_ROOT=str(root)), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    from pbc.core.runs import scoped_name

    error = scoped_name("vertex_error_cm", "patch" if exp.startswith("patch") else "whole")  # its scope in its name
    assert metrics["status"] == "ok" and np.isfinite(metrics["test"][error])


