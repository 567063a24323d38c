"""The entry floor's one error handler, its Hydra runner and the Hydra command line it reads (flags anywhere).

A user error is a mistake in what the user gave (a path, a value, an override, data made with other
settings): pbc's layers raise it with a message that names the problem and the fix, and here it becomes
that one line on stderr and exit status 2, in every command. Anything else is a bug: its traceback stays.
`--debug` (any command) or HYDRA_FULL_ERROR=1 shows the traceback of a user error too.

SIGINT and SIGTERM (pbc.core.stops) stop every command the same way: its child processes stopped, one line
`pbc CMD: stopped by SIGTERM in <step>; its processes are stopped and every file it wrote is whole; to continue:
pbc CMD ...`, exit status 130 or 143.
"""

from __future__ import annotations

import argparse
import difflib
import errno
import functools
import os
import re
import sys
import traceback
from collections.abc import Callable, Sequence

import hydra
from hydra._internal.utils import get_args_parser  # the parser hydra.main reads: Hydra's flags, not a copy
from hydra.core.hydra_config import HydraConfig
from hydra.errors import ConfigCompositionException, HydraException
from hydra.types import RunMode
from omegaconf import DictConfig
from omegaconf.errors import MissingMandatoryValue, OmegaConfBaseException

from pbc.core import stops
from pbc.core.config import override_hint
from pbc.core.io import DiskFull, LockHeld, free_bytes, out_of_space
from pbc.core.paths import CONF_DIR

USER_ERRORS = (ValueError, FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError, LockHeld,
               DiskFull, HydraException, OmegaConfBaseException)
# OSErrors that are the machine's state, not pbc's bug: say which path and what to free or change
USER_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EDQUOT}
DEBUG_FLAG = "--debug"
HYDRA_HELP_FLAG = "--hydra-help"
EXIT_USER_ERROR = 2


def is_user_error(exc: BaseException) -> bool:
    return isinstance(exc, USER_ERRORS) or (isinstance(exc, OSError) and exc.errno in USER_ERRNOS)


def one_line(exc: BaseException) -> str:
    """The message a user reads: pbc's own text, Hydra's without its wrapper, a close key for a typo."""
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, HydraException):  # Hydra's lists: one line of options, no search path
        text = text.split("\nConfig search path:")[0]
        text = re.sub(r"\n+Available options in '([^']+)':\s*((?:\n\t[^\n]+)+)",
                      lambda m: f"; options of {m.group(1)}: " + ", ".join(m.group(2).split()), text)
    if isinstance(exc, MissingMandatoryValue) and getattr(exc, "full_key", None):
        return f"the config value {exc.full_key} is not set (???): give it on the command line, {exc.full_key}=..."
    if not isinstance(exc, DiskFull) and out_of_space(exc):
        return full_disk_line(exc)
    cause = exc.__cause__
    if isinstance(exc, HydraException) and isinstance(cause, (OmegaConfBaseException, TypeError)):
        text = f"{text}: {str(cause).strip().splitlines()[0]}"  # Hydra's wrapper hides the key at fault
    if isinstance(exc, OSError) and exc.errno in USER_ERRNOS and exc.filename and str(exc.filename) not in text:
        text = f"{text} ({exc.filename})"
    return text


def full_disk_line(exc: BaseException) -> str:
    """A full disk that no writer named (the OSError is often two links down the chain): the file, the space
    left there and the fix, instead of a bare `[Errno 28] No space left on device`."""
    path, seen = None, set()
    while exc is not None and id(exc) not in seen and path is None:
        seen.add(id(exc))
        path = getattr(exc, "filename", None) if isinstance(exc, OSError) else None
        exc = exc.__cause__ or exc.__context__
    if path is None:
        return ("no space left on the device (a write failed with ENOSPC); free space on the disk of the output "
                "(--out, hydra.run.dir) or write it elsewhere")
    try:
        free = f" ({free_bytes(path) / 2**20:.1f} MiB free there)"
    except OSError:
        free = ""
    return (f"no space left on the device holding {path}{free}; free space there or write the output elsewhere "
            "(--out, hydra.run.dir); files pbc writes are whole or absent (written, then renamed)")


