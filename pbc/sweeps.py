"""Read Hydra run dirs into `Run` records: the one place that knows how a run dir looks on disk.

A run dir is what one `python -m pbc.train` / `pbc.evaluate` job leaves behind: `.hydra/{config,hydra,
overrides}.yaml`, `metrics.json` (numbers, or the job's error when it failed) and TensorBoard event
files. `load_runs(sweep_dir)` finds every run dir below a sweep dir (or the dir itself), so the report
never needs a global database. Nothing here plots or formats.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

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
        run.error = f"no {METRICS_FILE}" + (
            f": {t}" if (t := _log_tail(run_dir)) else " (killed, or still running)"
        )

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
    return [load_run(p, root, events=events) for p in find_run_dirs(root)]
