"""Hydra's own flags (`-m`, `--cfg job`, `-c job`, `--info [WHAT]`, `--help`, `--hydra-help`) work before, between
or after the overrides in every Hydra entry (pbc-X, `pbc X`, `python -m pbc.X`), pbc's own overrides still
reach Hydra, and a flag or a value Hydra does not know is one line naming it and the fix."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from helpers.cli import exit_code
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode

import pbc.cli.generate
import pbc.cli.train
from pbc import cli
from pbc.cli.errors import EXIT_USER_ERROR, hydra_argv


def script(name: str):
    """`pbc-NAME argv`."""
    return cli.command_main(name)


def dispatcher(name: str):
    """`pbc NAME argv` (and `python -m pbc NAME argv`)."""
    return lambda argv: cli.main([name, *argv])


def module(name: str):
    """`python -m pbc.NAME argv`: the alias reads sys.argv."""

    def main(argv):
        saved = sys.argv
        sys.argv = [f"pbc/{name}.py", *argv]
        try:
            cli.run_as_module(name)
        finally:
            sys.argv = saved

    return main


# entry -> (a group override and a value override, the line the group's choice puts in the job config)
OVERRIDES = {
    "train": (["+experiment=whole", "seed=7"], "- whole"),
    "generate": (["data=tshirt_tiny", "seed=7"], "  name: tshirt_tiny"),
    "evaluate": (["stitch=average", "seed=7"], "  method: average"),
}
BEFORE, BETWEEN, AFTER = range(3)


def placed(flag: list[str], overrides: list[str], where: int) -> list[str]:
    """`flag` before, between or after the two overrides."""
    argv = list(overrides)
    argv[where:where] = flag
    return argv


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # printing a config, help or info writes nothing: checked below
    monkeypatch.delenv("PBC_ROOT", raising=False)
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    return tmp_path


# (entry, route, the flag's spelling, two places): every route and spelling, each case one place that Hydra's
# own parser refuses when pbc appends an override or the flag stands between two
SHOW_CONFIG = [
    ("train", module, ["--cfg", "job"], (AFTER, BEFORE)),
    ("train", dispatcher, ["-c", "job"], (AFTER, BETWEEN)),
    ("train", script, ["--cfg=job"], (BETWEEN, AFTER)),
    ("generate", script, ["-c", "job"], (BETWEEN, BEFORE)),
    ("generate", dispatcher, ["--cfg", "job"], (BETWEEN, AFTER)),
    ("evaluate", script, ["--cfg", "job"], (BETWEEN, AFTER)),
]


@pytest.mark.parametrize(("name", "route", "flag", "places"), SHOW_CONFIG,
                         ids=[f"{n}-{r.__name__}-{f[0]}" for n, r, f, _ in SHOW_CONFIG])
def test_show_config_flag_anywhere(name, route, flag, places, in_tmp, capsys):
    overrides, line = OVERRIDES[name]
    for where in places:
        argv = placed(flag, overrides, where)
        assert exit_code(route(name), argv) == 0, argv
        lines = capsys.readouterr().out.splitlines()
        assert "seed: 7" in lines and line in lines and "hydra:" not in lines, argv  # the job's config alone
    assert not any(in_tmp.iterdir())


def test_info_with_or_without_its_value_anywhere(in_tmp, capsys):
    overrides, _ = OVERRIDES["train"]
    # without a value (all of it) before the overrides: an override is not taken for its value
    assert exit_code(module("train"), placed(["--info"], overrides, BEFORE)) == 0
    out = capsys.readouterr().out
    assert "experiment/whole" in out and "Config search path" in out
    assert exit_code(script("train"), placed(["-i", "defaults"], overrides, AFTER)) == 0
    out = capsys.readouterr().out
    assert "experiment/whole" in out and "Config search path" not in out
    overrides, _ = OVERRIDES["generate"]
    for argv in (placed(["--info", "defaults"], overrides, BETWEEN), placed(["--info=defaults"], overrides, AFTER)):
        assert exit_code(dispatcher("generate"), argv) == 0, argv
        assert "data/tshirt_tiny" in capsys.readouterr().out, argv
    assert not any(in_tmp.iterdir())


@pytest.mark.parametrize(("name", "flag", "where"), [("train", "--help", AFTER), ("generate", "-h", BETWEEN)])
def test_help_anywhere(name, flag, where, in_tmp, capsys):
    assert exit_code(script(name), placed([flag], OVERRIDES[name][0], where)) == 0
    out = capsys.readouterr().out
    assert "== Configuration groups ==" in out and "seed: 7" in out.splitlines()
    assert not any(in_tmp.iterdir())


def test_hydra_help_anywhere(in_tmp, capsys):
    # Hydra's own help: the command's overrides are left out of it (it composes no config of the command's)
    assert exit_code(module("train"), placed(["--hydra-help"], OVERRIDES["train"][0], AFTER)) == 0
    assert "== Flags ==" in capsys.readouterr().out
    assert not any(in_tmp.iterdir())


def recording_train(seen: list[dict]):
    """A stand-in for pbc.jobs.train.train: what Hydra handed the job, no training."""

    def train(cfg, past_the_door):
        hydra_cfg = HydraConfig.get()
        seen.append({"mode": hydra_cfg.mode, "output_subdir": hydra_cfg.output_subdir, "seed": cfg.seed,
                     "patch_id": cfg.model.get("patch_id"), "out": Path(hydra_cfg.runtime.output_dir)})
        return {"val_best": {"loss": 0.5}, "optimized_metric": "val/loss"}

    return train


def test_python_m_pbc_train_runs_as_before_and_multiruns_with_m_last(in_tmp, monkeypatch):
    seen: list[dict] = []
    monkeypatch.setattr(pbc.cli.train, "train", recording_train(seen))
    # the users' own command: one run, pbc's override applied (Hydra writes no .hydra/ of its own)
    assert exit_code(module("train"), ["+experiment=patch_07", f"hydra.run.dir={in_tmp / 'run'}"]) == 0
    # the same with -m after the overrides: a multirun of one job, pbc's override applied there too
    argv = ["+experiment=patch_07", "seed=3", f"hydra.sweep.dir={in_tmp / 'sweep'}", "-m"]
    assert exit_code(module("train"), argv) == 0
    assert [(s["mode"], s["output_subdir"], s["patch_id"], s["seed"]) for s in seen] == [
        (RunMode.RUN, None, 7, 0), (RunMode.MULTIRUN, None, 7, 3)]
    assert seen[0]["out"] == in_tmp / "run" and seen[1]["out"].parent == in_tmp / "sweep"
    assert not list(in_tmp.rglob(".hydra"))


def test_multirun_flag_between_the_overrides(in_tmp, monkeypatch):
    seen: list[dict] = []
    monkeypatch.setattr(pbc.cli.train, "train", recording_train(seen))
    argv = ["+experiment=whole", "--multirun", "seed=3", f"hydra.sweep.dir={in_tmp / 'sweep'}"]
    assert exit_code(dispatcher("train"), argv) == 0
    assert [(s["mode"], s["output_subdir"], s["seed"]) for s in seen] == [(RunMode.MULTIRUN, None, 3)]
    seeds: list[int] = []
    monkeypatch.setattr(pbc.cli.generate, "generate", lambda cfg: seeds.append(cfg.seed) or in_tmp)
    argv = ["data=tshirt_tiny", "-m", "seed=4", f"hydra.sweep.dir={in_tmp / 'data_sweep'}"]
    assert exit_code(script("generate"), argv) == 0
    assert seeds == [4]


@pytest.mark.parametrize("name", ["train", "generate", "evaluate"])
@pytest.mark.parametrize(("flag", "said"), [
    (["--cfg", "jobs"], "--cfg takes one of job, hydra, all, not 'jobs': e.g. --cfg job"),
    (["-c", "config"], "-c takes one of job, hydra, all, not 'config': e.g. -c job"),
    (["--cfg"], ": e.g. --cfg job"),  # last: "--cfg needs one of ...", first: "... not '+experiment=whole'"
    (["--info=everything"], "--info takes one of all, config, defaults, defaults-tree, plugins, searchpath, not "
                            "'everything'"),
    (["--multi-run"], "unknown flag '--multi-run': did you mean --multirun?"),
    (["-m=1"], "-m takes no value, not '1': give -m alone"),
    (["--nope"], "unknown flag '--nope': Hydra's flags are --help/-h, "),
])
def test_an_unknown_flag_or_value_is_one_line_naming_it(name, flag, said, in_tmp, capsys):
    overrides, _ = OVERRIDES[name]
    for argv in (placed(flag, overrides, AFTER), placed(flag, overrides, BEFORE)):
        assert exit_code(script(name), argv) == EXIT_USER_ERROR, argv
        err = capsys.readouterr().err
        assert err.startswith(f"pbc {name}: error: ") and said in err, argv
        assert len(err.strip().splitlines()) == 1 and "usage:" not in err and "Traceback" not in err, argv
    assert not any(in_tmp.iterdir())


def test_hydra_argv_puts_the_overrides_then_pbcs_then_each_flag_as_one_token():
    own = ["hydra.output_subdir=null"]
    assert hydra_argv("pbc-train", ["-c", "job", "a=1", "-m", "b=2"], own) == [
        "pbc-train", "a=1", "b=2", "hydra.output_subdir=null", "--cfg=job", "--multirun"]
    assert hydra_argv("p", ["--info", "a=1", "--multi", "--", "b=2"]) == ["p", "a=1", "b=2", "--info", "--multirun"]
    assert hydra_argv("p", ["--info", "plugins", "a=1"]) == ["p", "a=1", "--info=plugins"]
    # Hydra's own help composes no config of the command's: only the hydra.* overrides go with it
    assert hydra_argv("p", ["a=1", "--hydra-help", "hydra.job.name=x"], own) == [
        "p", "hydra.job.name=x", *own, "--hydra-help"]
