"""A long-sleeved shirt as MakeHuman clothes (tests/helpers/long_sleeves.py) through `pbc garment fit` on Anny in
its A-pose, at tiny settings and with the drape's own discard checks on: its sleeves are wrapped on the arms
(pbc.geometry.shrinkwrap's regions), so the drapes are kept. Before, the sleeves were wrapped from the spine onto
the torso and most drapes were discarded (area_compressed: cloth caught between arm and torso)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.long_sleeves import long_sleeve_mhclo  # noqa: E402

from pbc.core.config import load_config  # noqa: E402
from pbc.geometry.body import body_from_config  # noqa: E402
from pbc.geometry.body.anny import base_mesh_vertices  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = 4
TINY = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128", "datamodule.batch_size=4",
        "data.workers=1"]  # a few poses drape in less time than a second worker takes to start


def test_a_long_sleeved_makehuman_shirt_with_collar_and_cuffs_is_fitted_on_a_posed_anny_with_its_drapes_kept(
        tmp_path):
    """The shirt has a folded collar and turned-back cuffs lying on it (pieces of their own): they are wrapped on
    top of the shirt and their drapes start there (tests/unit/test_layers.py), and the drapes are kept."""
    cfg = load_config(["body=anny"])
    path = long_sleeve_mhclo(tmp_path / "mh", body_from_config(cfg.body), base_mesh_vertices(cfg.body).numpy(),
                             layers=True)
    out = tmp_path / "fit"
    env = dict(os.environ, PBC_ROOT=str(tmp_path), PBC_WARP_CACHE=str(ROOT / ".cache" / "warp"),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    res = subprocess.run(["pbc", "garment", "fit", str(path), "body=anny", *TINY, "--samples", str(SAMPLES),
                          "--epochs", "1", "--out", str(out)], env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
    stretch = float(res.stdout.split("most stretched patch ")[1].split()[1].rstrip("x"))
    assert stretch < 1.5  # the sleeves wrapped round the arms (the nearest-surface wrap: 2x)
    manifest = json.loads((out / "data" / "manifest.json").read_text())
    counts = manifest["counts"]
    assert counts["kept"] >= SAMPLES - 1, counts  # with the drape's 0.25x area check on
    assert manifest["shrinkwrap"]["layer_vertices"] > 0
    metrics = json.loads((out / "whole" / "metrics.json").read_text())
    assert metrics["status"] == "ok" and np.isfinite(metrics["test"]["vertex_error_cm"])  # a NaN loss before
