"""The main job's closing table puts each model beside the training mean shape, over the same vertices;
the mean-shape baseline equals a naive per-sample loop."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
from helpers.evaluate_world import fake_dataset  # noqa: E402

from pbc.core.runs import RunRecord, monitor  # noqa: E402
from pbc.data.baselines import mean_shape_errors  # noqa: E402
from pbc.jobs import main as main_job  # noqa: E402
from pbc.pixels.frames import from_offsets, to_offsets  # noqa: E402
from pbc.pixels.target import make_target  # noqa: E402


def naive_mean_shape_error(ds, split: str, vertices=None) -> float:
    skin = make_target(ds, None, "fc").skinner
    offsets = []
    for i in ds.split("train"):
        a, f = skin(torch.from_numpy(ds.poses[i:i + 1].copy()).float())
        offsets.append(to_offsets(torch.from_numpy(ds.verts[i:i + 1].copy()), a, f)[0].double())
    mean = torch.stack(offsets).mean(0)
    errs = []
    for i in ds.split(split):
        a, f = skin(torch.from_numpy(ds.poses[i:i + 1].copy()).float())
        d = (from_offsets(mean[None].float(), a, f)[0] - torch.from_numpy(ds.verts[i].copy())).norm(dim=-1)
        errs.append(float(d[vertices].mean() if vertices is not None else d.mean()))
    return 100.0 * sum(errs) / len(errs)


def test_mean_shape_errors_equal_the_naive_loop(tmp_path):
    ds = fake_dataset(tmp_path / "data")
    patch = ds.cage.patches[7].vertices
    got = mean_shape_errors(ds, ("train", "test"), batch=3)
    assert abs(got["test"] - naive_mean_shape_error(ds, "test")) < 1e-4
    assert abs(got["train"] - naive_mean_shape_error(ds, "train")) < 1e-4
    assert abs(mean_shape_errors(ds, ("test",), patch)["test"] - naive_mean_shape_error(ds, "test", patch)) < 1e-4
    assert got["test"] > 0.01  # the fake offsets vary with pose: the mean cannot be exact


def test_closing_table_shows_each_model_beside_the_mean_shape(tmp_path, monkeypatch):
    ds = fake_dataset(tmp_path / "data")
    monkeypatch.setattr(main_job, "load_dataset", lambda d, check=True: ds)
    runs = tmp_path / "runs"
    RunRecord(kind="whole", test={"vertex_error_cm": 1.25, "normal_distance": 0.01, "image_loss": 0.02},
              optimized_metric=monitor("whole"), config={"model": {"patch_id": None}},
              data={"dir": str(ds.dir)}).write(runs / "whole")
    RunRecord(kind="patch", test={"patch_vertex_error_cm": 0.75, "patch_normal_distance": 0.02,
                                  "patch_image_loss": 0.03},
              optimized_metric=monitor("patch"), config={"model": {"patch_id": 7}},
              data={"dir": str(ds.dir)}).write(runs / "patch_07")
    lines = main_job.closing_table(runs).splitlines()
    assert "mean shape cm" in lines[0]
    whole, patch = lines[2].split(), lines[3].split()
    assert whole[:4] == ["whole", "whole", "garment", "1.250"]
    assert abs(float(whole[4]) - mean_shape_errors(ds, ("test",))["test"]) < 1e-3
    assert patch[:4] == ["patch_07", "patch", "7", "0.750"]
    assert abs(float(patch[4]) - mean_shape_errors(ds, ("test",), ds.cage.patches[7].vertices)["test"]) < 1e-3
