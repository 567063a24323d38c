"""The entry floor: every pbc command, in one place and one style.

Each command is a module here with a `run(args) -> int | None` that parses its own arguments (Hydra
overrides for the config-driven jobs, argparse for the others) and calls the library; `main` wraps it in
the one error handler (`pbc.cli.errors`). Every command is reached three ways, all the same code:

    pbc COMMAND [args]            the dispatcher below ([project.scripts] `pbc`)
    pbc-COMMAND [args]            one script per command
    python -m pbc COMMAND [args]  (and `python -m pbc.train`, `pbc.generate`, ... for the jobs users know)

A user error (bad input, a config typo, a missing dataset, ...) prints one line and exits with status 2;
`--debug` or HYDRA_FULL_ERROR=1 shows the traceback. A bug still prints its traceback.
"""

from __future__ import annotations

import importlib
import sys

# command -> (module under pbc.cli, what it does); the order is the help's
COMMANDS: dict[str, tuple[str, str]] = {
    "main": ("main_job", "the README's main job: data, the whole-shirt model, patch model 7, their scores"),
    "generate": ("generate", "make (or resume, or merge) a dataset                      (Hydra)"),
    "train": ("train", "train one model, test it, write metrics.json                (Hydra)"),
    "evaluate": ("evaluate", "whole vs stitched patch models on a dataset split          (Hydra)"),
    "predict": ("predict", "body poses -> garment meshes from trained runs"),
    "edit": ("edit", "edit a cloth image -> a new 3D garment (appendix B)"),
    "sweeps": ("sweeps", "a named sweep end to end: data, multirun, evaluation, report"),
    "report": ("report", "the report (tables, figures) of a sweep dir"),
    "preview": ("preview", "cloth-image figures of a dataset"),
    "body": ("body", "the body a config builds: show (joints, limits, girths) or export (rest OBJ)"),
    "cage": ("cage", "a garment's automatic cage as an editable JSON; regenerate committed cages"),
    "cage-study": ("cage_study", "how much of each patch its cage explains (Fig. 4)"),
    "garment": ("garment", "a garment file: inspect (charts, fit, settings), split (an outfit), fit (file -> model)"),
    "outfit": ("outfit", "several garments on one body: predict (each piece's model, composed as layers)"),
    "view": ("view", "a local web viewer: body + predicted garment under joint sliders, in the browser"),
    "pretrained": ("pretrained", "the models shipped with pbc (--pretrained NAME): list them, pack a run as one"),
    "motion": ("motion", "motion clips: inspect (dialect, units, rest, joint match, a figure), limits (joint limits)"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"  {name:<{width}}  {text}" for name, (_, text) in COMMANDS.items()]
    return ("usage: pbc COMMAND [args]   (also pbc-COMMAND, python -m pbc COMMAND)\n\ncommands:\n"
            + "\n".join(lines) + "\n\n`pbc COMMAND --help` shows a command's own options; --debug shows tracebacks.")


def command_main(name: str):
    """The `main(argv=None)` of command `name` (what `pbc-NAME` and `python -m pbc.NAME` call)."""
    if name not in COMMANDS:
        raise KeyError(f"unknown pbc command {name!r}")
    return importlib.import_module(f"pbc.cli.{COMMANDS[name][0]}").main


def main(argv: list[str] | None = None) -> None:
    """`pbc COMMAND [args]`."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(usage())
        return
    if args[0] not in COMMANDS:
        print(f"pbc: error: unknown command {args[0]!r}\n\n{usage()}", file=sys.stderr)
        sys.exit(2)
    command_main(args[0])(args[1:])


def run_as_module(name: str) -> None:
    """`python -m pbc.NAME` for the commands users know by their module (pbc/train.py, ...: two-line aliases):
    the same command."""
    command_main(name)(None)
