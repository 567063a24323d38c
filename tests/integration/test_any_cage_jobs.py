"""The stitched path on a cage that is not the shirt's 28 patches: the tube top's automatic cage.

Fast: a stitcher built for the tube top's cage (import + automatic cage + operators, no drape) given the
exact crops of a known offset field returns that field. Slow: the tube top draped (the session's
`foreign` dataset), its whole model and its stacked all-patches job trained with `trainer=smoke`, then
`ClothPredictor.from_runs` under every seam method and `pbc.evaluate` on them.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.any_cage import SHIRT_PATCHES, _stitch_cfg, _train, _trained
from omegaconf import OmegaConf

from pbc.stitch.seams import METHODS

ROOT = Path(__file__).resolve().parents[2]
# what the smoke jobs train at: small images keep the two jobs to seconds on the 2-core CPU


@pytest.fixture(scope="module")
def trained(foreign):
    """The tube top's whole model and its stacked all-patches job (P single-patch runs exported under it)."""
    root, overrides, data_dir = foreign
    return root, _trained(root, overrides, data_dir, "whole"), _trained(root, overrides, data_dir, "patches")


def test_stitched_prediction_and_evaluation_on_a_cage_of_another_patch_count(trained, tmp_path):
    from pbc.inference.predictor import ClothPredictor, fit_training_pca
    from pbc.jobs.evaluate import evaluate

    root, whole, patches = trained
    pred = ClothPredictor.from_runs(whole, patches, _stitch_cfg("average"))
    ds = pred.dataset
    P, V = len(ds.cage.patches), ds.garment.vertices.shape[0]
    assert 1 < P != SHIRT_PATCHES
    assert len(pred.patch_nets) == P and len(list((patches / "patches").glob("patch_*"))) == P
    pred.use_pca(fit_training_pca(pred, 128, 64))
    poses = torch.from_numpy(np.array(ds.poses[:2])).float()
    crops = pred.patch_crops(poses)
    assert crops.shape[:2] == (2, P)
    # every vertex is read from crops whose blend weights sum to 1 (a vertex no crop covers would read 0)
    ones = pred.stitcher(torch.ones_like(crops), "average")
    assert torch.allclose(ones, torch.ones_like(ones), atol=1e-5)
    for method in METHODS:
        x = pred(poses, method=method)
        assert x.shape == (2, V, 3) and torch.isfinite(x).all(), method

    # pbc.evaluate on the same runs: every method scored, the ground-truth crops on the representation floor
    cfg = OmegaConf.merge(OmegaConf.load(ROOT / "conf/evaluate.yaml"),
                          {"whole_run": str(whole), "patch_runs": str(patches), "pca_fit_max": 64,
                           "stitch": _stitch_cfg("pca")})
    del cfg["defaults"]
    m = evaluate(cfg, tmp_path / "evaluate")
    e = m["entries"]
    for method in METHODS:
        for entry in (f"patches_{method}", f"gt_crops_{method}"):
            assert np.isfinite(e[entry]["vertex_error_cm"]), entry
    floor = e["floor_512"]["vertex_error_cm"]
    # not pca: its basis is fitted on this dataset's one or two training samples, which do not span a test pose
    for method in ("average", "hierarchy", "hierarchy_detail"):
        assert e[f"gt_crops_{method}"]["vertex_error_cm"] <= floor + 1e-3, method
    assert json.loads((tmp_path / "evaluate" / "metrics.json").read_text())["entries"].keys() == e.keys()

    # a patch count mismatch: the runs of all but two patches, one clear error naming them and the fix
    runs = sorted((patches / "patches").glob("patch_*"))
    with pytest.raises(ValueError, match=rf"missing patch runs for patch ids \[1, {P - 1}\]: the dataset's cage "
                                         rf"has {P} patches .*\+experiment=patch model.patch_id=ID"):
        ClothPredictor.from_runs(whole, [runs[0], *runs[2:-1]], _stitch_cfg("average"))


def test_a_patch_id_outside_the_garments_cage_is_refused(foreign):
    """`+experiment=patch model.patch_id=P` on a P-patch garment: refused before training, naming the range."""
    from pbc.data.dataset import load_dataset

    root, overrides, data_dir = foreign
    P = len(load_dataset(data_dir).cage.patches)
    run, r = _train(root, overrides, data_dir, "out_of_range", "+experiment=patch", f"model.patch_id={P}")
    assert r.returncode != 0 and not (run / "checkpoints").exists()
    # the dataset's target refuses it as it opens (pbc.pixels.target.make_target), before any model is built
    assert re.search(rf"unknown patch_id {P}: dataset \S+ has patches 0\.\.{P - 1}\n", r.stderr), r.stderr[-3000:]


def test_the_stacked_job_keeps_one_best_weights_file_and_one_last_file(trained):
    """Checkpoints a user can afford. The stacked job's checkpoints/ holds the best epoch
    (weights only: tested, exported, predicted from, never resumed) and last.ckpt (with the optimizer's
    state, for ckpt_path=last); every exported patch run holds its patch's weights only."""
    _, _, patches = trained
    files = sorted(p.name for p in (patches / "checkpoints").glob("*.ckpt"))
    assert len(files) == 2 and "last.ckpt" in files, files
    best = torch.load(patches / "checkpoints" / next(f for f in files if f != "last.ckpt"), map_location="cpu",
                      weights_only=False)
    last = torch.load(patches / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert "optimizer_states" not in best and last["optimizer_states"]
    weights = sum(v.numel() * v.element_size() for v in best["state_dict"].values())
    size = (patches / "checkpoints" / files[0]).stat().st_size
    assert size < 1.2 * weights + 200_000  # the weights and the hparams, no Adam moments (2x the weights)
    for ck in (patches / "patches").glob("patch_*/checkpoints/*.ckpt"):
        exported = torch.load(ck, map_location="cpu", weights_only=False)
        assert not {"optimizer_states", "lr_schedulers", "loops", "callbacks"} & set(exported), ck
