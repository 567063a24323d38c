"""Sweep configs: every sweep, scale and search config composes (Hydra compose API) for every value it
sweeps over; and a smoke multirun of the `losses` sweep with the joblib launcher makes run dirs and a
report (end to end, when the training pipeline runs here)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import TINY_SAMPLES
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from pbc import sweeps

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
SCALES = sorted(p.stem for p in (CONF / "scale").glob("*.yaml"))
SEARCH: list[str] = []  # the sweep group is in conf/: no extra search path


@pytest.fixture
def _hydra():
    # One initialisation per compose test (not per config); cleared after, so load_config works elsewhere.
    with initialize_config_dir(str(CONF), version_base="1.3"):
        yield


def _compose(overrides):
    return compose("config", overrides=overrides, return_hydra_config=True)


def test_sweep_names_and_scales():
    assert set(sweeps.SWEEP_NAMES) == {"losses", "architectures", "patches", "hierarchy", "robustness"}
    assert SCALES == ["cpu", "gpu", "paper", "smoke"]
    assert sweeps.sweep_values("experiment", "glob(patch_*)") == [f"patch_{i:02d}" for i in range(28)]
    assert len(sweeps.sweep_values("experiment", "glob([whole,patch_*])")) == 29


@pytest.mark.usefixtures("_hydra")
@pytest.mark.parametrize("name", ["losses", "architectures", "patches", "hierarchy", "robustness"])
def test_every_sweep_composes_for_every_value(name):
    base = _compose([*SEARCH, f"+sweep={name}", "scale=smoke"])
    params = OmegaConf.to_container(base.hydra.sweeper.params)
    assert params and base.hydra.launcher._target_.endswith("JoblibLauncher")
    jobs = [{}]
    for key, value in params.items():
        values = sweeps.sweep_values(key, str(value), CONF)
        assert values, f"{name}: {key}={value} selects nothing"
        jobs = [{**j, key: v} for j in jobs for v in values]
    # A glob sweep's options all come from the same files: compose its ends and a middle one.
    for job in jobs if len(jobs) <= 8 else [jobs[0], jobs[len(jobs) // 2], jobs[-1]]:
        cfg = _compose([*SEARCH, f"+sweep={name}", "scale=smoke", *[f"{k}={v}" for k, v in job.items()]])
        choices = cfg.hydra.runtime.choices
        for k, v in job.items():
            assert choices.get(k) == v or OmegaConf.select(cfg, k) == v, (name, job)
        assert cfg.data.name == "tshirt_tiny" and choices["trainer"] == "smoke"
        if choices["experiment"].startswith("patch_"):
            assert cfg.model.kind == "patch" and cfg.model.patch_id == int(choices["experiment"][6:])
    # The sweep dir names the sweep and the scale (resolved as Hydra does in the launching process).
    sweep_dir = OmegaConf.select(base, "hydra.sweep.dir")
    assert f"sweeps/{name}/smoke_" in sweep_dir


@pytest.mark.usefixtures("_hydra")
@pytest.mark.parametrize("scale", SCALES)
def test_scales_compose_in_sweeps_and_single_runs(scale):
    cfg = _compose([*SEARCH, "+sweep=losses", f"scale={scale}"])
    single = _compose(["+experiment=whole", f"+scale={scale}"])
    for c in (cfg, single):
        assert c.hydra.runtime.choices["scale"] == scale
        assert c.data.num_samples > 0 and c.trainer.max_epochs > 0 and c.datamodule.batch_size > 0
    assert cfg.data.name == {"smoke": "tshirt_tiny", "cpu": "tshirt_small", "paper": "tshirt_paper",
                             "gpu": "tshirt_gpu"}[scale]


@pytest.mark.usefixtures("_hydra")
@pytest.mark.parametrize("name", ["hierarchy", "losses"])
def test_gpu_scale_schedule_composes_and_paper_stays_plain_adam(name):
    """`python -m pbc.sweeps hierarchy|losses scale=gpu`: the GPU data set and trainer, a cosine LR decay
    over the run's epochs and early stopping on the checkpoint's metric; scale=paper keeps plain Adam."""
    import torch
    from hydra.utils import instantiate

    cfg = _compose([*SEARCH, f"+sweep={name}", "scale=gpu"])
    assert cfg.data.name == "tshirt_gpu" and cfg.trainer.accelerator == "gpu"
    assert cfg.image.whole_resolution == 256 and cfg.datamodule.batch_size == 32  # the paper's sizes
    assert cfg.callbacks.early_stopping.monitor == cfg.callbacks.model_checkpoint.monitor == "val/vertex_error_cm"
    job = _compose([*SEARCH, f"+sweep={name}", "scale=gpu", "experiment=patch_07"]) if name == "hierarchy" else cfg
    model = instantiate(job.model, identity={}, summary={})
    sched = model.configure_optimizers()["lr_scheduler"]["scheduler"]
    assert isinstance(sched, torch.optim.lr_scheduler.CosineAnnealingLR) and sched.T_max == cfg.trainer.max_epochs
    cmds = dict(sweeps.sweep_commands(name, ["scale=gpu"], Path("/tmp/sweep"), python="py"))
    assert "data=tshirt_gpu" in cmds["data"] and "scale=gpu" in cmds["train"]
    paper = _compose([*SEARCH, f"+sweep={name}", "scale=paper"])
    assert paper.model.scheduler is None and "early_stopping" not in paper.callbacks


@pytest.mark.usefixtures("_hydra")
def test_slurm_launcher_replaces_joblib():
    cfg = _compose([*SEARCH, "+sweep=patches", "scale=paper", "hydra/launcher=submitit_slurm"])
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")


@pytest.mark.usefixtures("_hydra")
def test_optuna_search_composes():
    cfg = _compose(["+experiment=whole", "+scale=smoke", "+hparams_search=optuna"])
    sw = cfg.hydra.sweeper
    assert sw._target_.endswith("OptunaSweeper") and sw.direction == "minimize"
    # the searched keys exist in the composed config
    for key in sw.params:
        assert OmegaConf.select(cfg, key) is not None, key


def test_runner_commands(tmp_path):
    cmds = dict(
        sweeps.sweep_commands(
            "hierarchy", ["scale=smoke", "hydra.launcher.n_jobs=2", "data.seed=3"], tmp_path, python="py"
        )
    )
    assert cmds["data"] == [
        "py",
        "-m",
        "pbc.generate",
        "data=tshirt_tiny",
        "data.seed=3",
        f"hydra.run.dir={tmp_path}/.generate",
    ]
    train = cmds["train"]
    assert train[:5] == ["py", "-m", "pbc.train", "-m", "+sweep=hierarchy"] and "-cd" not in train
    assert "scale=smoke" in train and "hydra.launcher.n_jobs=2" in train and f"hydra.sweep.dir={tmp_path}" in train
    assert cmds["evaluate"] is None  # built after training, from the runs it made
    with pytest.raises(ValueError, match="choose one of"):
        sweeps.sweep_commands("nope", [], tmp_path)


@pytest.fixture(scope="module")
def tiny_data(tiny_dataset: Path) -> Path:
    """The data root holding the session's real tiny dataset."""
    return tiny_dataset.parent


