"""Run dirs on disk, read back: the one module that knows what a `python -m pbc.train` / `pbc.evaluate`
job leaves behind, so sweeps, reports and the predictor never parse it themselves.

A run dir holds `.hydra/{config,hydra,overrides}.yaml`, `metrics.json` (numbers, or the job's error when
it failed), `checkpoints/` (training) and TensorBoard event files. `load_runs(sweep_dir)` -> [`Run`]
(what a report needs: choices, metrics, curves, status); `read_run(run_dir)` -> `RunInfo` and
`select_patch_runs(paths, garment_hash, num_patches)` (what the predictor needs: kind, patch id, best checkpoint).
Nothing here trains, plots or formats.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from pbc.io import load_checkpoint, read_json

# The hand-made T-shirt cage's patch count (patches/, conf/experiment/patch_00..27). Everything that
# assembles or stitches patch runs takes the count from the dataset's cage instead: an imported garment's
# automatic cage has its own.
NUM_PATCHES = 28
# Where a stacked all-patches run (`+experiment=patches`) exports its P single-patch run dirs
# (`<run>/patches/patch_NN/`): `find_runs` given such a run dir answers those.
PATCH_EXPORT_DIR = "patches"
METRICS_FILE = "metrics.json"
# Keys under which a failing job records why it failed in its metrics.json (pbc.train writes "error").
ERROR_KEYS = ("error", "exception", "traceback")
# Blocks of metrics.json that describe the run rather than measure it (their numbers are not metrics).
NON_METRIC_KEYS = ("config", "identity", "summary", "status", "optimized_metric", "best_checkpoint",
                   "training_identity", "data")
# Other names for the same metric, mapped onto the name pbc.train logs.
ALIASES = {"normal_error": "normal_distance"}
EVENTS_PREFIX = "events.out.tfevents."
VERTEX_ERROR = "vertex_error_cm"
# Metrics averaged over the vertices a model predicts: a patch model's cover its patch only (110 of the
# shirt's 3,153 vertices), so they carry the scope in their name ("patch_vertex_error_cm") wherever they
# appear (TensorBoard, metrics.json, reports) and are never compared with a whole-garment number.
SCOPED = (VERTEX_ERROR, "normal_distance")
PATCH_PREFIX = "patch_"

# Folders inside a run dir that never hold another run: skipping them keeps the walk cheap.
_SKIP_DIRS = {".hydra", "checkpoints", "__pycache__", "meshes", "figures"}

OK, FAILED, INCOMPLETE = "ok", "failed", "incomplete"
# Jobs that leave a run dir but are no experiment (the runner's data step).
IGNORED_JOBS = ("generate",)

ROOT = Path(__file__).resolve().parents[1]
SWEEP_RECORD = "sweep.json"


def scoped_name(name: str, kind: str) -> str:
    """The logged name of metric ``name`` (or ``name_std``, ...) of a ``kind`` model: ``patch_`` + name for a
    patch model's vertex-subset metrics, else ``name``."""
    return PATCH_PREFIX + name if kind == "patch" and name.startswith(SCOPED) else name


def monitor(kind: str) -> str:
    """The checkpoint / scheduler monitor of a ``kind`` model: its validation vertex error (the one place
    this is derived; conf/callbacks reads it through the ``pbc.monitor`` resolver, pbc.config)."""
    return "val/" + scoped_name(VERTEX_ERROR, kind)


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

    patch = run_kind(run, data if mfile.exists() else {}) == "patch"
    if patch:
        scope_patch_metrics(run.metrics)
    if events:
        run.curves = read_events(run_dir)
        if patch:
            scope_patch_metrics(run.curves)
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


def run_kind(run: Run, metrics: dict) -> str | None:
    """whole | patch | fc of a training run: its config's model.kind, else metrics.json's identity or
    summary, else a `patch_NN` experiment choice; None for other jobs."""
    for kind in (run.cfg("model.kind"), (metrics.get("identity") or {}).get("kind"),
                 (metrics.get("summary") or {}).get("kind")):
        if isinstance(kind, str):
            return kind
    exp = run.get("experiment") or ""
    return "patch" if exp.startswith(PATCH_PREFIX) and exp[len(PATCH_PREFIX):].isdigit() else None


def scope_patch_metrics(table: dict) -> None:
    """A patch run's metrics or curves ({"split/name": ...}) under their scoped names, in place: runs made
    before the names said their scope logged patch_vertex_error_cm as vertex_error_cm (scoped_name)."""
    for key in list(table):
        head, sep, leaf = key.rpartition("/")
        new = head + sep + scoped_name(leaf, "patch")
        if new != key:
            table.setdefault(new, table.pop(key))


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


# ------------------------------------------------------------------------------------------ checkpoints
@dataclass
class RunInfo:
    """What a training run dir holds: its model kind, patch id, garment and best checkpoint."""

    dir: Path
    kind: str
    patch_id: int | None
    garment_hash: str
    checkpoint: Path
    config: dict
    data: dict | None = None  # metrics.json "data": the dataset's resolved dir and fingerprint (newer runs)


