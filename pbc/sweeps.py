"""Sweeps: run a named sweep end to end.

`python -m pbc.sweeps NAME [overrides]` makes the data once, runs the training multirun of
`conf/sweep/NAME.yaml`, then (for `hierarchy`) the stitched evaluation, then `pbc.report`; it records
the exact commands and wall time in `<sweep dir>/sweep.json`. Reading run dirs back (`Run`,
`load_runs`) lives in `pbc.runs`, which this module and `pbc.report` both import (names re-exported here).
Nothing here plots or formats.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

from pbc.io import write_text
from pbc.report import build_report
from pbc.runs import (  # noqa: F401  (re-exported: the run-dir reader's names, as before)
    ALIASES,
    FAILED,
    INCOMPLETE,
    METRICS_FILE,
    OK,
    SWEEP_RECORD,
    Run,
    _read_yaml,
    expected_jobs,
    find_run_dirs,
    flatten,
    load_run,
    load_runs,
    read_events,
    sweep_values,
)

ROOT = Path(__file__).resolve().parents[1]
# the sweep group lives with the other config groups: `python -m pbc.train -m +sweep=NAME`
SWEEP_NAMES = tuple(sorted(p.stem for p in (ROOT / "conf" / "sweep").glob("*.yaml")))
DEFAULT_SCALE = "cpu"  # the `- /scale:` default of every conf/sweep/*.yaml
# Overrides that decide the data set: the data step gets these and no others (launcher keys, losses...
# are not in a single run's config).
_DATA_KEYS = ("data", "garment", "body", "sim", "paths", "seed")


# ------------------------------------------------------------------------------------------ the runner
def _scale_of(overrides: list[str]) -> str:
    vals = [o.split("=", 1)[1] for o in overrides if o.lstrip("+").startswith("scale=")]
    return vals[-1] if vals else DEFAULT_SCALE


def scale_data(scale: str, conf_dir: Path = ROOT / "conf") -> str:
    """The data set a scale selects (its `override /data:` default). The data step asks for that data set
    alone: the samples do not depend on the image sizes or the trainer the scale also sets."""
    cfg = _read_yaml(conf_dir / "scale" / f"{scale}.yaml") or {}
    for entry in cfg.get("defaults") or []:
        if isinstance(entry, dict) and "override /data" in entry:
            return str(entry["override /data"])
    raise ValueError(f"conf/scale/{scale}.yaml selects no data set (`- override /data: NAME`)")


def sweep_commands(name: str, overrides: list[str], sweep_dir: Path, python: str = sys.executable):
    """The commands of one sweep, in order: [(step, argv)]."""
    if name not in SWEEP_NAMES:
        raise ValueError(f"unknown sweep {name!r}; choose one of {', '.join(SWEEP_NAMES)}")
    scale = _scale_of(overrides)
    data_ovr = [o for o in overrides if o.lstrip("+").split("=", 1)[0].split(".")[0] in _DATA_KEYS]
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
    if name == "robustness":  # one body per trial, then one training each and Figs. 9-10 (pbc.robustness)
        rest = [o for o in overrides if not o.lstrip("+").startswith("scale=")]
        cmds[1] = ("robustness", [python, "-m", "pbc.robustness", f"scale={scale}", *rest, "--dir", str(sweep_dir)])
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
    patches = [r for r in runs if r.cfg("model.kind") in ("patch", "patches")
               or (r.get("experiment") or "").startswith("patch")]
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


def _run_logged(argv: list[str], log: Path) -> tuple[int, str | None]:
    """Run argv, echoing its output and keeping it in log; -> (exit code, last error line or None)."""
    last_err = None
    with (
        open(log, "w") as f,
        subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc,
    ):
        for line in proc.stdout:
            sys.stdout.write(line)
            f.write(line)
            if "Error" in line or "Exception" in line:
                last_err = line.strip()
        code = proc.wait()
    return code, (last_err or f"exit {code}, see {log.name}") if code else None


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
        base = Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "sweeps" / name
        sweep_dir = base / f"{_scale_of(overrides)}_{time.strftime('%Y-%m-%d_%H-%M-%S')}"
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
        if argv is None:
            argv, error = evaluate_command(sweep_dir, python)
        if argv is None:
            code = 1
        else:
            print(f"[pbc.sweeps] {step}: {shlex.join(argv)}", flush=True)
            code, error = _run_logged(argv, sweep_dir / f"{step}.log")
        record["steps"].append(
            {"step": step, "argv": argv, "returncode": code, "error": error, "seconds": round(time.time() - ts, 1)}
        )
        rc = rc or code
        if step == "data" and code != 0:
            break  # no data, no runs: the train step would fail the same way in every job
    record["seconds"] = round(time.time() - t0, 1)
    write_text(sweep_dir / SWEEP_RECORD, json.dumps(record, indent=1))
    if report:
        print(f"[pbc.sweeps] report: {build_report(sweep_dir, report_dir)}", flush=True)
    return sweep_dir, rc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m pbc.sweeps",
        description="Run a named sweep end to end (data, training multirun, evaluation, report).",
    )
    ap.add_argument("name", choices=SWEEP_NAMES)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. scale=smoke hydra.launcher.n_jobs=2")
    ap.add_argument("--dir", type=Path, default=None, help="sweep dir (default runs/sweeps/NAME/SCALE_TIME)")
    ap.add_argument("--no-report", action="store_true")
    ap.add_argument("--report-dir", type=Path, default=None, help="write the report here (default: sweep dir)")
    args = ap.parse_args(argv)
    sweep_dir, rc = run_sweep(
        args.name, args.overrides, args.dir, report=not args.no_report, report_dir=args.report_dir
    )
    print(f"[pbc.sweeps] {sweep_dir} (exit {rc})")
    return rc


if __name__ == "__main__":
    sys.exit(main())
