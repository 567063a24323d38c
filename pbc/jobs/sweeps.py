"""Sweeps: run a named sweep end to end (the one sweep runner).

`python -m pbc.sweeps NAME [overrides]` makes the data once, (for `robustness`) one dataset per body
(`pbc.jobs.robustness.prepare_bodies`), runs the training multirun of `conf/sweep/NAME.yaml`, then (for
`hierarchy`) the stitched evaluation, then the report (`pbc.jobs.report.build_report`; the wrong-body study's
own: `pbc.jobs.robustness.build_report`); it records the exact commands and wall time in
`<sweep dir>/sweep.json`. Run dirs are read back through `pbc.core.runs`. Nothing here plots or formats.
"""

from __future__ import annotations

import json
import logging
import shlex
import subprocess
import sys
import time
import traceback
from pathlib import Path

from pbc.core.io import write_text
from pbc.core.paths import CONF_DIR
from pbc.core.runs import OK, SWEEP_RECORD, ModelKind, default_sweep_dir, load_runs, read_yaml
from pbc.jobs.report import build_report
from pbc.jobs.robustness import build_report as robustness_report
from pbc.jobs.robustness import prepare_bodies

log = logging.getLogger(__name__)


# the sweep group lives with the other config groups: `python -m pbc.train -m +sweep=NAME`
SWEEP_NAMES = tuple(sorted(p.stem for p in (CONF_DIR / "sweep").glob("*.yaml")))


DEFAULT_SCALE = "cpu"  # the `- /scale:` default of every conf/sweep/*.yaml


# Overrides that decide the data set: the data step gets these and no others (launcher keys, losses...
# are not in a single run's config).
_DATA_KEYS = ("data", "garment", "body", "sim", "paths", "seed")


# Steps run in this process (library functions, not commands): the wrong-body study's per-body datasets.
IN_PROCESS_STEPS = {"bodies": "pbc.jobs.robustness.prepare_bodies"}


# ------------------------------------------------------------------------------------------ the runner
def _scale_of(overrides: list[str]) -> str:
    vals = [o.split("=", 1)[1] for o in overrides if o.lstrip("+").startswith("scale=")]
    return vals[-1] if vals else DEFAULT_SCALE


def scale_data(scale: str, conf_dir: Path = CONF_DIR) -> str:
    """The data set a scale selects (its `override /data:` default). The data step asks for that data set
    alone: the samples do not depend on the image sizes or the trainer the scale also sets."""
    cfg = read_yaml(conf_dir / "scale" / f"{scale}.yaml") or {}
    for entry in cfg.get("defaults") or []:
        if isinstance(entry, dict) and "override /data" in entry:
            return str(entry["override /data"])
    raise ValueError(f"conf/scale/{scale}.yaml selects no data set (`- override /data: NAME`)")


def data_overrides(overrides: list[str]) -> list[str]:
    """The overrides that decide the data set (`_DATA_KEYS`)."""
    return [o for o in overrides if o.lstrip("+").split("=", 1)[0].split(".")[0] in _DATA_KEYS]


def sweep_commands(name: str, overrides: list[str], sweep_dir: Path, python: str = sys.executable):
    """The commands of one sweep, in order: [(step, argv)]; argv None: a step made or run at its turn
    (`evaluate`: its argv names the trained runs; an `IN_PROCESS_STEPS` step: a library call)."""
    if name not in SWEEP_NAMES:
        raise ValueError(f"unknown sweep {name!r}; choose one of {', '.join(SWEEP_NAMES)}")
    scale = _scale_of(overrides)
    data_ovr = data_overrides(overrides)
    cmds = [
        # Made once before the parallel jobs, which would otherwise all generate the same data at once.
        (
            "data",
            [
                python,
                "-m",
                "pbc.generate",
                f"data={scale_data(scale)}",
                *data_ovr,
                f"hydra.run.dir={sweep_dir}/.generate",
            ],
        ),
        (
            "train",
            [
                python,
                "-m",
                "pbc.train",
                "-m",
                f"+sweep={name}",
                f"scale={scale}",
                *[o for o in overrides if not o.lstrip("+").startswith("scale=")],
                f"hydra.sweep.dir={sweep_dir}",
            ],
        ),
    ]
    if name == "robustness":
        # one dataset per body before the multirun over robustness.trial; each trial's data.dir is its body's
        # (conf/sweep/robustness.yaml), so a data.dir override names the base data and stays out of training
        train = cmds[1][1]
        cmds[1] = ("train", [a for a in train if not a.lstrip("+").startswith("data.dir=")])
        cmds.insert(1, ("bodies", None))
    if name == "hierarchy":
        # Its argv names the runs, known only once training is over: see evaluate_command.
        cmds.append(("evaluate", None))
    return cmds


def _quote(path: Path) -> str:
    # Hydra run-dir names hold "=" and ","; quoted, the override grammar reads them as one string.
    return "'" + str(path) + "'"