def _best_checkpoint(run_dir: Path, metrics: dict) -> Path | None:
    best = metrics.get("best_checkpoint")
    if best and Path(best).is_file():
        return Path(best)
    ck = run_dir / "checkpoints"
    cands = sorted(p for p in ck.glob("*.ckpt") if p.name != "last.ckpt") if ck.is_dir() else []
    if cands:
        return cands[-1]
    return ck / "last.ckpt" if (ck / "last.ckpt").is_file() else None


def read_run(run_dir: str | Path) -> RunInfo:
    """Read a run dir (metrics.json + checkpoints/); raises ValueError saying what is missing."""
    d = Path(run_dir)
    mpath = d / "metrics.json"
    if not mpath.is_file():
        raise ValueError(f"{d}: not a finished training run (no metrics.json)")
    metrics = read_json(mpath, "run metrics")
    if metrics.get("status") not in (None, "ok"):
        raise ValueError(f"{d}: the run failed ({metrics.get('error', 'status ' + str(metrics.get('status')))})")
    ckpt = _best_checkpoint(d, metrics)
    if ckpt is None:
        raise ValueError(f"{d}: no checkpoint under {d / 'checkpoints'}")
    ident = metrics.get("identity") or {}
    if not ident:  # older runs: the identity lives in the checkpoint's hparams
        ident = load_checkpoint(ckpt)["hyper_parameters"]["identity"]
    pid = ident.get("patch_id")
    return RunInfo(d, str(ident.get("kind")), None if pid is None else int(pid),
                   str(ident.get("garment_hash", "")), ckpt, metrics.get("config") or {}, metrics.get("data"))


def run_image_config(info: RunInfo, default=None):
    """The `image` config node a run was trained under (its metrics.json "config", resolved within the
    whole config), or `default` when the run records none."""
    if not (info.config or {}).get("image"):
        return default
    from omegaconf import OmegaConf

    return OmegaConf.create(info.config).image


def find_runs(paths: Sequence[str | Path] | str | Path) -> list[Path]:
    """Run dirs from a list of run dirs and/or sweep dirs (any dir holding */metrics.json below it).

    A stacked all-patches run dir stands for the single-patch runs it exported (PATCH_EXPORT_DIR)."""
    if isinstance(paths, str | Path):
        paths = [paths]
    out: list[Path] = []
    for p in map(Path, paths):
        if (p / "metrics.json").is_file():
            exported = sorted(m.parent for m in (p / PATCH_EXPORT_DIR).glob("*/metrics.json"))
            out += exported or [p]
        elif p.is_dir():
            # a sweep dir: training runs only (an evaluate run below it has no checkpoints/)
            found = sorted(m.parent for m in p.rglob("metrics.json") if (m.parent / "checkpoints").is_dir())
            if not found:
                raise ValueError(f"{p}: no training runs (metrics.json) found below it")
            out += found
        else:
            raise ValueError(f"{p}: no such run or sweep directory")
    return out


def select_patch_runs(paths, garment_hash: str, num_patches: int) -> list[RunInfo]:
    """Exactly one patch run per patch id 0..num_patches-1 for this garment, in id order.

    num_patches: the dataset's cage's patch count (no default: a garment's cage has its own, and a
    default of the shirt's 28 would ask a 10-patch garment for 18 runs that cannot exist).
    Raises one ValueError listing every problem: unreadable runs, runs of another kind or garment,
    unknown patch ids, patches claimed by two runs, and missing patches (with how to train them).
    """
    problems: list[str] = []
    by_id: dict[int, list[RunInfo]] = {}
    named = {Path(p) for p in ([paths] if isinstance(paths, str | Path) else paths)}
    for d in find_runs(paths):
        try:
            r = read_run(d)
        except ValueError as e:
            problems.append(str(e))
            continue
        if r.kind != "patch":
            if d in named:  # a whole/fc run found inside a sweep dir is simply not a patch run
                problems.append(f"{d}: a {r.kind!r} run, not a patch run")
        elif r.garment_hash != garment_hash:
            problems.append(f"{d}: trained on garment {r.garment_hash!r}, not {garment_hash!r}")
        elif r.patch_id is None or not 0 <= r.patch_id < num_patches:
            problems.append(f"{d}: patch id {r.patch_id} is not in 0..{num_patches - 1}")
        else:
            by_id.setdefault(r.patch_id, []).append(r)
    for k, rs in sorted(by_id.items()):
        if len(rs) > 1:
            problems.append(f"patch {k} is claimed by {len(rs)} runs: " + ", ".join(str(r.dir) for r in rs))
    missing = [k for k in range(num_patches) if k not in by_id]
    if missing:
        problems.append(f"missing patch runs for patch ids {missing}: the dataset's cage has {num_patches} "
                        f"patches (ids 0..{num_patches - 1}) and {num_patches - len(missing)} have a run. Train "
                        "each missing one with `python -m pbc.train +experiment=patch model.patch_id=ID`, or "
                        "every patch in one job with `+experiment=patches` (pass that run dir), and give all "
                        "the patch runs together")
    if problems:
        raise ValueError("cannot assemble the patch models:\n  - " + "\n  - ".join(problems))
    return [by_id[k][0] for k in range(num_patches)]