def test_smoke_losses_multirun_with_joblib(tmp_path, tiny_data):
    """`python -m pbc.sweeps losses scale=smoke hydra.launcher.n_jobs=2`: four run dirs and a report."""
    t0 = time.time()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pbc.sweeps",
            "losses",
            "scale=smoke",
            "hydra.launcher.n_jobs=2",
            f"paths.data_dir={tiny_data}",
            f"data.num_samples={TINY_SAMPLES}",
            "--dir",
            str(tmp_path / "sweep"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-4000:]
    runs = sweeps.load_runs(tmp_path / "sweep")
    assert sorted(x.get("loss") for x in runs) == ["l1", "l1_normal", "l2", "l2_normal"], out[-2000:]
    assert all(x.status == sweeps.OK for x in runs), [(x.name, x.error) for x in runs]
    assert all(x.get("experiment") == "whole" and x.cfg("data.name") == "tshirt_tiny" for x in runs)
    assert all(x.curves for x in runs)  # TensorBoard events were read back
    data = json.loads((tmp_path / "sweep" / "report.json").read_text())
    for row in data["table1"]:
        run = next(x for x in runs if x.get("loss") == row["select"]["loss"])
        m = json.loads((run.path / "metrics.json").read_text())
        assert row["values"]["test/vertex_error_cm"] == m["test"]["vertex_error_cm"]
    assert (tmp_path / "sweep" / "learning_curves.png").is_file()
    rec = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    print(f"smoke losses sweep: {time.time() - t0:.1f} s; steps {[(s['step'], s['seconds']) for s in rec['steps']]}")
