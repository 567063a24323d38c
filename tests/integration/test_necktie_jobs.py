"""The necktie (appendix F): garment, cage, 4-joint poses, the configs and the 2.16M decoder preset."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.necktie_runs import TIE_DATA

from pbc.core.config import load_config
from pbc.geometry.garment import garment_from_config


@pytest.fixture(scope="module")
def cfg():
    return load_config(["+experiment=necktie", "garment.grid_spacing=0.015"])


@pytest.fixture(scope="module")
def tie(cfg):
    return garment_from_config(cfg.garment)


# ------------------------------------------------------------------------------------- training the tie
@pytest.fixture(scope="module")
def tie_ops(tie, tmp_path_factory):
    from pbc.pixels.operators import ImageOperators

    return ImageOperators.for_garment(tie[0], 256, 4, exact=True, cache_dir=tmp_path_factory.mktemp("ops"))


def test_the_necktie_trains_and_predicts_end_to_end(tmp_path):
    """`python -m pbc.train +experiment=necktie` on a few real drapes of a coarse tie, then pbc.predict."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from pbc.core.config import load_config
    from pbc.data.dataset import load_dataset
    from pbc.data.generate import generate
    from pbc.inference.predictor import ClothPredictor

    overrides = [*TIE_DATA, f"paths.data_dir={tmp_path}"]
    data_dir = generate(load_config(overrides))
    ds = load_dataset(data_dir)
    assert ds.manifest["posed_joints"] == ["lower_back", "spine", "neck", "neck1"]  # recorded by generate
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PBC_ROOT=str(tmp_path))

    def train(run, *extra):
        return subprocess.run([sys.executable, "-m", "pbc.train", *overrides, "trainer=smoke", f"data.dir={data_dir}",
                               f"hydra.run.dir={run}", *extra], cwd=root, env=env, capture_output=True, text=True,
                              timeout=300)

    r = train(tmp_path / "tie")
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((tmp_path / "tie" / "metrics.json").read_text())
    assert metrics["status"] == "ok" and np.isfinite(metrics["test"]["vertex_error_cm"])
    assert metrics["identity"]["window"] == [[0], 96, 160] and metrics["identity"]["space"] == "root"
    assert "edge_loss" in metrics["test"] and "normal_loss" in metrics["test"]  # appendix F's loss
    # the predictor rebuilds the 36-input net and the window from the run alone, and takes full poses
    pred = ClothPredictor.from_runs(tmp_path / "tie", None)
    assert pred.whole_net.input_joints == (0, 1, 3, 4) and pred.whole_net.in_features == 36
    pose = torch.from_numpy(np.array(ds.poses[:2])).float()
    out = pred(pose)
    assert out.shape == (2, ds.verts.shape[1], 3) and torch.isfinite(out).all()
    assert torch.allclose(pred(pose[0]), out[0], atol=1e-6)  # one pose (J, 3, 3) -> (V, 3)
    # ... and as far from the simulation as the run's own test says (same poses' scale: cm, not metres off)
    assert (out - torch.from_numpy(np.array(ds.verts[:2]))).norm(dim=-1).mean() < 0.1
    r = subprocess.run([sys.executable, "-m", "pbc.predict", str(tmp_path / "tie"), "--poses", "test", "--out",
                        str(tmp_path / "pred")], cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert list((tmp_path / "pred" / "meshes").glob("*.obj")) and (tmp_path / "pred" / "contact_sheet.png").is_file()
    # the dataset preview shows the 64 x 256 window in the root frame, as training serves it
    r = subprocess.run([sys.executable, "-m", "pbc", "preview", str(data_dir), "--samples", "2", *overrides],
                       cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    from PIL import Image

    w, h = Image.open(data_dir / "preview_pixels" / "cloth_images.png").size
    assert w > 2 * h  # 2 samples x 1 side of a 1:4 image, not 2 x 2 squares
    # a model that would not see a joint the data moves is refused at the door, before training
    r = train(tmp_path / "blind", "data.pose_joints=[lower_back,spine,neck]", "body.sampling.posed_joints="
              "[lower_back,spine,neck,neck1]")
    assert r.returncode != 0 and "poses joints ['neck1'] that the model does not read" in r.stderr
