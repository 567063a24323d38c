"""Sweep configs: every sweep, scale and search config composes (Hydra compose API) for every value it
sweeps over; and a smoke multirun of the `losses` sweep with the joblib launcher makes run dirs and a
report (end to end, when the training pipeline runs here)."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.sweeps_runs import CONF, SCALES, _compose
from hydra import initialize_config_dir
from omegaconf import OmegaConf

import pbc.core.config  # noqa: F401  (registers the pbc.monitor resolver that conf/callbacks reads)
from pbc.core.runs import sweep_values
from pbc.jobs import sweeps

ROOT = Path(__file__).resolve().parents[2]
SEARCH: list[str] = []  # the sweep group is in conf/: no extra search path


@pytest.fixture
def _hydra():
    # One initialisation per compose test (not per config); cleared after, so load_config works elsewhere.
    with initialize_config_dir(str(CONF), version_base="1.3"):
        yield


def test_sweep_names_and_scales():
    assert set(sweeps.TRAIN_SWEEPS) == {"losses", "architectures", "patches", "hierarchy", "robustness"}
    assert set(sweeps.SWEEP_NAMES) == {*sweeps.TRAIN_SWEEPS, "paper"}
    assert SCALES == ["cpu", "cpu_1k", "gpu", "paper", "smoke"]
    assert sweep_values("experiment", "glob(patch_*)") == [f"patch_{i:02d}" for i in range(28)]
    assert len(sweep_values("experiment", "glob([whole,patch_*])")) == 29


@pytest.mark.usefixtures("_hydra")
@pytest.mark.parametrize("scale", SCALES)
def test_scales_compose_in_sweeps_and_single_runs(scale):
    cfg = _compose([*SEARCH, "+sweep=losses", f"scale={scale}"])
    single = _compose(["+experiment=whole", f"+scale={scale}"])
    for c in (cfg, single):
        assert c.hydra.runtime.choices["scale"] == scale
        assert c.data.num_samples > 0 and c.trainer.max_epochs > 0 and c.datamodule.batch_size > 0
    assert cfg.data.name == {"smoke": "tshirt_tiny", "cpu": "tshirt_small", "paper": "tshirt_paper",
                             "gpu": "tshirt_gpu", "cpu_1k": "tshirt_1k"}[scale]


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


def test_robustness_is_a_sweep_of_the_runner(tmp_path):
    """The wrong-body study: data, then the bodies (a library step), then the plain multirun over
    robustness.trial; a data.dir override names the base data (data step) and never reaches training,
    where each trial's data.dir is its body's."""
    ovr = ["scale=smoke", "data.dir=/base", "robustness.trial=shape_0.0,shape_2.0", "trainer.max_epochs=1"]
    steps = sweeps.sweep_commands("robustness", ovr, tmp_path, python="py")
    assert [s for s, _ in steps] == ["data", "bodies", "train"]
    cmds = dict(steps)
    assert cmds["bodies"] is None and "bodies" in sweeps.IN_PROCESS_STEPS
    assert "data.dir=/base" in cmds["data"] and "robustness.trial=shape_0.0,shape_2.0" not in cmds["data"]
    train = cmds["train"]
    assert train[:5] == ["py", "-m", "pbc.train", "-m", "+sweep=robustness"]
    assert not any(a.startswith("data.dir=") for a in train)
    assert "robustness.trial=shape_0.0,shape_2.0" in train and "trainer.max_epochs=1" in train
    assert sweeps.data_overrides(ovr) == ["data.dir=/base"]


@pytest.mark.usefixtures("_hydra")
def test_robustness_trial_runs_on_its_body():
    from hydra.core.hydra_config import HydraConfig

    from pbc.jobs.robustness import load_settings, selected_trials, trial_names

    cfg = _compose(["+sweep=robustness", "scale=smoke", "robustness.trial=paint_torso",
                    "hydra.sweep.dir=/sweep"])
    HydraConfig.instance().set_config(cfg)  # what a launched job has: ${hydra:sweep.dir} resolves
    try:
        assert cfg.data.dir == "/sweep/bodies/paint_torso"
        assert cfg.hydra.sweep.subdir == "paint_torso"  # the run dir beside its body: <sweep>/<trial>/
    finally:
        HydraConfig.instance().cfg = None
    rob = load_settings()
    swept = sweep_values("robustness.trial", str(cfg.hydra.sweeper.params["robustness.trial"]))
    assert swept == trial_names(rob) == selected_trials(rob)  # the sweep runs every trial the settings name
    assert selected_trials(rob, ["robustness.trial=shape_0.0,paint_torso"]) == ["shape_0.0", "paint_torso"]


@pytest.fixture(scope="module")
def tiny_data(tiny_dataset: Path) -> Path:
    """The data root holding the session's real tiny dataset."""
    return tiny_dataset.parent




