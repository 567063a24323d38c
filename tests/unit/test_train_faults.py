"""Faults at the training door: the run-dir lock, a run dir holding another training, the best checkpoint of a
resumed run, and mistyped trainer keys. Synthetic (a scripted two-parameter Lightning module, no data):
`pbc.jobs.train.train` is stopped where it would open the dataset, so these tests prove the doors, not a run."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import pytest
from helpers.train_runs import ReachedTheData, ScriptedModule
from omegaconf import OmegaConf

import pbc.jobs.train as pbc_train
from pbc.core.config import load_config
from pbc.core.io import LockHeld, dir_lock
from pbc.core.validate import check_config, suggest_config_key
from pbc.jobs.train import KeepBestOfResumedRun, RunDirInUse, RunDirTaken, record_failure


def _cfg(out: Path, *extra: str):
    return load_config([f"paths.output_dir={out}", *extra])


# ============================================================================ one run dir, one training
def test_second_training_in_one_run_dir_is_refused_at_once(tmp_path, stop_at_data):
    out = tmp_path / "run"
    with dir_lock(out / pbc_train.RUN_LOCK, "the first job"):  # a first training holds the dir
        with pytest.raises(RunDirInUse, match=rf"run dir {out} is in use by another training \(pid \d+ (.|\n)*"
                                              r"another run dir \(hydra.run.dir=") as err:
            pbc_train.train(_cfg(out))
        assert isinstance(err.value, LockHeld) and isinstance(err.value, ValueError)  # CLI: a user error
        # the refused job records nothing over the running one's files
        assert record_failure(_cfg(out), err.value) is None and not (out / "metrics.json").exists()
    # the first job finished (its lock is gone): the dir is free again
    with pytest.raises(ReachedTheData):
        pbc_train.train(_cfg(out))
    assert not (out / pbc_train.RUN_LOCK).exists()


def test_run_dir_holding_a_finished_training_is_refused_unless_resumed(tmp_path, stop_at_data):
    out = tmp_path / "run"
    (out / "checkpoints").mkdir(parents=True)
    finished = {"status": "ok", "test": {"vertex_error_cm": 2.5}}
    (out / "metrics.json").write_text(json.dumps(finished))
    (out / "checkpoints" / "epoch_003.ckpt").write_bytes(b"x")
    (out / "checkpoints" / "last.ckpt").write_bytes(b"x")
    with pytest.raises(RunDirTaken, match=r"already holds another training's results \(metrics.json of a finished "
                                          r"training; checkpoints epoch_003.ckpt, last.ckpt\)(.|\n)*hydra.run.dir"
                                          r"(.|\n)*ckpt_path=last") as err:
        pbc_train.train(_cfg(out))
    assert record_failure(_cfg(out), err.value) is None
    assert json.loads((out / "metrics.json").read_text()) == finished  # the first run's record kept
    # resuming this dir's own run is what the files are for
    for spec in ("last", str(out), str(out / "checkpoints" / "last.ckpt")):
        with pytest.raises(ReachedTheData):
            pbc_train.train(_cfg(out, f"ckpt_path={spec}"))


def test_run_dir_of_a_killed_run_needs_resume_and_a_failed_door_check_does_not(tmp_path, stop_at_data):
    killed = tmp_path / "killed"
    (killed / "checkpoints").mkdir(parents=True)
    (killed / "checkpoints" / "epoch_001.ckpt").write_bytes(b"x")  # killed before its last.ckpt: no resume
    with pytest.raises(RunDirTaken, match="checkpoints epoch_001.ckpt") as err:
        pbc_train.train(_cfg(killed))
    assert "ckpt_path=last" not in str(err.value)  # nothing to continue from: not offered
    # a run refused at the door (a typo) left only a failed metrics.json: the fixed command runs there
    typo = tmp_path / "typo"
    typo.mkdir()
    (typo / "metrics.json").write_text(json.dumps({"status": "failed", "error": "ValueError: ..."}))
    with pytest.raises(ReachedTheData):
        pbc_train.train(_cfg(typo))


# ============================================================================ resume: the best of both runs
@pytest.fixture(scope="module")
def shipped_callbacks():
    """The default preset's two checkpoint callbacks (best by the monitor, then last.ckpt), unresolved."""
    cfg = load_config([]).callbacks
    return {n: (OmegaConf.to_container(cfg[n], resolve=False), cfg[n].monitor)
            for n in ("model_checkpoint", "last_checkpoint")}


