"""The run record (pbc.core.runs.RunRecord): the one reader and writer of metrics.json. Its kind is validated
when a record is made (so on every read and write), a finished training record names the metric that chose
its checkpoint, metric names are scoped for patch models, and the run-dir reader (load_run / read_run)
reads every record through it: a bad record reads as a failed run, and the predictor's read_run refuses
anything but a finished training run with a checkpoint."""

from __future__ import annotations

import json

import pytest

from pbc.core.runs import FAILED, INCOMPLETE, OK, ModelKind, RunRecord, load_run, monitor, read_run, scoped_name


def _whole(**kw) -> RunRecord:
    return RunRecord(kind="whole", optimized_metric=monitor("whole"), **kw)


def test_record_round_trips_through_metrics_json(tmp_path):
    rec = _whole(test={"vertex_error_cm": 2.5, "normal_distance": 0.03}, val_best={"vertex_error_cm": 2.4},
                 config={"model": {"kind": "whole"}}, data={"dir": "/d"}, epochs=3, seconds=1.5,
                 extra={"note": {"x": 1}})
    path = rec.write(tmp_path)
    assert path == tmp_path / "metrics.json" and not list(tmp_path.glob(".*"))  # atomic: no temp file left
    raw = json.loads(path.read_text())
    assert raw["kind"] == "whole" and raw["note"] == {"x": 1}  # extra blocks sit at the top level
    assert "error" not in raw and "exported_from" not in raw  # unset fields are not written
    back = RunRecord.read(tmp_path)
    assert back == rec and back.kind is ModelKind.WHOLE
    assert back.metrics() == {"test/vertex_error_cm": 2.5, "test/normal_distance": 0.03,
                              "val_best/vertex_error_cm": 2.4, "note/x": 1.0, "epochs": 3.0, "seconds": 1.5}


def test_kind_is_validated_once_on_read_and_write(tmp_path):
    with pytest.raises(ValueError, match="'blob' is not a model kind; one of whole, patch, patches, fc"):
        RunRecord(kind="blob")
    (tmp_path / "metrics.json").write_text(json.dumps({"status": "ok", "kind": "blob"}))
    with pytest.raises(ValueError, match="metrics.json is not a run record.*not a model kind"):
        RunRecord.read(tmp_path)
    rec = _whole()
    rec.kind = "blob"  # changed after it was made: refused at the write, nothing written
    with pytest.raises(ValueError, match="not a model kind"):
        rec.write(tmp_path / "w")
    assert not (tmp_path / "w" / "metrics.json").exists()
    assert [k.value for k in ModelKind] == ["whole", "patch", "patches", "fc"]


def test_a_finished_training_record_names_its_checkpoint_metric():
    with pytest.raises(ValueError, match="chosen by val/patch_vertex_error_cm, the record says 'val/vertex_error_cm'"):
        RunRecord(kind="patch", optimized_metric="val/vertex_error_cm")
    # an exported patch run: chosen by its stacked run's mean, which it names instead
    assert RunRecord(kind="patch", exported_from="/stacked").optimized_metric is None
    with pytest.raises(ValueError, match="test/vertex_error_cm is not a number"):
        _whole(test={"vertex_error_cm": "2.5"})
    with pytest.raises(ValueError, match="status 'done'"):
        RunRecord(status="done")
    with pytest.raises(ValueError, match="must say why"):
        RunRecord(status=FAILED)
    with pytest.raises(ValueError, match=r"extra blocks \['config'\]"):
        RunRecord(extra={"config": {}})


def test_patch_metrics_are_scoped():
    assert scoped_name("vertex_error_cm", ModelKind.PATCH) == "patch_vertex_error_cm"
    assert scoped_name("normal_distance_std", "patch") == "patch_normal_distance_std"
    assert scoped_name("vertex_error_cm", "patches") == "vertex_error_cm"  # the stacked run's mean
    with pytest.raises(ValueError, match="not a model kind"):
        monitor("patchs")
    rec = RunRecord(kind="patch", optimized_metric=monitor("patch"), test={"patch_vertex_error_cm": 1.2})
    assert rec.metric("test", "vertex_error_cm") == 1.2 and rec.metric("train", "vertex_error_cm") is None


