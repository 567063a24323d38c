"""The entry floor: every command is reachable the same three ways, and a user error is one line with
exit status 2 in every command (the traceback behind --debug)."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
import tomllib
from helpers.cli import exit_code

from pbc import cli
from pbc.cli.errors import EXIT_USER_ERROR, entry_point, is_user_error, one_line

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def test_every_command_has_a_script_and_the_scripts_are_the_commands():
    assert SCRIPTS.pop("pbc") == "pbc.cli:main"
    assert {name.removeprefix("pbc-") for name in SCRIPTS} == set(cli.COMMANDS)
    for command, (module, _) in cli.COMMANDS.items():
        assert SCRIPTS[f"pbc-{command}"] == f"pbc.cli.{module}:main", command
        assert cli.command_main(command) is importlib.import_module(f"pbc.cli.{module}").main


def test_python_m_aliases_hand_over_to_the_same_command():
    # `python -m pbc.train` is the users' own command: its module's main guard runs pbc.cli's train
    for name in ("train", "generate", "evaluate", "predict", "edit", "sweeps", "report", "main"):
        text = (ROOT / "pbc" / f"{name}.py").read_text()
        assert f'run_as_module("{name}")' in text, name


def test_dispatcher_lists_commands_and_refuses_an_unknown_one(capsys):
    cli.main([])
    out = capsys.readouterr().out
    assert all(c in out for c in cli.COMMANDS)
    assert exit_code(cli.main, ["nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'nope'" in err and "train" in err


def test_dispatcher_passes_arguments_and_exit_status(tmp_path, capsys):
    assert exit_code(cli.main, ["report", str(tmp_path / "missing")]) == EXIT_USER_ERROR
    err = capsys.readouterr().err.strip()
    assert err.startswith("pbc report: error:") and str(tmp_path / "missing") in err
    assert "Traceback" not in err and len(err.splitlines()) == 1


def _failing(exc):
    def run(args):
        raise exc

    return run


def test_a_user_error_is_one_line_and_exit_2_a_bug_keeps_its_traceback(capsys, monkeypatch):
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    main = entry_point("demo", _failing(ValueError("pose file x.npy is empty: write poses with np.save")))
    assert exit_code(main, []) == 2
    assert capsys.readouterr().err == "pbc demo: error: pose file x.npy is empty: write poses with np.save\n"
    with pytest.raises(ValueError, match="is empty"):  # --debug: the traceback, not the line
        main(["--debug"])
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(ValueError):
        main([])
    monkeypatch.delenv("HYDRA_FULL_ERROR")
    with pytest.raises(ZeroDivisionError):  # a bug is not a user error
        entry_point("demo", _failing(ZeroDivisionError("oops")))([])


def test_which_errors_are_the_users():
    full = OSError(28, "No space left on device", "/data/x.npy")
    assert is_user_error(full) and "/data/x.npy" in one_line(full)
    assert is_user_error(FileNotFoundError("no dataset at data/x: make it with `pbc generate`"))
    assert not is_user_error(RuntimeError("CUDA error")) and not is_user_error(KeyError("k"))


def test_hydra_errors_become_one_line_with_the_options(capsys, tmp_path, monkeypatch):
    from pbc.cli.train import main

    monkeypatch.chdir(tmp_path)  # nothing may be written anywhere for a config error
    assert exit_code(main, ["+experiment=nope"]) == 2
    err = capsys.readouterr().err
    assert "Could not find 'experiment/nope'" in err and "patch_07" in err and "search path" not in err
    assert len(err.strip().splitlines()) == 1
    # a mistyped key names the real one, not Hydra's "+trainer.max_epoch" advice that then fails
    assert exit_code(main, ["trainer.max_epoch=3"]) == 2
    err = capsys.readouterr().err
    assert "did you mean trainer.max_epochs" in err and "+trainer.max_epoch" not in err
    assert not any(tmp_path.iterdir())


def test_a_run_dir_that_cannot_be_made_is_named_with_the_fix(capsys, tmp_path, monkeypatch):
    from pbc.cli.train import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").write_text("a file where the runs folder should be")  # read-only as root cannot be
    assert exit_code(main, ["data=tshirt_tiny"]) == 2
    err = capsys.readouterr().err
    assert "cannot create the run dir runs/train/" in err and "hydra.run.dir" in err and "Errno" not in err
