"""The entry layer: every `pbc COMMAND` and every [project.scripts] script names a callable main."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
import tomllib

from pbc import cli

ROOT = Path(__file__).resolve().parents[2]


def test_every_script_and_command_resolves():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert {"pbc", "pbc-train", "pbc-generate", "pbc-evaluate", "pbc-sweeps"} <= set(scripts)
    for name, target in scripts.items():
        module, func = target.split(":")
        assert callable(getattr(importlib.import_module(module), func)), name
    for command, module in cli.COMMANDS.items():
        assert callable(importlib.import_module(module).main), command
        assert scripts.get(f"pbc-{command}") == f"{module}:main", command


def test_dispatcher_lists_commands_and_refuses_unknown_ones(capsys):
    cli.main([])
    assert "train" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="unknown command 'nope'"):
        cli.main(["nope"])


def test_dispatcher_passes_arguments_and_exit_status(tmp_path):
    # `pbc report MISSING_DIR`: argparse command, its own error and non-zero status come back
    with pytest.raises(SystemExit) as e:
        cli.main(["report", str(tmp_path / "missing")])
    assert e.value.code not in (0, None)