def test_failure_records_why_and_what_was_configured(tmp_path):
    try:
        raise FloatingPointError("non-finite loss")
    except FloatingPointError as e:
        rec = RunRecord.failure(e, {"model": {"kind": "patch", "patch_id": 4}}, "Traceback ...")
    rec.write(tmp_path)
    run = load_run(tmp_path, events=False)
    assert run.status == FAILED and run.error == "FloatingPointError: non-finite loss"
    assert run.kind is ModelKind.PATCH and run.patch_id == 4  # from the recorded config
    # a config whose kind is the error's cause records no kind rather than failing to record the failure
    assert RunRecord.failure("bad", {"model": {"kind": "blob"}}).kind is None
    with pytest.raises(ValueError, match=r"the run failed \(FloatingPointError: non-finite loss\)"):
        read_run(tmp_path)


def test_reader_states(tmp_path):
    (tmp_path / "killed" / ".hydra").mkdir(parents=True)
    run = load_run(tmp_path / "killed", tmp_path, events=False)
    assert run.status == INCOMPLETE and run.name == "killed" and "no metrics.json" in run.error
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metrics.json").write_text(json.dumps({"status": "ok", "kind": "whole"}))  # no optimized_metric
    run = load_run(bad, events=False)
    assert run.status == FAILED and "unreadable metrics.json" in run.error and run.record is None
    ev = tmp_path / "evaluate"
    RunRecord(extra={"entries": {"whole": {"vertex_error_cm": 1.0}}}, seconds=2.0).write(ev)
    run = load_run(ev, events=False)
    assert run.status == OK and run.kind is None and run.metrics["entries/whole/vertex_error_cm"] == 1.0
    with pytest.raises(ValueError, match="not a training run"):
        read_run(ev)
    with pytest.raises(ValueError, match="no metrics.json"):
        read_run(tmp_path / "killed")


def test_read_run_finds_the_best_checkpoint_of_a_moved_run(tmp_path):
    moved = tmp_path / "moved"
    (moved / "checkpoints").mkdir(parents=True)
    (moved / "checkpoints" / "epoch_003.ckpt").write_bytes(b"x")
    (moved / "checkpoints" / "last.ckpt").write_bytes(b"x")
    (moved / "checkpoints" / "epoch_007.ckpt").write_bytes(b"x")
    # recorded where it was trained; the run dir now lives elsewhere
    _whole(best_checkpoint="/elsewhere/run/checkpoints/epoch_003.ckpt",
           config={"image": {"whole_resolution": 64}}, identity={"patch_id": None, "garment_hash": "g"}).write(moved)
    run = read_run(moved)
    assert run.checkpoint == moved / "checkpoints" / "epoch_003.ckpt"  # the recorded best, not the newest
    assert run.kind is ModelKind.WHOLE and run.garment_hash == "g" and run.patch_id is None
    assert run.config == {"image": {"whole_resolution": 64}}  # the record's config: what it trained with
    (moved / "checkpoints" / "epoch_003.ckpt").unlink()
    assert read_run(moved).checkpoint == moved / "checkpoints" / "epoch_007.ckpt"
    for p in (moved / "checkpoints").iterdir():
        p.unlink()
    with pytest.raises(ValueError, match="no checkpoint under"):
        read_run(moved)


def test_expected_jobs_follow_the_command_line(tmp_path):
    """A swept key typed on the command line replaces the sweeper's list, as Hydra's sweeper does, so a
    report does not list the trials that were never launched as missing."""
    import yaml

    from pbc.core.runs import expected_jobs

    mr = {"hydra": {"sweeper": {"params": {"robustness.trial": "shape_0.0,shape_0.5,paint_torso", "loss": "l1,l2"}},
                    "overrides": {"task": ["scale=smoke", "robustness.trial=shape_0.0,paint_torso"]}}}
    (tmp_path / "multirun.yaml").write_text(yaml.safe_dump(mr))
    assert expected_jobs(tmp_path) == {"robustness.trial": ["shape_0.0", "paint_torso"], "loss": ["l1", "l2"]}
