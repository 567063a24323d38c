"""`pbc COMMAND [args]`: one door to every command, the same as `python -m pbc.COMMAND [args]` and the
`pbc-COMMAND` scripts ([project.scripts] in pyproject.toml). Each command keeps its own arguments (Hydra
overrides for train / generate / evaluate, argparse for the others); see `pbc COMMAND --help`."""

from __future__ import annotations

import importlib
import sys

# command -> the module whose `main()` runs it
COMMANDS = {
    "generate": "pbc.generate",      # make (or resume, or merge) a dataset          (Hydra)
    "train": "pbc.train",            # train one model, test it, write metrics.json  (Hydra)
    "evaluate": "pbc.evaluate",      # whole vs stitched patch models                (Hydra, conf/evaluate.yaml)
    "predict": "pbc.predict",        # poses -> garment meshes from trained runs      (argparse)
    "sweeps": "pbc.sweeps",          # a named sweep end to end                      (argparse)
    "report": "pbc.report",          # the report of a sweep dir                      (argparse)
    "preview": "pbc.data.preview",   # cloth-image figures of a dataset               (argparse)
    "main": "pbc.main",              # the README's main job                          (argv passed on)
}


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help") or args[0] not in COMMANDS:
        width = max(map(len, COMMANDS))
        lines = [f"  {c:<{width}}  python -m {m}" for c, m in COMMANDS.items()]
        msg = "usage: pbc COMMAND [args]\n\ncommands:\n" + "\n".join(lines)
        if args and args[0] not in ("-h", "--help"):
            sys.exit(f"unknown command {args[0]!r}\n{msg}")
        print(msg)
        return
    command, rest = args[0], args[1:]
    sys.argv = [f"pbc-{command}", *rest]  # Hydra and argparse read the command line themselves
    rc = importlib.import_module(COMMANDS[command]).main()
    if isinstance(rc, int) and not isinstance(rc, bool):  # the argparse commands return an exit status
        sys.exit(rc)


if __name__ == "__main__":
    main()