def evaluate_command(sweep_dir: Path, python: str = sys.executable) -> tuple[list[str] | None, str | None]:
    """`pbc.evaluate` on the sweep's successful whole run and patch runs -> (argv, None) or (None, why)."""
    runs = [r for r in load_runs(sweep_dir, events=False) if r.status == OK and r.job == "train"]
    whole = [r for r in runs if r.get("experiment") == "whole"]
    # by model kind, not experiment name: the T-shirt's patch_NN, `+experiment=patch model.patch_id=N` on any
    # garment, or a stacked `+experiment=patches` run (pbc.evaluate reads the single-patch runs it exported)
    patches = [r for r in runs if r.kind in (ModelKind.PATCH, ModelKind.PATCHES)]
    if not whole or not patches:
        return None, f"nothing to evaluate: {len(whole)} successful whole runs, {len(patches)} patch runs"
    argv = [
        python,
        "-m",
        "pbc.evaluate",
        f"whole_run={_quote(whole[-1].path)}",
        "patch_runs=[" + ",".join(_quote(r.path) for r in patches) + "]",
        f"hydra.run.dir={sweep_dir / 'evaluate'}",
    ]
    return argv, None


def run_logged(argv: list[str], log: Path, show=None) -> tuple[int, str | None]:
    """Run argv, echoing its output and keeping it in log; -> (exit code, last error line or None).
    show: line -> the text to echo for it, or None to keep it in the log only (default: every line)."""
    last_err = None
    with (
        open(log, "w") as f,
        subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc,
    ):
        for line in proc.stdout:
            shown = line if show is None else show(line)
            if shown:
                sys.stdout.write(shown)
                sys.stdout.flush()
            f.write(line)
            if "Error" in line or "Exception" in line or ": error: " in line:  # the last, a command's one line
                last_err = line.strip()
        code = proc.wait()
    return code, (last_err or f"exit {code}, see {log.name}") if code else None


def _run_in_process(step: str, overrides: list[str], sweep_dir: Path) -> tuple[int, str | None]:
    """An `IN_PROCESS_STEPS` step; -> (0, None) or (1, its error), the traceback printed."""
    try:
        if step == "bodies":

            prepare_bodies(sweep_dir, [f"+scale={_scale_of(overrides)}", *data_overrides(overrides)], overrides)
        else:
            raise ValueError(f"no in-process step {step!r}")
    except Exception as e:  # recorded like a failed command: the sweep record says which step and why
        traceback.print_exc()
        return 1, f"{type(e).__name__}: {e}"
    return 0, None


def build_sweep_report(name: str, sweep_dir: Path, report_dir: Path | None = None) -> Path:
    """The report of a sweep dir: the wrong-body study's (robustness.md, Figs. 9-10) or the tables and
    claims of pbc.report (report.md)."""
    if name == "robustness":

        return robustness_report(sweep_dir, report_dir)
    return build_report(sweep_dir, report_dir)


def run_sweep(
    name: str,
    overrides: list[str],
    sweep_dir: Path | None = None,
    report: bool = True,
    python: str = sys.executable,
    report_dir: Path | None = None,
) -> tuple[Path, int]:
    """Run every step (a failed step is recorded and the rest still run); returns (sweep dir, rc)."""
    if sweep_dir is None:
        sweep_dir = default_sweep_dir(name, _scale_of(overrides))
    sweep_dir = Path(sweep_dir).resolve()
    sweep_dir.mkdir(parents=True, exist_ok=True)
    record = {
        "name": name,
        "argv": ["python", "-m", "pbc.sweeps", name, *overrides],
        "started": time.strftime("%Y-%m-%d %H:%M:%S"),
        "steps": [],
    }
    t0 = time.time()
    rc = 0
    for step, argv in sweep_commands(name, overrides, sweep_dir, python):
        ts = time.time()
        error = None
        entry = {"step": step}
        if step in IN_PROCESS_STEPS:
            print(f"[pbc.sweeps] {step}: {IN_PROCESS_STEPS[step]}", flush=True)
            entry["call"] = IN_PROCESS_STEPS[step]
            code, error = _run_in_process(step, overrides, sweep_dir)
        else:
            if argv is None:
                argv, error = evaluate_command(sweep_dir, python)
            if argv is None:
                code = 1
            else:
                print(f"[pbc.sweeps] {step}: {shlex.join(argv)}", flush=True)
                code, error = run_logged(argv, sweep_dir / f"{step}.log")
        entry.update(argv=argv, returncode=code, error=error, seconds=round(time.time() - ts, 1))
        record["steps"].append(entry)
        rc = rc or code
        if step in ("data", "bodies") and code != 0:
            break  # no data, no runs: the train step would fail the same way in every job
    record["seconds"] = round(time.time() - t0, 1)
    write_text(sweep_dir / SWEEP_RECORD, json.dumps(record, indent=1))
    if report:
        print(f"[pbc.sweeps] report: {build_sweep_report(name, sweep_dir, report_dir)}", flush=True)
    return sweep_dir, rc
