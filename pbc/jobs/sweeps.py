"""Sweeps: run a named sweep end to end (the one sweep runner).

`python -m pbc.sweeps NAME [overrides]` makes the data once, (for `robustness`) one dataset per body
(`pbc.jobs.robustness.prepare_bodies`), runs the training multirun of `conf/sweep/NAME.yaml`, then (for
`hierarchy`) the stitched evaluation, then the report (`pbc.jobs.report.build_report`; the wrong-body study's
own: `pbc.jobs.robustness.build_report`); it records the exact commands and wall time in
`<sweep dir>/sweep.json`. Run dirs are read back through `pbc.core.runs`. Nothing here plots or formats.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import re
import shlex
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

from pbc.core import stops
from pbc.core.config import load_config
from pbc.core.io import write_text
from pbc.core.paths import CONF_DIR
from pbc.core.runs import OK, SWEEP_RECORD, ModelKind, default_sweep_dir, load_runs, read_yaml, sweep_values
from pbc.data.dataset import load_dataset
from pbc.jobs.report import build_report
from pbc.jobs.robustness import build_report as robustness_report
from pbc.jobs.robustness import prepare_bodies

log = logging.getLogger(__name__)


# the sweep group lives with the other config groups: `python -m pbc.train -m +sweep=NAME`
TRAIN_SWEEPS = tuple(sorted(p.stem for p in (CONF_DIR / "sweep").glob("*.yaml")))


# `pbc sweeps paper`: the paper's comparisons, several of the sweeps above under several seeds on one data set
# (conf/paper.yaml `comparison`)
PAPER = "paper"
SWEEP_NAMES = tuple(sorted((*TRAIN_SWEEPS, PAPER)))


DEFAULT_SCALE = "cpu"  # the `- /scale:` default of every conf/sweep/*.yaml


# Overrides that decide the data set: the data step gets these and no others (launcher keys, losses...
# are not in a single run's config; the training `seed` is not the data's `data.seed`).
_DATA_KEYS = ("data", "garment", "body", "sim", "paths")


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


def data_command(scale: str, overrides: list[str], sweep_dir: Path, python: str = sys.executable) -> list[str]:
    """`pbc.generate` of the scale's data set with the overrides that decide the data (`data_overrides`)."""
    return [python, "-m", "pbc.generate", f"data={scale_data(scale)}", *data_overrides(overrides),
            f"hydra.run.dir={sweep_dir}/.generate"]


