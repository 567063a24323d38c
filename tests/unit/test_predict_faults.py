"""Faults at the predictor and edit doors: model names, runs made at other image sizes, empty pose files, --max,
and non-finite edit values. Synthetic runs (tests/unit/test_predict.py's fake_run on the stand-in dataset):
no drape, no training."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from test_predict import IMAGE, fake_run
from test_robustness import stand_in_dataset

from pbc.inference.poses import PoseSet, check_max_poses, read_poses
from pbc.inference.predictor import ClothPredictor, load_decoder, stitch_config


@pytest.fixture(scope="module")
def runs(tmp_path_factory, body):
    """(dataset dir, whole run, a sweep of one patch run per cage patch), all at IMAGE's sizes."""
    root = tmp_path_factory.mktemp("predict_faults")
    data = stand_in_dataset(root / "data", body)
    whole = fake_run(root / "whole", data)
    sweep = root / "patches"
    for k in range(28):
        fake_run(sweep / f"{k}_experiment=patch_{k:02d}", data, "patch", k, seed=k + 1)
    return data, whole, sweep


def _pose(n: int = 2) -> torch.Tensor:
    return torch.eye(3).expand(n, 10, 3, 3).clone()


# ============================================================================ model names
def test_predictor_refuses_an_unknown_model_name(runs):
    data, whole, sweep = runs
    pred = ClothPredictor.from_runs(whole, sweep)  # used to answer all of these with the stitched patches
    for model in ("Whole", "whole_shirt", "patch", ""):
        with pytest.raises(ValueError, match=rf"model={model!r} is not a predictor model; choose one of "
                                             r"\['patches', 'whole'\]"):
            pred(_pose(), model=model)
    assert pred(_pose(), model="whole").shape == pred(_pose()).shape == (2, len(pred.faces.unique()), 3)


def test_predict_to_dir_checks_the_model_before_making_its_folder(runs, tmp_path):
    from pbc.jobs.predict import predict_to_dir

    data, whole, _ = runs
    pred = ClothPredictor.from_runs(whole)
    with pytest.raises(ValueError, match="choose one of"):
        predict_to_dir(pred, _pose(), ["a", "b"], tmp_path / "out", model="Whole", sheet=0)
    assert not (tmp_path / "out").exists()
    # a person on a model of one body, or a person that is not an index: refused, nothing written
    for person, message in ((0, "draped on one body"), (1.5, "an integer")):
        with pytest.raises(ValueError, match=message):
            predict_to_dir(pred, _pose(), ["a", "b"], tmp_path / "out", person=person, sheet=0)
        assert not (tmp_path / "out").exists()


# ============================================================================ image sizes across runs
def test_runs_at_other_image_sizes_are_compared_when_the_predictor_is_built(runs, tmp_path):
    data, whole, sweep = runs
    # a whole run whose config says 128-pixel patch images (40-pixel crops); the patch runs made 20-pixel ones
    other = fake_run(tmp_path / "whole_128", data)
    rec = json.loads((other / "metrics.json").read_text())
    rec["config"]["image"]["patch_resolution"] = 128
    (other / "metrics.json").write_text(json.dumps(rec))
    # used to build, then fail in the stitcher: mat1 and mat2 shapes cannot be multiplied (...x11200 and 44800x3)
    with pytest.raises(ValueError, match=rf"patch run {sweep}/0_experiment=patch_00 was trained at other image "
                                         rf"sizes than {other}: patch_resolution 64, crop_size 20(.|\n)*vs "
                                         r"patch_resolution 128, crop_size 40"):
        ClothPredictor.from_runs(other, sweep)


def test_constructor_compares_patch_nets_with_the_image_config(runs):
    import pbc.data.dataset as datasets

    data, _, sweep = runs
    nets = [load_decoder(next((sweep / f"{k}_experiment=patch_{k:02d}" / "checkpoints").glob("*.ckpt")))[0]
            for k in range(28)]
    image = dict(IMAGE, patch_resolution=128)
    with pytest.raises(ValueError, match=r"patch models \[0, 1, 2, 3, 4, 5, 6, 7\] \.\.\. predict \(20, 20\) crops, "
                                         r"the image config gives \(40, 40\)"):
        ClothPredictor(datasets.load_dataset(data), image, None, nets, stitch_config("average"))


# ============================================================================ pose files and --max
def _dataset():
    names = [f"j{i}" for i in range(10)]
    return SimpleNamespace(poses=np.zeros((1, 10, 3, 3)), body=SimpleNamespace(skeleton=SimpleNamespace(names=names)),
                           manifest={}, dir="ds")


def test_empty_or_truncated_pose_file_is_named(tmp_path):
    empty = tmp_path / "poses.npy"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=rf"pose file {empty} is empty \(0 bytes\)(.|\n)*np.save"):
        read_poses(empty, _dataset())  # was a bare EOFError naming no file
    cut = tmp_path / "cut.npy"
    np.save(cut, np.tile(np.eye(3, dtype=np.float32), (2, 10, 1, 1)))
    cut.write_bytes(cut.read_bytes()[:9])  # the magic string and part of the header
    with pytest.raises(ValueError, match=rf"pose file {cut} is not a complete numpy .npy array"):
        read_poses(cut, _dataset())


@pytest.mark.parametrize("bad", [0, -1, 2.5, True, "3"])
def test_max_poses_must_be_at_least_one(bad):
    # --max 0 wrote every pose and --max -1 all but one (the CLI sliced poses[:n] when n was truthy)
    with pytest.raises(ValueError, match=r"--max .*an integer >= 1"):
        check_max_poses(bad)


def test_first_poses_keeps_names_truth_and_people_in_step():
    poses, truth = _pose(3), torch.zeros(3, 5, 3)
    p, names, t, who = PoseSet(poses, ["a", "b", "c"], truth, np.array([2, 0, 1])).first(2)
    assert (p.shape[0], names, t.shape[0], who.tolist()) == (2, ["a", "b"], 2, [2, 0])
    assert PoseSet(poses, ["a", "b", "c"], None, None).first(None).names == ["a", "b", "c"]


# ============================================================================ edit values
@pytest.mark.parametrize("field, flag", [("normal", "--normal"), ("shift_u", "--shift-u"), ("normal_gain",
                                         "--normal-gain"), ("feature_amplitude", "--feature-amplitude")])
def test_edit_refuses_non_finite_values(field, flag):
    from pbc.jobs.edit import EditSpec

    for v in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match=rf"edit values must be finite numbers(.|\n)*{field}={v!r} \({flag}\)"):
            EditSpec(**{field: v})


def test_edit_with_nan_writes_nothing(tmp_path):
    from pbc.jobs.edit import run_edit

    out = tmp_path / "edit"
    args = argparse.Namespace(overrides=[], resolution=None, data_dir=str(tmp_path / "no_data"), sample=0, run=None,
                              shift_u=0.0, shift_v=0.0, normal=float("nan"), normal_gain=0.0, patch=None, mask=None,
                              mask_side=None, rect=None, feature=None, feature_rect=None, feature_amplitude=0.01,
                              gallery=False, out=str(out))
    # used to write edited.npy and after.obj full of NaN, then die in matplotlib
    with pytest.raises(ValueError, match=r"normal=nan \(--normal\)"):
        run_edit(args)
    assert not Path(out).exists()
