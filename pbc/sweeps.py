"""Sweeps on disk: run a named sweep end to end, and read run dirs back into `Run` records.

`python -m pbc.sweeps NAME [overrides]` makes the data once, runs the training multirun of
`sweeps/sweep/NAME.yaml`, then (for `hierarchy`) the stitched evaluation, then `pbc.report`; it records
the exact commands and wall time in `<sweep dir>/sweep.json`. `load_runs(sweep_dir)` is the one place
that knows how a run dir looks: what a `python -m pbc.train` / `pbc.evaluate` job leaves behind,
`.hydra/{config,hydra,overrides}.yaml`, `metrics.json` (numbers, or the job's error when it failed) and
TensorBoard event files, so the report never needs a global database. Nothing here plots or formats.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from pbc.io import write_text

METRICS_FILE = "metrics.json"
# Keys under which a failing job records why it failed in its metrics.json (pbc.train writes "error").
ERROR_KEYS = ("error", "exception", "traceback")
# Blocks of metrics.json that describe the run rather than measure it (their numbers are not metrics).
NON_METRIC_KEYS = ("config", "identity", "summary", "status", "optimized_metric", "best_checkpoint")
# Other names for the same metric, mapped onto the name pbc.train logs.
ALIASES = {"normal_error": "normal_distance"}
EVENTS_PREFIX = "events.out.tfevents."
# Folders inside a run dir that never hold another run: skipping them keeps the walk cheap.
_SKIP_DIRS = {".hydra", "checkpoints", "__pycache__", "meshes", "figures"}

OK, FAILED, INCOMPLETE = "ok", "failed", "incomplete"
# Jobs that leave a run dir but are no experiment (the runner's data step).
IGNORED_JOBS = ("generate",)

ROOT = Path(__file__).resolve().parents[1]
SWEEPS_DIR = ROOT / "sweeps"
SWEEP_NAMES = tuple(sorted(p.stem for p in (SWEEPS_DIR / "sweep").glob("*.yaml")))
DEFAULT_SCALE = "cpu"  # the `- /scale:` default of every sweeps/sweep/*.yaml
SWEEP_RECORD = "sweep.json"
# Overrides that decide the data set: the data step gets these and no others (launcher keys, losses...
# are not in a single run's config).
_DATA_KEYS = ("data", "garment", "body", "sim", "paths", "seed")


@dataclass
class Run:
    """One job's results. `metrics` is flat: "test/vertex_error_cm" -> float."""

    path: Path
    name: str  # path relative to the sweep dir ("." for the dir itself)
    job: str = ""  # hydra.job.name: "train", "evaluate", ...
    choices: dict[str, str] = field(default_factory=dict)  # config-group choices (experiment, loss, ...)
    overrides: dict[str, str] = field(default_factory=dict)  # the job's command-line overrides
    config: dict = field(default_factory=dict)  # .hydra/config.yaml, unresolved
    metrics: dict[str, float] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)  # non-scalar metrics.json content (per-patch lists, tables)
    curves: dict[str, list[tuple[int, float]]] = field(default_factory=dict)  # TensorBoard scalars
    sources: dict[str, str] = field(default_factory=dict)  # metric -> TensorBoard tag it was filled from
    status: str = OK
    error: str | None = None

    def get(self, key: str) -> str | None:
        """A group choice or override by name ("experiment", "loss", "stitch", ...)."""
        return self.choices.get(key, self.overrides.get(key))

    def cfg(self, dotted: str, default=None):
        node = self.config
        for part in dotted.split("."):
            if not isinstance(node, dict) or part not in node:
                return default
            node = node[part]
        return node


def flatten(d: dict, prefix: str = "") -> tuple[dict[str, float], dict]:
    """Nested metrics -> ({"a/b": float}, {"a/c": non-scalar}). Both flat and nested JSON are accepted."""
    scalars: dict[str, float] = {}
    other: dict = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            s, o = flatten(v, key + "/")
            scalars.update(s)
            other.update(o)
        elif isinstance(v, bool) or v is None:
            other[key] = v
        elif isinstance(v, (int, float)):
            scalars[key] = float(v)
        else:
            other[key] = v
    return scalars, other


def _read_yaml(path: Path):
    try:
        with open(path) as f:
            return yaml.safe_load(f)
    except (OSError, yaml.YAMLError):
        return None


def _parse_overrides(lines) -> dict[str, str]:
    out = {}
    for line in lines or []:
        key, sep, value = str(line).partition("=")
        if sep:
            out[key.lstrip("+~")] = value
    return out


def _log_tail(run_dir: Path, lines: int = 3) -> str | None:
    """The last error-looking lines of the job's log, for runs that died without writing metrics."""
    for log in sorted(run_dir.glob("*.log")):
        try:
            text = log.read_text(errors="replace").strip().splitlines()
        except OSError:
            continue
        hits = [t for t in text if "Error" in t or "Exception" in t]
        if hits:
            return " / ".join(h.strip() for h in hits[-lines:])
    return None