def sweep_commands(name: str, overrides: list[str], sweep_dir: Path, python: str = sys.executable):
    """The commands of one sweep, in order: [(step, argv)]; argv None: a step made or run at its turn
    (`evaluate`: its argv names the trained runs; an `IN_PROCESS_STEPS` step: a library call)."""
    if name not in TRAIN_SWEEPS:
        raise ValueError(f"unknown sweep {name!r}; choose one of {', '.join(SWEEP_NAMES)}"
                         + (" (`paper` runs several: run_paper)" if name == PAPER else ""))
    scale = _scale_of(overrides)
    cmds = [
        # Made once before the parallel jobs, which would otherwise all generate the same data at once.
        ("data", data_command(scale, overrides, sweep_dir, python)),
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


def evaluate_command(sweep_dir: Path, python: str = sys.executable, seed: int | None = None,
                     out: Path | None = None) -> tuple[list[str] | None, str | None]:
    """`pbc.evaluate` on the sweep's successful whole run and patch runs (of training `seed` only, when given)
    -> (argv, None) or (None, why). out: its run dir (default <sweep dir>/evaluate)."""
    runs = [r for r in load_runs(sweep_dir, events=False) if r.status == OK and r.job == "train"
            and (seed is None or run_seed(r) == seed)]
    whole = [r for r in runs if r.get("experiment") == "whole"]
    # by model kind, not experiment name: the T-shirt's patch_NN, `+experiment=patch model.patch_id=N` on any
    # garment, or a stacked `+experiment=patches` run (pbc.evaluate reads the single-patch runs it exported)
    patches = [r for r in runs if r.kind in (ModelKind.PATCH, ModelKind.PATCHES)]
    if not whole or not patches:
        return None, f"nothing to evaluate: {len(whole)} successful whole runs, {len(patches)} patch runs"
    # the whole model trained under the patches' loss (a `pbc sweeps paper` dir also holds Table 1's others)
    whole = [r for r in whole if r.get("loss") in {p.get("loss") for p in patches}] or whole
    argv = [
        python,
        "-m",
        "pbc.evaluate",
        f"whole_run={_quote(whole[-1].path)}",
        "patch_runs=[" + ",".join(_quote(r.path) for r in patches) + "]",
        f"hydra.run.dir={out or sweep_dir / 'evaluate'}",
    ]
    return argv, None


def run_seed(run) -> int:
    """The training seed a run was made with (the config's `seed`)."""
    return int(run.cfg("seed", 0) or 0)


def run_logged(argv: list[str], log: Path, show=None) -> tuple[int, str | None]:
    """Run argv, echoing its output and keeping it in log; -> (exit code, last error line or None).
    show: line -> the text to echo for it, or None to keep it in the log only (default: every line).
    A stop (SIGINT, SIGTERM) or an error here stops the command and its processes (pbc.core.stops.child); what
    it printed until it ended (its own stop line) is in the log."""
    last_err = None
    with (
        open(log, "w") as f,
        stops.child(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc,
    ):
        try:
            for line in proc.stdout:
                shown = line if show is None else show(line)
                if shown:
                    sys.stdout.write(shown)
                    sys.stdout.flush()
                f.write(line)
                if "Error" in line or "Exception" in line or ": error: " in line:  # the last, a command's one line
                    last_err = line.strip()
        except BaseException as exc:
            stops.stop_group(proc, stops.stopped_by(exc) or signal.SIGTERM)
            with contextlib.suppress(Exception):
                f.write(proc.stdout.read())  # the rest of its output: the group is gone, so this ends
            raise
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
    """Run every step (a failed step is recorded and the rest still run); returns (sweep dir, rc).
    `paper`: run_paper."""
    if name == PAPER:
        return run_paper(overrides, sweep_dir, report, python, report_dir)
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
                with stops.step(f"step {step} (its log: {sweep_dir / f'{step}.log'})",
                                f"with --dir {sweep_dir}: a finished data set is kept, the steps run again"):
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


# ------------------------------------------------------------------------------ the paper's comparisons
# `pbc sweeps paper [scale=cpu_1k] [comparison.tables=losses,architectures] [comparison.seeds=0,1,2]`: one data
# set, then each table's training multirun once per seed (only the settings a seed still lacks: a killed
# sweep re-runs what is missing), the hierarchy's stitched evaluation once per seed, and one report over all
# of it (pbc.jobs.report: each setting's mean over its seeds, their range, and the claims judged against it).
# Before a table starts its wall time is estimated from a measured step (`estimate_table`).
COMPARISON_PREFIX = "comparison."


def comparison_settings(overrides: list[str], conf_dir: Path = CONF_DIR) -> dict:
    """conf/paper.yaml's `comparison` node, with `comparison.KEY=a,b` overrides applied."""
    comp = dict((read_yaml(conf_dir / "paper.yaml") or {}).get("comparison") or {})
    for o in overrides:
        key, _, value = o.partition("=")
        if key.startswith(COMPARISON_PREFIX):
            name = key[len(COMPARISON_PREFIX):]
            if name not in ("tables", "seeds", "scale", "timing_batches", "plan"):
                raise ValueError(f"{key}: unknown; set comparison.tables, comparison.seeds, comparison.scale, "
                                 "comparison.timing_batches or comparison.plan")
            comp[name] = [v for v in value.strip("[]").split(",") if v] if name in ("tables", "seeds") else value
    tables = [str(t) for t in comp.get("tables") or []]
    unknown = [t for t in tables if t not in TRAIN_SWEEPS]
    if unknown or not tables:
        raise ValueError(f"comparison.tables={','.join(tables)}: each must be one of {', '.join(TRAIN_SWEEPS)}")
    seeds = [int(x) for x in comp.get("seeds") or []]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"comparison.seeds={comp.get('seeds')}: give distinct integers, e.g. comparison.seeds=0,1")
    return {"tables": tables, "seeds": seeds, "scale": str(comp.get("scale") or DEFAULT_SCALE),
            "timing_batches": int(comp.get("timing_batches") or 3),
            "plan": str(comp.get("plan", False)).lower() in ("true", "1", "yes")}


def table_grid(table: str, overrides: list[str], conf_dir: Path = CONF_DIR) -> tuple[str, list[str]]:
    """The setting a table varies (its sweeper parameter with several values) and its values, narrowed by a
    command-line override of that key (`loss=l1,l2`)."""
    params = ((read_yaml(conf_dir / "sweep" / f"{table}.yaml") or {}).get("hydra") or {}).get("sweeper", {})
    params = dict(params.get("params") or {})
    values = {k.lstrip("+"): sweep_values(k, str(v), conf_dir) for k, v in params.items()}
    key = next((k for k, v in values.items() if len(v) > 1), next(iter(values)))
    for o in overrides:
        k, sep, v = o.partition("=")
        if sep and k.lstrip("+") == key:
            return key, sweep_values(key, v, conf_dir)
    return key, values[key]


def table_jobs(table: str, key: str, values: list[str], conf_dir: Path = CONF_DIR) -> dict[str, tuple[str, str]]:
    """Each value's job as (experiment, loss): the table's fixed parameters, else the sweep's and the root
    config's defaults (whole, l1). Two tables' jobs with the same pair are one training."""
    params = ((read_yaml(conf_dir / "sweep" / f"{table}.yaml") or {}).get("hydra") or {}).get("sweeper", {})
    fixed = {k.lstrip("+"): str(v) for k, v in dict(params.get("params") or {}).items() if k.lstrip("+") != key}
    out = {}
    for v in values:
        job = {"experiment": "whole", "loss": "l1", **fixed, key: v}
        out[v] = (job["experiment"], job["loss"])
    return out


def paper_grids(tables: list[str], overrides: list[str], conf_dir: Path = CONF_DIR) -> dict[str, tuple[str, list[str]]]:
    """{table: (key, values)} with every job trained once: a job an earlier table trains is left out of the
    later ones (Table 2's CNN and the hierarchy's whole model are Table 1's L1 runs; the report reads them
    from there and the hierarchy's evaluation finds them in the sweep dir)."""
    grids, seen = {}, set()
    for t in tables:
        key, values = table_grid(t, overrides, conf_dir)
        jobs = table_jobs(t, key, values, conf_dir)
        grids[t] = (key, [v for v in values if jobs[v] not in seen])
        seen |= set(jobs.values())
    return grids


def missing_settings(table_dir: Path, key: str, values: list[str], seed: int) -> list[str]:
    """The values of `key` that have no successful training run of `seed` under table_dir yet."""
    done = set()
    if table_dir.is_dir():
        done = {r.get(key) for r in load_runs(table_dir, events=False)
                if r.status == OK and r.job == "train" and run_seed(r) == seed}
    return [v for v in values if v not in done]


def _table_overrides(overrides: list[str], varied: set[str]) -> list[str]:
    """The command line for one table: without comparison.*, scale=, the seed, or any key some table varies
    (each table gets its own values of those)."""
    return [o for o in overrides if not o.startswith(COMPARISON_PREFIX)
            and o.lstrip("+").partition("=")[0] not in ({"scale", "seed"} | varied)]


def paper_train_command(table: str, seed: int, key: str, values: list[str], scale: str, overrides: list[str],
                        varied: set[str], out: Path, python: str = sys.executable) -> list[str]:
    """One table's training multirun for one seed, over `values` of its varied key."""
    return [python, "-m", "pbc.train", "-m", f"+sweep={table}", f"scale={scale}",
            *_table_overrides(overrides, varied), f"seed={seed}", f"{key}={','.join(values)}",
            f"hydra.sweep.dir={out}"]


def _attempt_dir(table_dir: Path, seed: int) -> Path:
    """A fresh multirun dir for a seed (an earlier, killed attempt keeps its own: its finished runs count)."""
    k = 0
    while (table_dir / f"seed{seed}_{k}").exists():
        k += 1
    return table_dir / f"seed{seed}_{k}"


def estimate_table(step_s: dict[str, float], overhead_s: dict[str, float], runs: dict[str, int],
                   epochs: dict[str, int], steps_per_epoch: dict[str, int]) -> float:
    """Seconds a table takes at most (early stopping only shortens it), one run after another: for each model
    kind, runs x (start-up overhead + epochs x steps an epoch x seconds a step)."""
    return sum(n * (overhead_s[k] + epochs[k] * steps_per_epoch[k] * step_s[k]) for k, n in runs.items() if n)


_PER_EPOCH = re.compile(r"([0-9.]+) s/epoch")


def measure_kind(experiment: str, scale: str, overrides: list[str], out: Path, batches: int,
                 python: str = sys.executable) -> dict:
    """Time a model kind on this machine: `pbc.train` for two epochs of `batches` batches (one validation batch
    each); -> {"step_s", "overhead_s", "epochs", "steps_per_epoch"}, kept in out/timing.json and reused."""
    cached = out / "timing.json"
    if cached.is_file():
        return json.loads(cached.read_text())
    overrides = [o for o in overrides if not o.lstrip("+").startswith(("hydra.", "hydra/"))]  # a single run's
    argv = [python, "-m", "pbc.train", f"+experiment={experiment}", f"+scale={scale}", *overrides,
            "trainer.max_epochs=2", f"++trainer.limit_train_batches={batches}", "++trainer.limit_val_batches=1",
            "test=false", "trainer.enable_progress_bar=false", f"hydra.run.dir={out}"]
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    code, error = run_logged(argv, out.parent / f"{out.name}.log", show=lambda line: None)
    wall = time.time() - t0
    if code:
        raise RuntimeError(f"timing run of {experiment} failed: {error}")
    per = [float(m.group(1)) for m in _PER_EPOCH.finditer((out / "train.log").read_text())]
    if len(per) < 2:
        raise RuntimeError(f"timing run of {experiment}: no per-epoch times in {out / 'train.log'}")
    second = max(2 * per[1] - per[0], per[1] / 2)  # epoch 2 alone (epoch 1 pays the warm-up)
    cfg = load_config([f"+experiment={experiment}", f"+scale={scale}", *overrides])
    rows = len(load_dataset(cfg.data.dir).split("train"))
    steps = math.ceil(rows / int(cfg.datamodule.batch_size))
    limit = cfg.trainer.get("limit_train_batches")
    if isinstance(limit, int) and not isinstance(limit, bool):
        steps = min(steps, limit)
    rec = {"step_s": second / batches, "overhead_s": max(0.0, wall - per[0] - second), "experiment": experiment,
           "epochs": int(cfg.trainer.max_epochs), "steps_per_epoch": steps, "train_rows": rows}
    write_text(cached, json.dumps(rec, indent=1))
    return rec


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 3600 else f"{seconds / 60:.1f} min"


def _kind(experiment: str) -> str:
    return "fc" if experiment.startswith("fc_") else "patch" if experiment.startswith("patch") else "whole"


def run_paper(overrides: list[str], sweep_dir: Path | None = None, report: bool = True,
              python: str = sys.executable, report_dir: Path | None = None) -> tuple[Path, int]:
    """`pbc sweeps paper`: every step, resumable; returns (sweep dir, rc)."""
    comp = comparison_settings(overrides)
    scale = _scale_of(overrides) if any(o.lstrip("+").startswith("scale=") for o in overrides) else comp["scale"]
    sweep_dir = Path(sweep_dir or default_sweep_dir(PAPER, scale)).resolve()
    sweep_dir.mkdir(parents=True, exist_ok=True)
    grids = paper_grids(comp["tables"], overrides)
    varied = {k for k, _ in grids.values()}
    base = _table_overrides(overrides, varied)
    record = {"name": PAPER, "argv": ["python", "-m", "pbc.sweeps", PAPER, *overrides], "scale": scale,
              "tables": comp["tables"], "seeds": comp["seeds"], "started": time.strftime("%Y-%m-%d %H:%M:%S"),
              "steps": []}
    t0 = time.time()

    def step(name: str, argv: list[str] | None, code: int, error: str | None, ts: float, **extra) -> None:
        record["steps"].append({"step": name, "argv": argv, "returncode": code, "error": error,
                                "seconds": round(time.time() - ts, 1), **extra})
        write_text(sweep_dir / SWEEP_RECORD, json.dumps({**record, "seconds": round(time.time() - t0, 1)}, indent=1))

    ts = time.time()
    data = data_command(scale, base, sweep_dir, python)
    print(f"[pbc.sweeps] data: {shlex.join(data)}", flush=True)
    code, error = run_logged(data, sweep_dir / "data.log")
    step("data", data, code, error, ts)
    rc = code
    if code == 0:
        for table in comp["tables"]:
            key, values = grids[table]
            table_dir = sweep_dir / table
            table_dir.mkdir(exist_ok=True)
            todo = {s: missing_settings(table_dir, key, values, s) for s in comp["seeds"]} if values else {}
            n_left = sum(len(v) for v in todo.values())
            if not n_left:
                print(f"[pbc.sweeps] {table}: every setting done under every seed", flush=True)
            else:
                ts = time.time()
                kinds = sorted({_kind(v) for vals in todo.values() for v in vals})
                rep = {"whole": "whole", "fc": next((v for v in values if _kind(v) == "fc"), ""),
                       "patch": next((v for v in values if _kind(v) == "patch"), "")}
                try:
                    timing = {k: measure_kind(rep[k], scale, base, sweep_dir / ".timing" / f"{rep[k]}",
                                              comp["timing_batches"], python) for k in kinds}
                except (RuntimeError, OSError, ValueError) as e:
                    print(f"[pbc.sweeps] {table}: timing failed, the table is skipped: {e}", flush=True)
                    step(f"{table}: timing", None, 1, str(e), ts)
                    rc = 1
                    continue
                runs = {k: sum(_kind(v) == k for vals in todo.values() for v in vals) for k in kinds}
                est = estimate_table({k: t["step_s"] for k, t in timing.items()},
                                     {k: t["overhead_s"] for k, t in timing.items()}, runs,
                                     {k: t["epochs"] for k, t in timing.items()},
                                     {k: t["steps_per_epoch"] for k, t in timing.items()})
                print(f"[pbc.sweeps] {table}: {n_left} runs to go ("
                      + ", ".join(f"{n} {k} x {timing[k]['epochs']} epochs x {timing[k]['steps_per_epoch']} "
                                  f"steps x {timing[k]['step_s']:.3g} s" for k, n in runs.items())
                      + f"): at most {_hours(est)} on this machine, one run after another", flush=True)
                step(f"{table}: timing", None, 0, None, ts, estimate_s=round(est, 1), timing=timing)
                if comp["plan"]:  # comparison.plan=true: the estimates alone
                    continue
                ts = time.time()
                for seed, vals in todo.items():
                    if not vals:
                        continue
                    argv = paper_train_command(table, seed, key, vals, scale, overrides, varied,
                                               _attempt_dir(table_dir, seed), python)
                    print(f"[pbc.sweeps] {table}, seed {seed}: {shlex.join(argv)}", flush=True)
                    with stops.step(f"{table}, seed {seed} (its log: {table_dir / f'train_seed{seed}.log'})",
                                    f"with --dir {sweep_dir}: it trains only the settings still missing"):
                        code, error = run_logged(argv, table_dir / f"train_seed{seed}.log")
                    step(f"{table}: train seed {seed}", argv, code, error, ts, estimate_s=round(est, 1))
                    rc = rc or code
                    ts = time.time()
            if table == "hierarchy" and not comp["plan"]:
                for seed in comp["seeds"]:
                    out = table_dir / f"evaluate_s{seed}"
                    if (out / "metrics.json").is_file() and json.loads((out / "metrics.json").read_text()).get(
                            "status") == OK:
                        continue
                    ts = time.time()
                    argv, error = evaluate_command(sweep_dir, python, seed=seed, out=out)
                    code = 1 if argv is None else run_logged(argv, table_dir / f"evaluate_s{seed}.log")[0]
                    step(f"hierarchy: evaluate seed {seed}", argv, code, error, ts)
                    rc = rc or code
    record["seconds"] = round(time.time() - t0, 1)
    write_text(sweep_dir / SWEEP_RECORD, json.dumps(record, indent=1))
    if report and any(True for _ in sweep_dir.glob("*/seed*_*")):
        print(f"[pbc.sweeps] report: {build_report(sweep_dir, report_dir)}", flush=True)
    return sweep_dir, rc