@pytest.mark.usefixtures("_hydra")
def test_cpu_1k_scale_is_the_converged_schedule_on_over_1000_rows():
    """`pbc sweeps paper`'s default scale: the shirt's 1,200 poses with mirror images, batch 32, a cosine decay
    over 41 epochs and early stopping (docs/results/converged_gpu's schedule)."""
    cfg = _compose([*SEARCH, "+sweep=losses", "scale=cpu_1k"])
    assert cfg.data.num_samples == 1200 and cfg.data.mirror is True and cfg.data.name == "tshirt_1k"
    assert cfg.trainer.accelerator == "cpu" and cfg.trainer.max_epochs == 41 and cfg.datamodule.batch_size == 32
    assert cfg.model.scheduler.T_max == 41 and "early_stopping" in cfg.callbacks
    assert sweeps.scale_data("cpu_1k") == "tshirt_1k"


def test_paper_comparison_settings_and_tables():
    comp = sweeps.comparison_settings([])
    assert comp["tables"] == ["losses", "architectures", "hierarchy"] and comp["seeds"] == [0, 1]
    assert comp["scale"] == "cpu_1k"
    comp = sweeps.comparison_settings(["comparison.tables=losses", "comparison.seeds=0,1,2"])
    assert comp["tables"] == ["losses"] and comp["seeds"] == [0, 1, 2]
    for bad, match in (("comparison.tables=lossses", "each must be one of"), ("comparison.seeds=1,1", "distinct"),
                       ("comparison.seed=1", "unknown")):
        with pytest.raises(ValueError, match=match):
            sweeps.comparison_settings([bad])
    assert sweeps.table_grid("losses", []) == ("loss", ["l1", "l2", "l2_normal", "l1_normal"])
    assert sweeps.table_grid("losses", ["loss=l1,l2"]) == ("loss", ["l1", "l2"])
    key, values = sweeps.table_grid("architectures", [])
    assert key == "experiment" and values[0] == "whole" and len(values) == 7
    key, values = sweeps.table_grid("hierarchy", [])
    assert key == "experiment" and len(values) == 29


def test_paper_train_command_gives_each_table_its_own_settings(tmp_path):
    """A narrowing of one table's key stays out of the tables that vary another; the training seed never
    reaches the data step (it is not data.seed)."""
    ovr = ["comparison.seeds=0,1", "loss=l1,l2", "hydra.launcher.n_jobs=2", "seed=5", "scale=smoke"]
    argv = sweeps.paper_train_command("architectures", 1, "experiment", ["fc_pca_local"], "smoke", ovr,
                                      {"loss", "experiment"}, tmp_path / "a", python="py")
    assert argv[:5] == ["py", "-m", "pbc.train", "-m", "+sweep=architectures"]
    assert "seed=1" in argv and "seed=5" not in argv and "experiment=fc_pca_local" in argv
    assert not any(a.startswith(("loss=", "comparison.")) for a in argv) and "hydra.launcher.n_jobs=2" in argv
    data = dict(sweeps.sweep_commands("losses", ["seed=0,1", "data.seed=3", "scale=smoke"], tmp_path, "py"))["data"]
    assert "data.seed=3" in data and not any(a.startswith("seed=") for a in data)


def test_table_estimate_is_runs_times_epochs_times_steps():
    est = sweeps.estimate_table({"whole": 2.0, "fc": 0.1}, {"whole": 30.0, "fc": 10.0}, {"whole": 4, "fc": 2},
                                {"whole": 41, "fc": 41}, {"whole": 47, "fc": 47})
    assert est == pytest.approx(4 * (30 + 41 * 47 * 2.0) + 2 * (10 + 41 * 47 * 0.1))


def test_paper_trains_each_job_once():
    """Table 2's CNN and the hierarchy's whole model are Table 1's L1 runs: trained there only; without
    Table 1 (or with it narrowed away from L1) the later tables keep their own."""
    grids = sweeps.paper_grids(["losses", "architectures", "hierarchy"], [])
    assert grids["losses"][1] == ["l1", "l2", "l2_normal", "l1_normal"]
    assert "whole" not in grids["architectures"][1] and len(grids["architectures"][1]) == 6
    assert "whole" not in grids["hierarchy"][1] and len(grids["hierarchy"][1]) == 28
    assert "whole" in sweeps.paper_grids(["architectures", "hierarchy"], [])["architectures"][1]
    assert "whole" in sweeps.paper_grids(["losses", "hierarchy"], ["loss=l2"])["hierarchy"][1]