def entry_point(name: str, run: Callable[[list[str]], int | None]) -> Callable[[Sequence[str] | None], None]:
    """`main(argv=None)` of command `name`: `run(args)` under the one handler; exits with run's status. Under
    SIGINT or SIGTERM (pbc.core.stops.handled) it exits with 128 + the signal after one line naming the step it
    stopped in and the command that continues (stops.stop_line); any exception after the signal is that stop."""

    def main(argv: Sequence[str] | None = None) -> None:
        args = list(sys.argv[1:] if argv is None else argv)
        debug = DEBUG_FLAG in args or os.environ.get("HYDRA_FULL_ERROR") == "1"
        args = [a for a in args if a != DEBUG_FLAG]
        with stops.handled():
            try:
                rc = run(args)
            except BaseException as exc:
                signum = stops.stopped_by(exc)
                if signum is not None:  # SIGINT, SIGTERM: its children are stopped on the way here
                    if debug:
                        traceback.print_exc()
                    print(f"pbc {name}: {stops.stop_line(signum, name, args)}", file=sys.stderr, flush=True)
                    sys.exit(128 + signum)
                if not isinstance(exc, Exception) or debug or not is_user_error(exc):
                    raise
                print(f"pbc {name}: error: {one_line(exc)}", file=sys.stderr)
                sys.exit(EXIT_USER_ERROR)
        sys.exit(int(rc or 0))

    main.__doc__ = f"`pbc {name} [args]` (see `pbc {name} --help`)."
    return main


def run_hydra(task: Callable[[DictConfig], object], args: list[str], config_name: str = "config",
              own_overrides: Sequence[str] = ()) -> None:
    """Run the Hydra job `task` (a function of the composed config) with command-line `args`, the configs
    read from pbc's shipped conf/ (pbc.core.paths) wherever pbc is installed. `own_overrides` are the
    command's own (`hydra.output_subdir=null`), applied after the user's; Hydra's flags (`-m`, `--cfg job`,
    `--info`, `--help`, ...) may stand anywhere in `args` (hydra_argv).

    Hydra prints an exception itself and exits 1; here it re-raises instead (HYDRA_FULL_ERROR for the
    duration) so the entry floor's handler decides. In a single run the task's own exception is carried
    out of Hydra and raised after it has closed the job (no "Error executing job" banner); in a multirun
    it stays with the launcher, which marks that job failed and runs the others.
    """
    failure: list[BaseException] = []
    started: list[bool] = []

    def job(cfg: DictConfig):
        started.append(True)
        try:
            return task(cfg)
        except Exception as exc:
            if HydraConfig.get().mode != RunMode.RUN:
                raise
            failure.append(exc)
            return None

    job.__module__, job.__qualname__ = task.__module__, task.__qualname__  # Hydra names the job from these
    job.__name__ = task.__name__
    saved_argv, saved_env = sys.argv, os.environ.get("HYDRA_FULL_ERROR")
    sys.argv = hydra_argv(f"pbc-{task.__module__.rsplit('.', 1)[-1]}", args, own_overrides)
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        hydra.main(config_path=str(CONF_DIR), config_name=config_name, version_base="1.3")(job)()
    except ConfigCompositionException as exc:
        hint = config_key_hint(str(exc), hydra_flags_and_overrides(args)[1], config_name)
        if hint is None:
            raise
        raise ValueError(hint) from exc  # instead of Hydra's advice to add the key with "+"
    except OSError as exc:
        if started or not exc.filename:
            raise
        # Hydra makes the run dir (and its .hydra/, log file) before the job runs: name it and the fix
        raise PermissionError(f"cannot create the run dir {exc.filename}: {exc.strerror}; set hydra.run.dir "
                              "(or PBC_ROOT, or hydra.sweep.dir for -m) to a writable folder") from exc
    finally:
        sys.argv = saved_argv
        if saved_env is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = saved_env
    if failure:
        raise failure[0]


def config_key_hint(message: str, args: list[str], config_name: str) -> str | None:
    """For a mistyped override (`trainer.max_epoch=3`): the key meant (pbc.core.config.override_hint, as
    load_config says it); None when that is not the error."""
    return override_hint(message, args, config_name)


