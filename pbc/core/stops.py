"""Stops that stop: SIGTERM and SIGINT end a pbc command and every process it started, with one line saying
where it stopped and the command that continues, and exit status 128 + the signal (130 SIGINT, 143 SIGTERM).

- `handled()`: while it runs (the entry floor wraps every command in it; `map_in_workers` too, for library
  callers), SIGINT raises KeyboardInterrupt and SIGTERM raises `Stopped` (a SystemExit, status 143) in the main
  thread, so every `finally` and `with` on the way out runs (Python's default for SIGTERM ends the process past
  them). Neither is an Exception: an `except Exception` (a failed-run record, a sweep step's) passes them on.
  A handler set over this one that calls it (Lightning's trainer: it stops after the current batch, writes
  `last.ckpt` and raises its SystemExit) owns that SIGTERM; this one records it (`stopped_by` reads it), and the
  exception leaving the command is reported as the stop. A second signal while a stop is under way is ignored.
- `child(argv, ...)`: a child process in a process group of its own, for a `with` block; an exception leaving
  the block (a stop, an error) stops it and everything in its group (`stop_group`: the same signal to the
  child, SIGKILL to the group for what is left after conf/stops.yaml's `grace_s`), so its own children (drape
  workers, data loader workers) go with it. A normal end waits for it.
- `step(where, note)`: what the stop line says (`stop_line`): the innermost step at the moment of the signal.

Every file pbc writes is written beside its place and renamed (pbc.core.io), so a stop leaves it whole or absent.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import yaml

from pbc.core.paths import CONF_DIR

SIGNALS = (signal.SIGINT, signal.SIGTERM)
STOPS_FILE = CONF_DIR / "stops.yaml"  # grace_s, kill_wait_s


@functools.cache
def stop_settings() -> dict[str, float]:
    """conf/stops.yaml (`grace_s`: how long a stopped child has before its group is killed; `kill_wait_s`: how
    long the killed group may take to go), read once a process and held to conf/bounds.yaml: a value out of its
    range is one ValueError naming the file, the key and the range. `child` reads it before its process starts,
    so a stop never waits on a file."""
    from pbc.core.validate import check_settings_file  # noqa: PLC0415 - validate loads torch; only children need it

    node = yaml.safe_load(STOPS_FILE.read_text()) or {}
    check_settings_file("stops", node, STOPS_FILE)
    return {k: float(node[k]) for k in ("grace_s", "kill_wait_s")}


class Stopped(SystemExit):
    """SIGTERM as an exception of the main thread: a SystemExit with status 128 + the signal, so a library caller
    with no handler of its own exits as a killed process would (143), after its `finally` blocks."""

    def __init__(self, signum: int):
        super().__init__(128 + int(signum))
        self.signum = int(signum)


@dataclass
class Step:
    """Where a command is (`where`, e.g. "step 3/5 data") and what the stop line adds after the command that
    continues (`note`, e.g. "the same command goes on from there"; a callable is asked when the line is made)."""
    where: str
    note: str | Callable[[], str] = ""

    def note_text(self) -> str:
        return self.note() if callable(self.note) else self.note


_steps: list[Step] = []
_received: int | None = None  # the stop signal that arrived, None before one
_at: Step | None = None  # the innermost step when it arrived
_installed = 0  # depth of `handled` blocks that set the handlers


def stopped_by(exc: BaseException) -> int | None:
    """The stop signal `exc` is or carries: Stopped's, SIGINT for KeyboardInterrupt, and for any other exception
    raised after a stop signal arrived (Lightning's SystemExit after a SIGTERM, its exit(1) after a Ctrl-C) that
    signal; None for an exception that is no stop."""
    if isinstance(exc, Stopped):
        return exc.signum
    if _received is not None:
        return _received
    if isinstance(exc, KeyboardInterrupt):
        return signal.SIGINT
    return None


def _on_signal(signum, frame) -> None:
    global _received, _at
    if _received is not None:  # a stop is under way: it ends within stop_settings()'s grace
        return
    _received, _at = signum, (_steps[-1] if _steps else None)
    if signum == signal.SIGTERM and signal.getsignal(signal.SIGTERM) is not _on_signal:
        return  # a handler set over this one called it (Lightning's): that code stops at its next safe point
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Stopped(signum)


@contextlib.contextmanager
def handled() -> Iterator[None]:
    """SIGINT and SIGTERM as exceptions for the block (see the module's docstring). Only the main thread may set
    a handler: elsewhere, or inside another `handled` block, it changes nothing."""
    global _installed, _received, _at
    if threading.current_thread() is not threading.main_thread() or _installed:
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        signal.signal(s, _on_signal)
    _installed += 1
    try:
        yield
    finally:
        _installed -= 1
        for s, handler in previous.items():
            with contextlib.suppress(TypeError, ValueError):  # None: a handler not set from Python
                signal.signal(s, handler if handler is not None else signal.SIG_DFL)
        _received, _at = None, None


@contextlib.contextmanager
def step(where: str, note: str | Callable[[], str] = "") -> Iterator[Step]:
    """The step a stop in the block is reported in; the yielded Step's `where` may change as the block goes on
    (`at`)."""
    here = Step(where, note)
    _steps.append(here)
    try:
        yield here
    finally:
        _steps.remove(here)


def at(where: str) -> None:
    """Say where the innermost `step` is now (`the drapes, 3 of 10 made`); nothing outside a step."""
    if _steps:
        _steps[-1].where = where


def stop_line(signum: int, command: str, args: Sequence[str]) -> str:
    """`stopped by SIGTERM in step 3/5 data (...); its processes are stopped and every file it wrote is whole; to
    continue: pbc garment fit shirt.obj ... (note)`: the step where the signal arrived and the command that
    continues (`pbc COMMAND args`, as it was started)."""
    here = _at if _at is not None else (_steps[-1] if _steps else None)
    again = shlex.join(["pbc", command, *args])
    where = f" in {here.where}" if here is not None else ""
    note = here.note_text() if here is not None else ""
    return (f"stopped by {signal.Signals(signum).name}{where}; its processes are stopped and every file it wrote "
            "is whole; " + (f"to continue: {again} ({note})" if note else f"to run it again: {again}"))


# ------------------------------------------------------------------------------------------ child processes
@contextlib.contextmanager
def child(argv: Sequence[str], **popen_kwargs) -> Iterator[subprocess.Popen]:
    """`subprocess.Popen(argv, **popen_kwargs)` in a process group of its own, for the block: an exception leaving
    the block stops the child and its group (`stop_group`, with the stop's own signal, else SIGTERM) before it
    goes on; a normal end waits for the child. No signal is taken between the start and the block."""
    group = {"process_group": 0} if sys.version_info >= (3, 11) else {"start_new_session": True}
    stop_settings()  # read (and checked) now: a stop must not wait on a file
    in_main = threading.current_thread() is threading.main_thread()
    if in_main:
        signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        proc = subprocess.Popen(list(argv), **group, **popen_kwargs)
    except BaseException:
        if in_main:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
        raise
    with proc:
        try:
            if in_main:  # a signal that came during the start is taken here, inside the block
                signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
            yield proc
        except BaseException as exc:
            stop_group(proc, stopped_by(exc) or signal.SIGTERM)
            raise


def _group_alive(pgid: int) -> bool:
    """Whether a live (not zombie) process is in group `pgid` (Linux: /proc; elsewhere killpg's answer)."""
    proc = Path("/proc")
    if not proc.is_dir():
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True
    for stat in proc.glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()  # state, ppid, pgrp, ...
            if int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
                return True
    return False


def stop_group(proc: subprocess.Popen, signum: int = signal.SIGTERM, grace: float | None = None) -> None:
    """Stop `proc` (started by `child`: its pid is its group's) and every process of its group: `signum` to the
    child (a pbc command stops its own children on it), then, for anything left in the group after `grace` s
    (None: conf/stops.yaml's grace_s), SIGKILL to the group. Returns once the child is reaped and the group is
    empty (or kill_wait_s after the SIGKILL)."""
    settings = stop_settings()
    grace = settings["grace_s"] if grace is None else grace
    pgid = proc.pid
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signum)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and (proc.poll() is None or _group_alive(pgid)):
        time.sleep(0.05)
    if proc.poll() is None or _group_alive(pgid):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pgid, signal.SIGKILL)
        deadline = time.monotonic() + settings["kill_wait_s"]
        while time.monotonic() < deadline and (proc.poll() is None or _group_alive(pgid)):
            time.sleep(0.05)
