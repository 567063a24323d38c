"""The training poses' joint-angle range recorded in the run (RunRecord.pose_range, written by pbc.train): what
it holds, that predict reads it from the run (a run whose dataset is gone still flags a clip's frames), and
the fallback, said in one line, for a run made before runs recorded it."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from helpers.cli import exit_code
from test_bvh import clip_text, random_poses
from test_predict import fake_run
from test_robustness import stand_in_dataset

import pbc.inference.poses
from pbc.cli.predict import main
from pbc.core.runs import RunRecord
from pbc.data.dataset import load_dataset
from pbc.inference.predictor import ClothPredictor
from pbc.jobs.predict import predict_sequence
from pbc.jobs.train import pose_range_record
from pbc.motion.bvh import read_bvh
from pbc.motion.ranges import angle_range, range_from_record
from pbc.motion.retarget import bvh_to_poses, choose_joint_map


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory, body):
    return stand_in_dataset(tmp_path_factory.mktemp("range") / "data", body)


def recording_run(d, data_dir):
    """A fake finished run whose record holds its training range, as pbc.train writes it."""
    run = fake_run(d, data_dir)
    record = RunRecord.read(run)
    record.pose_range = pose_range_record(load_dataset(data_dir))
    record.write(run)
    return run


def test_train_records_the_training_splits_range(dataset_dir, tmp_path):
    ds = load_dataset(dataset_dir)
    rec = pose_range_record(ds)
    names = list(ds.body.skeleton.names)
    idx = ds.split("train")
    assert rec["split"] == "train" and rec["poses"] == len(idx) > 0 and list(rec["deg"]) == names
    np.testing.assert_allclose(range_from_record(rec, names).deg, angle_range(np.asarray(ds.poses)[idx]).deg, atol=0)
    assert rec["chart"] == range_from_record(rec, names).chart == "swing_twist"
    # through metrics.json and back; a record of another body (a joint missing) reads as none
    run = recording_run(tmp_path / "run", dataset_dir)
    assert RunRecord.read(run).pose_range == json.loads(json.dumps(rec))
    assert range_from_record(rec, [*names, "l_knee"]) is None and range_from_record(None, names) is None
    # a malformed range is refused when the record is read, naming the entry
    bad = json.loads((run / "metrics.json").read_text())
    bad["pose_range"]["deg"]["l_arm"]["z"] = [10.0, -10.0]
    (run / "metrics.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"pose_range/deg/l_arm/z: \[10.0, -10.0\] is not a \[min, max\]"):
        RunRecord.read(run)
    # so is a chart no reader knows, on the record and on the table alone
    with pytest.raises(ValueError, match=r"pose_range/chart: 'quaternion' is not a joint-angle chart \(euler_xzy, "):
        range_from_record({**rec, "chart": "quaternion"}, names)
    bad["pose_range"] = {**rec, "chart": "quaternion"}
    (run / "metrics.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"pose_range/chart: 'quaternion'"):
        RunRecord.read(run)


def test_a_run_whose_dataset_is_gone_still_flags_the_frames(dataset_dir, tmp_path, monkeypatch):
    data = shutil.copytree(dataset_dir, tmp_path / "data")
    run = recording_run(tmp_path / "run", data)
    predictor = ClothPredictor.from_runs(run)  # opens the data (garment, body, embedding)...
    shutil.rmtree(data)  # ...then the dataset is deleted
    # the range must come from the run: reading the dataset's training poses is an error here
    monkeypatch.setattr(pbc.inference.poses, "training_pose_range", lambda ds: pytest.fail("read the dataset's poses"))
    clip = tmp_path / "clip.bvh"
    clip.write_text(clip_text(random_poses(6, seed=3)))
    bvh = read_bvh(clip)
    motion = bvh_to_poses(bvh, predictor.dataset.body.skeleton, choose_joint_map(bvh))
    res = predict_sequence(predictor, motion, tmp_path / "out", video=None, glb=False, progress=False)
    rep = res["pose_range"]
    assert res["pose_range_source"] == f"recorded in the run {run}"
    assert 0 < rep["num_outside"] == len(rep["frames_outside"])  # limit-wide poses vs the stand-in's small turns
    recorded = RunRecord.read(run).pose_range["deg"]
    assert rep["range_deg"] == {j: {a: [round(v, 3) for v in lo_hi] for a, lo_hi in axes.items()}
                                for j, axes in recorded.items()}
    assert not any("records no training pose range" in n for n in res["notes"])


def test_an_older_run_falls_back_to_its_dataset_saying_so(dataset_dir, tmp_path, capsys):
    run = fake_run(tmp_path / "old", dataset_dir)  # a record without pose_range
    clip = tmp_path / "clip.bvh"
    clip.write_text(clip_text(random_poses(4, seed=5)))
    out = tmp_path / "out"
    assert exit_code(main, [str(run), "--poses", str(clip), "--out", str(out), "--video", "none", "--no-glb"]) == 0
    printed = capsys.readouterr().out
    res = json.loads((out / "predict.json").read_text())
    line = (f"the run {run} records no training pose range (made before runs recorded it): the range is taken "
            f"from the training split of its dataset {dataset_dir}")
    assert printed.count(line) == 1 and line in res["notes"]
    assert res["pose_range_source"] == f"the training split of its dataset {dataset_dir}"
    ds = load_dataset(dataset_dir)
    names = list(ds.body.skeleton.names)
    want = angle_range(np.asarray(ds.poses)[ds.split("train")]).deg
    got = np.array([[res["pose_range"]["range_deg"][n][a] for a in "xyz"] for n in names])
    np.testing.assert_allclose(got, want, atol=1e-3)