def hydra_argv(program: str, args: Sequence[str], own_overrides: Sequence[str] = ()) -> list[str]:
    """The command line hydra.main reads (its sys.argv) for `program args` plus the command's `own_overrides`:
    the user's overrides, then `own_overrides` (the later override of a key wins), then Hydra's flags, each
    one token (hydra_flags_and_overrides), wherever the user put them. argparse takes Hydra's overrides in one
    stretch, so this order holds whatever the user's was; ValueError (one line) for a flag Hydra refuses.
    With `--hydra-help` (Hydra's own help, composed without the command's config) only the overrides of
    `hydra.` keys are passed: the others name keys that config alone has."""
    flags, overrides = hydra_flags_and_overrides(args)
    if HYDRA_HELP_FLAG in flags:
        overrides = [o for o in overrides if o.lstrip("+~").startswith(("hydra.", "hydra/"))]
    return [program, *overrides, *own_overrides, *flags]


@functools.cache
def hydra_options() -> dict[str, argparse.Action]:
    """Every option string of Hydra's command line (`--cfg`, `-c`, `--multirun`, `-m`, `--info`, ...) -> its
    argparse action, read from the parser hydra.main uses."""
    return {name: action for action in get_args_parser()._actions for name in action.option_strings}


def hydra_flag_names() -> str:
    """Hydra's flags as a user reads them on one line: `--cfg/-c job|hydra|all, --multirun/-m, ...`."""
    actions = dict.fromkeys(hydra_options().values())
    return ", ".join("/".join(a.option_strings) + (f" {'|'.join(a.choices)}" if a.choices else "")
                     for a in actions)


def hydra_action(name: str) -> argparse.Action:
    """The action of Hydra's flag `name` (`--cfg`, `-c`, or a long flag's unique prefix `--multi`, as argparse
    takes it); ValueError naming the flag, the flag meant when one is close, and Hydra's flags otherwise."""
    options = hydra_options()
    if name in options:
        return options[name]
    prefixed = {options[o] for o in options if name.startswith("--") and o.startswith(name)}
    if len(prefixed) == 1:
        return prefixed.pop()
    close = difflib.get_close_matches(name, options, n=1, cutoff=0.75)
    fix = f"did you mean {close[0]}?" if close else f"Hydra's flags are {hydra_flag_names()}"
    raise ValueError(f"unknown flag {name!r}: {fix} (an override is key=value)")


def hydra_flag_value(action: argparse.Action, name: str, value: str) -> str:
    """`value` when Hydra's flag `action` (given as `name`) takes it; ValueError naming the flag, the value and
    what the flag takes."""
    if action.nargs == 0:
        raise ValueError(f"{name} takes no value, not {value!r}: give {name} alone")
    if action.choices and value not in action.choices:
        raise ValueError(f"{name} takes one of {', '.join(action.choices)}, not {value!r}: "
                         f"e.g. {name} {action.choices[0]}")
    return value


def hydra_flags_and_overrides(args: Sequence[str]) -> tuple[list[str], list[str]]:
    """`args` of a Hydra command split into (Hydra's flags, the overrides), each in its given order, the flags
    before, after or between the overrides. Each flag is one token, `--flag` or `--flag=value` (its long
    name), so the flags may follow the overrides on Hydra's command line whatever their values. A flag's value
    is the next argument (`--cfg job`) or joined (`--cfg=job`, `-c=job`); an optional one (`--info`) takes the
    next argument only when it is one of its choices. After `--` every argument is an override.

    ValueError (one line: the flag, the value, the fix) for a flag Hydra does not know, a value it refuses, a
    value missing, or a value given to a flag that takes none."""
    flags: list[str] = []
    overrides: list[str] = []
    rest = list(args)
    while rest:
        arg = rest.pop(0)
        if arg == "--":
            overrides += rest
            break
        if not arg.startswith("-"):
            overrides.append(arg)
            continue
        name, joined, value = arg.partition("=")
        action = hydra_action(name)
        long_name = max(action.option_strings, key=len)
        if joined:
            flags.append(f"{long_name}={hydra_flag_value(action, name, value)}")
        elif action.nargs == 0 or (action.nargs == "?" and not (rest and rest[0] in (action.choices or ()))):
            flags.append(long_name)
        elif rest and not rest[0].startswith("-"):
            flags.append(f"{long_name}={hydra_flag_value(action, name, rest.pop(0))}")
        else:
            values = f"one of {', '.join(action.choices)}" if action.choices else "a value"
            raise ValueError(f"{name} needs {values}: e.g. {name} {(action.choices or ['VALUE'])[0]}")
    return flags, overrides
