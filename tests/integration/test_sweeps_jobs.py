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
from helpers.sweeps_runs import CONF, _compose
from hydra import initialize_config_dir
from omegaconf import OmegaConf

from pbc.core.runs import OK, load_runs, sweep_values

ROOT = Path(__file__).resolve().parents[2]
SEARCH: list[str] = []  # the sweep group is in conf/: no extra search path


@pytest.fixture
def _hydra():
    # One initialisation per compose test (not per config); cleared after, so load_config works elsewhere.
    with initialize_config_dir(str(CONF), version_base="1.3"):
        yield


@pytest.mark.usefixtures("_hydra")
@pytest.mark.parametrize("name", ["losses", "architectures", "patches", "hierarchy", "robustness"])
def test_every_sweep_composes_for_every_value(name):
    base = _compose([*SEARCH, f"+sweep={name}", "scale=smoke"])
    params = OmegaConf.to_container(base.hydra.sweeper.params)
    assert params and base.hydra.launcher._target_.endswith("JoblibLauncher")
    jobs = [{}]
    for key, value in params.items():
        values = sweep_values(key, str(value), CONF)
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
    runs = load_runs(tmp_path / "sweep")
    assert sorted(x.get("loss") for x in runs) == ["l1", "l1_normal", "l2", "l2_normal"], out[-2000:]
    assert all(x.status == OK for x in runs), [(x.name, x.error) for x in runs]
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


def _paper(tmp_path: Path, tiny_data: Path) -> tuple[subprocess.CompletedProcess, dict]:
    r = subprocess.run(
        [sys.executable, "-m", "pbc.sweeps", "paper", "scale=smoke", "comparison.tables=losses",
         "comparison.seeds=0,1", "loss=l1", "hydra.launcher.n_jobs=2", f"paths.data_dir={tiny_data}",
         f"data.num_samples={TINY_SAMPLES}", "--dir", str(tmp_path / "paper")],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    return r, json.loads((tmp_path / "paper" / "sweep.json").read_text())


def test_paper_comparison_runs_every_seed_states_its_time_and_resumes(tmp_path, tiny_data):
    """`pbc sweeps paper` narrowed to Table 1's L1 under two seeds (`test_smoke_losses_multirun_with_joblib`
    compares the four losses): the table's wall time is stated (from a measured step) before it
    trains, the setting runs under each seed, the report shows the seeds' mean and range; run again after one run
    was lost, it trains that one alone."""
    r, rec = _paper(tmp_path, tiny_data)
    timing = next(s for s in rec["steps"] if s["step"] == "losses: timing")
    assert timing["estimate_s"] > 0 and timing["timing"]["whole"]["step_s"] > 0
    assert "at most" in r.stdout and r.stdout.index("at most") < r.stdout.index("losses, seed 0")
    runs = [x for x in load_runs(tmp_path / "paper") if x.job == "train"]
    assert sorted((x.get("loss"), int(x.cfg("seed"))) for x in runs) == [("l1", 0), ("l1", 1)]
    assert all(x.status == OK for x in runs), [(x.name, x.error) for x in runs]
    data = json.loads((tmp_path / "paper" / "report.json").read_text())
    l1 = next(row for row in data["table1"] if row["select"]["loss"] == "l1")
    tests = [json.loads((x.path / "metrics.json").read_text())["test"]["vertex_error_cm"] for x in runs
             if x.get("loss") == "l1"]
    assert len(l1["runs"]) == 2 and l1["values"]["test/vertex_error_cm"] == pytest.approx(sum(tests) / 2)
    assert l1["spread"]["test/vertex_error_cm"] == pytest.approx(max(tests) - min(tests))

    lost = next(x for x in runs if int(x.cfg("seed")) == 1)
    (lost.path / "metrics.json").unlink()  # killed before it finished
    r, rec = _paper(tmp_path, tiny_data)
    trained = [s for s in rec["steps"] if ": train seed" in s["step"]]
    assert len(trained) == 1 and "seed=1" in trained[0]["argv"] and "loss=l1" in trained[0]["argv"], trained
    done = [x for x in load_runs(tmp_path / "paper") if x.job == "train" and x.status == OK]
    assert len(done) == 2