def read_events(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """All TensorBoard scalar series under a run dir (every events folder, merged by tag)."""
    folders = sorted({p.parent for p in run_dir.rglob(EVENTS_PREFIX + "*")})
    if not folders:
        return {}
    # Imported lazily: tensorboard's loader costs a second and many run dirs have no events.
    from tensorboard.backend.event_processing import event_accumulator

    curves: dict[str, list[tuple[int, float]]] = {}
    for folder in folders:
        acc = event_accumulator.EventAccumulator(str(folder), size_guidance={event_accumulator.SCALARS: 0})
        try:
            acc.Reload()
        except Exception:  # a truncated events file (killed job) must not hide the rest of the sweep
            continue
        for tag in acc.Tags().get("scalars", []):
            curves.setdefault(tag, []).extend((e.step, float(e.value)) for e in acc.Scalars(tag))
    for tag in curves:
        curves[tag].sort()
    return curves


def load_run(run_dir: Path, root: Path, events: bool = True) -> Run:
    run_dir = Path(run_dir)
    rel = os.path.relpath(run_dir, root)
    run = Run(path=run_dir, name=rel)
    hydra_cfg = _read_yaml(run_dir / ".hydra" / "hydra.yaml") or {}
    h = hydra_cfg.get("hydra", {}) if isinstance(hydra_cfg, dict) else {}
    run.job = str((h.get("job") or {}).get("name") or "")
    run.choices = {
        k: str(v)
        for k, v in ((h.get("runtime") or {}).get("choices") or {}).items()
        if v is not None and not k.startswith("hydra/")
    }
    run.overrides = _parse_overrides(_read_yaml(run_dir / ".hydra" / "overrides.yaml"))
    for k, v in run.overrides.items():
        if "." not in k:  # a group choice typed on the command line (a dotted key is a value override)
            run.choices.setdefault(k, v)
    run.config = _read_yaml(run_dir / ".hydra" / "config.yaml") or {}

    mfile = run_dir / METRICS_FILE
    if mfile.exists():
        try:
            data = json.loads(mfile.read_text())
        except (OSError, ValueError) as e:
            data = {"error": f"unreadable {METRICS_FILE}: {e}"}
        if not isinstance(data, dict):
            data = {"error": f"{METRICS_FILE} is not an object"}
        err = next((data.get(k) for k in ERROR_KEYS if data.get(k)), None)
        if err is None and str(data.get("status", "")).lower() in ("failed", "error"):
            err = "failed (no message)"
        run.metrics, run.extra = flatten(
            {k: v for k, v in data.items() if k not in ERROR_KEYS and k not in NON_METRIC_KEYS}
        )
        for key in list(run.metrics):
            head, _, leaf = key.rpartition("/")
            if leaf in ALIASES:
                run.metrics.setdefault(f"{head}/{ALIASES[leaf]}" if head else ALIASES[leaf], run.metrics[key])
        if err is not None:
            lines = str(err).strip().splitlines()
            run.status, run.error = FAILED, (lines[-1] if lines else "failed")
    else:
        run.status = INCOMPLETE
        run.error = f"no {METRICS_FILE}" + (f": {t}" if (t := _log_tail(run_dir)) else " (killed, or still running)")

    if events:
        run.curves = read_events(run_dir)
        # Fill what metrics.json lacks from the last logged value: the training split is only logged
        # as per-epoch running means ("train/x_epoch"), which is what a run without a "train" block has.
        if run.status == OK:
            for tag, series in run.curves.items():
                if "/" not in tag or tag.endswith("_step") or not series:
                    continue
                key = tag[: -len("_epoch")] if tag.endswith("_epoch") else tag
                if key not in run.metrics:
                    run.metrics[key] = series[-1][1]
                    run.sources[key] = tag
    return run


def is_run_dir(path: Path) -> bool:
    return (path / ".hydra").is_dir() or (path / METRICS_FILE).is_file()


def find_run_dirs(root: Path) -> list[Path]:
    """Every run dir at or below root, in a stable order (Hydra job number first, then name)."""
    root = Path(root)
    found = []
    for dirpath, dirnames, _ in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in _SKIP_DIRS and not d.startswith("tensorboard"))
        if is_run_dir(Path(dirpath)):
            found.append(Path(dirpath))

    def order(p: Path):
        rel = os.path.relpath(p, root)
        head = Path(rel).parts[0] if rel != "." else ""
        num = head.split("_", 1)[0]
        return (0 if rel == "." else 1, int(num) if num.isdigit() else 10**9, rel)

    return sorted(found, key=order)


def load_runs(root: Path, events: bool = True) -> list[Run]:
    """All runs under a sweep dir. Raises FileNotFoundError when the dir does not exist."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"sweep dir {root} does not exist")
    runs = [load_run(p, root, events=events) for p in find_run_dirs(root)]
    return [r for r in runs if r.job not in IGNORED_JOBS]


def sweep_values(key: str, value: str, conf_dir: Path = ROOT / "conf") -> list[str]:
    """What one `hydra.sweeper.params` entry expands to, with Hydra's own override grammar: a comma list,
    a range, or `glob(...)` over the options of config group `key` (read from conf/<key>/*.yaml)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    ovr = OverridesParser.create().parse_overrides([f"{key}={value}"])[0]
    if not ovr.is_sweep_override():
        return [str(ovr.value())]
    val = ovr.value()
    if type(val).__name__ == "Glob":
        return val.filter(sorted(p.stem for p in (conf_dir / key.lstrip("+")).glob("*.yaml")))
    return [str(v) for v in ovr.sweep_string_iterator()]


def expected_jobs(sweep_dir: Path) -> dict[str, list[str]]:
    """{key: values} the sweep was launched with (from Hydra's multirun.yaml), for naming missing runs."""
    cfg = _read_yaml(Path(sweep_dir) / "multirun.yaml")
    params = (((cfg or {}).get("hydra") or {}).get("sweeper") or {}).get("params") or {}
    out = {}
    for key, value in params.items():
        try:
            out[key.lstrip("+")] = sweep_values(key, str(value))
        except Exception:  # an unparsable or Optuna-style search space: nothing to enumerate
            continue
    return out


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
                "-cd",
                str(SWEEPS_DIR),
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
    patches = [r for r in runs if (r.get("experiment") or "").startswith("patch_")]
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
        from pbc.report import build_report

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