def _fit(nodes, dirpath: Path, epochs: int, ckpt: Path | None, val: list[float]):
    from hydra.utils import instantiate

    callbacks = [instantiate(dict(node, dirpath=str(dirpath), monitor=mon)) for node, mon in nodes.values()]
    if ckpt is not None:
        callbacks.append(KeepBestOfResumedRun(ckpt))  # what pbc.train adds to a resumed run
    t = L.Trainer(max_epochs=epochs, callbacks=callbacks, logger=False, enable_progress_bar=False,
                  enable_model_summary=False, accelerator="cpu", num_sanity_val_steps=0)
    t.fit(ScriptedModule(val), ckpt_path=ckpt)
    return t.checkpoint_callback


def test_resumed_run_tests_the_best_checkpoint_of_both_run_dirs(tmp_path, shipped_callbacks):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    # run a: best at epoch 1 (3.382), killed after epoch 3 (its last.ckpt); resumed in b, whose epochs are worse
    _fit(shipped_callbacks, a, 4, None, [3.5, 3.382, 3.45, 3.46])
    ck = _fit(shipped_callbacks, b, 6, a / "last.ckpt", [0, 0, 0, 0, 3.403, 3.41])
    # Lightning alone made b's epoch 4 (3.403) the best and tested it; a's epoch 1 is the real best
    assert (ck.best_model_path, round(float(ck.best_model_score), 3)) == (str(a / "epoch_001.ckpt"), 3.382)
    assert not list(b.glob("epoch_*.ckpt"))  # no worse epoch saved as "best" in b
    # chained: b's last.ckpt carries a's best on to the next resume, and a better epoch there wins
    ck = _fit(shipped_callbacks, c, 8, b / "last.ckpt", [0] * 6 + [3.39, 3.30])
    assert (ck.best_model_path, round(float(ck.best_model_score), 3)) == (str(c / "epoch_007.ckpt"), 3.3)
    assert (a / "epoch_001.ckpt").is_file()  # another run's folder is never cleaned by this one


def test_a_resumed_training_gets_the_carry_callback(tmp_path):
    from pbc.jobs.train import trainer_callbacks

    cfg = _cfg(tmp_path / "run")
    ck = str(tmp_path / "killed" / "checkpoints" / "last.ckpt")
    assert [c.ckpt_path for c in trainer_callbacks(cfg, ck) if isinstance(c, KeepBestOfResumedRun)] == [ck]
    assert not [c for c in trainer_callbacks(cfg, None) if isinstance(c, KeepBestOfResumedRun)]


# ============================================================================ mistyped trainer keys
def test_unknown_trainer_key_is_refused_naming_the_close_option():
    # `+trainer.max_epoch=3` composes, then used to fail in Lightning with "unexpected keyword argument"
    with pytest.raises(ValueError, match=r"trainer.max_epoch: not an argument of lightning's Trainer; did you mean "
                                         r"trainer.max_epochs\?"):
        check_config(load_config(["+trainer.max_epoch=3"]))
    check_config(load_config(["+trainer.detect_anomaly=true"]))  # a real Trainer argument passes


@pytest.mark.parametrize("preset", ["default", "cpu", "gpu", "ddp", "smoke"])
def test_shipped_trainer_presets_use_only_trainer_arguments(preset):
    check_config(load_config([f"trainer={preset}"]))


def test_hydra_override_error_becomes_the_key_meant():
    cfg = load_config([])

    def hydra_message(override: str) -> str:
        with pytest.raises(Exception) as err:  # hydra's ConfigCompositionException
            load_config([override])
        return "\n".join(str(e) for e in (err.value, err.value.__cause__) if e is not None)

    msg = hydra_message("trainer.max_epoch=3")
    assert "+trainer.max_epoch=3" in msg  # what Hydra itself suggests, and what then fails
    assert suggest_config_key(msg, cfg) == ("unknown key trainer.max_epoch; did you mean trainer.max_epochs? "
                                            "(trainer.max_epochs=3)")
    assert suggest_config_key(hydra_message("modle.lr=0.01"), cfg).startswith("unknown key modle.lr; did you mean "
                                                                             "model.lr?")
    # a real Trainer argument the preset does not set: the + form is right
    assert suggest_config_key(hydra_message("trainer.detect_anomaly=true"), cfg) == (
        "trainer.detect_anomaly is not set by the trainer preset: add it with +trainer.detect_anomaly=true")
    assert suggest_config_key("Error in call to target 'x': boom", cfg) is None
