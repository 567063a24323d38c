"""Run dirs on disk, written and read back: the one module that knows what a `python -m pbc.train` /
`pbc.evaluate` job leaves behind, so training, sweeps, reports and the predictor never parse it themselves.

A run dir holds `.hydra/{config,hydra,overrides}.yaml`, `metrics.json` (a `RunRecord`: numbers, or the
job's error when it failed), `checkpoints/` (training) and TensorBoard event files.

- `RunRecord`: the typed metrics.json. `RunRecord.read(path)` / `.write(run_dir)` (atomic) are the only
  reader and writer; pbc.train, the stacked export (pbc.models.stacked) and pbc.evaluate write through it.
- `ModelKind`: what a model predicts (whole | patch | patches | fc), validated when a record is made.
- metric names (`VERTEX_ERROR`, `NORMAL_DISTANCE`, `IMAGE_LOSS`) and their patch scope (`scoped_name`,
  `monitor`).
- `Run`: one run dir read back (its record, Hydra choices and overrides, TensorBoard curves, status).
  `load_run` / `load_runs(sweep_dir)` never raise on a failed or killed job (reports list them);
  `read_run(run_dir)` is the same `Run`, refused unless it is a finished training run with a checkpoint
  (what the predictor needs), and `select_patch_runs` picks one patch run per patch id.

Nothing here trains, plots or formats.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from enum import Enum
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from pbc.core.io import read_json, write_json
from pbc.core.paths import CONF_DIR

# ------------------------------------------------------------------------------------------ metric names
# What pbc.models logs and metrics.json holds, per split ("test/vertex_error_cm"); the one definition.
VERTEX_ERROR = "vertex_error_cm"  # mean vertex distance to the simulated cloth, cm
NORMAL_DISTANCE = "normal_distance"  # mean 1 - cos between predicted and simulated vertex normals
IMAGE_LOSS = "image_loss"  # eq. 1 on the cloth image
# pbc.evaluate's, per entry: what an edge carries that the ground truth's does not, across the cage's seams
# and over every other edge (for scale), cm
SEAM_JUMP, INTERIOR_JUMP = "seam_jump_cm", "interior_jump_cm"
# Metrics averaged over the vertices a model predicts: a patch model's cover its patch only (110 of the
# shirt's 3,153 vertices), so they carry the scope in their name ("patch_vertex_error_cm") wherever they
# appear (TensorBoard, metrics.json, reports) and are never compared with a whole-garment number.
SCOPED = (VERTEX_ERROR, NORMAL_DISTANCE)
PATCH_PREFIX = "patch_"
# The metric blocks of a training record: the best checkpoint on the test and training splits, and the
# best validation score (the checkpoint monitor's split).
METRIC_BLOCKS = ("test", "train", "val_best")

# Where a stacked all-patches run (`+experiment=patches`) exports its P single-patch run dirs
# (`<run>/patches/patch_NN/`): `find_runs` given such a run dir answers those.
PATCH_EXPORT_DIR = "patches"
METRICS_FILE = "metrics.json"
EVENTS_PREFIX = "events.out.tfevents."

# Folders inside a run dir that never hold another run: skipping them keeps the walk cheap.
# .timing: `pbc sweeps paper`'s short runs that measure a model's step (no experiment)
_SKIP_DIRS = {".hydra", "checkpoints", "__pycache__", "meshes", "figures", ".timing"}

OK, FAILED, INCOMPLETE = "ok", "failed", "incomplete"
# Jobs that leave a run dir but are no experiment (the runner's data step).
IGNORED_JOBS = ("generate",)

SWEEP_RECORD = "sweep.json"


class ModelKind(str, Enum):
    """What a model predicts (`model.kind`, the cloth target of pbc.pixels.target)."""
    WHOLE = "whole"  # the whole garment's image
    PATCH = "patch"  # one patch's crop
    PATCHES = "patches"  # every patch in one stacked job (exports one PATCH run per patch)
    FC = "fc"  # per-vertex values from a fully connected net

    def __str__(self) -> str:
        return self.value

    @classmethod
    def parse(cls, value, where: str = "model.kind") -> ModelKind:
        """`value` as a kind; a ValueError naming the valid ones otherwise."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"{where}={value!r} is not a model kind; one of "
                             f"{', '.join(k.value for k in cls)}") from None


def scoped_name(name: str, kind: ModelKind | str) -> str:
    """The logged name of metric ``name`` (or ``name_std``, ...) of a ``kind`` model: ``patch_`` + name for a
    patch model's vertex-subset metrics, else ``name``."""
    return PATCH_PREFIX + name if ModelKind.parse(kind) is ModelKind.PATCH and name.startswith(SCOPED) else name


def monitor(kind: ModelKind | str) -> str:
    """The checkpoint / scheduler monitor of a ``kind`` model: its validation vertex error (the one place
    this is derived; conf/callbacks reads it through the ``pbc.monitor`` resolver, pbc.core.config)."""
    return "val/" + scoped_name(VERTEX_ERROR, kind)


# ------------------------------------------------------------------------------------------ the record
def _metric_block(block, where: str) -> dict[str, float]:
    if not isinstance(block, Mapping):
        raise ValueError(f"{where} is not a table of metrics: {block!r}")
    out = {}
    for k, v in block.items():
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ValueError(f"{where}/{k} is not a number: {v!r}")
        out[str(k)] = float(v)
    return out


@dataclass
class RunRecord:
    """A job's metrics.json: what it measured and what it was configured with, or why it failed.

    A training record (``kind`` set) holds the best checkpoint's ``test`` / ``train`` metrics and the best
    ``val_best`` score under the names the model logged (``scoped_name``), the metric that chose the
    checkpoint (``optimized_metric``, ``monitor(kind)``; a patch run exported from a stacked run has none of
    its own: ``exported_from`` names the stacked run whose mean chose it), the config as trained and the
    data record. A job that trains no model (pbc.evaluate) has ``kind`` None and keeps its own blocks in
    ``extra`` (written at the top level: split, entries, ...). A failed job has ``status`` "failed", the
    ``error`` line and its ``traceback``.
    """
    status: str = OK
    kind: ModelKind | None = None
    test: dict[str, float] = field(default_factory=dict)
    train: dict[str, float] = field(default_factory=dict)
    val_best: dict[str, float] = field(default_factory=dict)
    optimized_metric: str | None = None
    best_checkpoint: str | None = None
    config: dict = field(default_factory=dict)  # the config as run (data.dir resolved: pbc.train)
    data: dict | None = None  # the dataset's resolved dir and fingerprint (pbc.data.dataset.run_data_record)
    identity: dict = field(default_factory=dict)  # what a checkpoint must match (the target's identity)
    training_identity: dict | None = None  # what a resumed run must match (pbc.core.validate.training_identity)
    summary: dict = field(default_factory=dict)  # the flat hparams (pbc.jobs.train.run_summary)
    epochs: int | None = None
    seconds: float | None = None
    error: str | None = None
    traceback: str | None = None
    exported_runs: list[str] = field(default_factory=list)  # a stacked run's exported single-patch run dirs
    exported_from: str | None = None  # an exported patch run's stacked run dir
    # the training split's joint-angle range (pbc.motion.ranges.range_record): what predict compares new
    # poses with, kept here so it travels with the run (and a shipped model) when its dataset does not
    pose_range: dict | None = None
    extra: dict = field(default_factory=dict)  # a job's own top-level blocks (pbc.evaluate's)

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Validate (on every construction, so on every read and write): status, kind, the metric blocks,
        and that a finished training record names the metric its checkpoint was chosen by."""
        if self.status not in (OK, FAILED):
            raise ValueError(f"status {self.status!r} is neither {OK!r} nor {FAILED!r}")
        if self.kind is not None:
            self.kind = ModelKind.parse(self.kind, "kind")
        for name in METRIC_BLOCKS:
            setattr(self, name, _metric_block(getattr(self, name), name))
        if self.status == FAILED and not self.error:
            raise ValueError("a failed run's record must say why (error)")
        if self.status == OK and self.kind is not None and self.exported_from is None \
                and self.optimized_metric != monitor(self.kind):
            raise ValueError(f"a {self.kind} run's checkpoint is chosen by {monitor(self.kind)}, "
                             f"the record says {self.optimized_metric!r}")
        if self.pose_range is not None:
            check_pose_range(self.pose_range)
        clash = set(self.extra) & {f.name for f in fields(self)}
        if clash:
            raise ValueError(f"extra blocks {sorted(clash)} would overwrite the record's own fields")

    # -------------------------------------------------------------- constructors
    @classmethod
    def failure(cls, error: BaseException | str, config: Mapping | None = None,
                traceback: str | None = None) -> RunRecord:
        """The record of a job that failed: its error line, traceback and config (its model kind when the
        config names a valid one; a config whose model.kind is the error's cause records none)."""
        msg = f"{type(error).__name__}: {error}" if isinstance(error, BaseException) else str(error)
        config = dict(config or {})
        kind = ((config.get("model") or {}) if isinstance(config.get("model"), Mapping) else {}).get("kind")
        kind = kind if kind in {k.value for k in ModelKind} else None
        return cls(status=FAILED, kind=kind, error=msg, traceback=traceback, config=config)

    @classmethod
    def from_dict(cls, d: Mapping, where: str = METRICS_FILE) -> RunRecord:
        """A record from metrics.json's object; a ValueError naming `where` when it is not one."""
        if not isinstance(d, Mapping):
            raise ValueError(f"{where} is not a JSON object")
        own = {f.name for f in fields(cls)} - {"extra"}
        try:
            return cls(**{k: v for k, v in d.items() if k in own},
                       extra={k: v for k, v in d.items() if k not in own})
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where} is not a run record: {e}") from e

    @classmethod
    def read(cls, path: str | Path) -> RunRecord:
        """Read a metrics.json (a run dir's, or the file itself)."""
        path = Path(path)
        if path.is_dir():
            path = path / METRICS_FILE
        return cls.from_dict(read_json(path, "run metrics"), str(path))

    def to_dict(self) -> dict:
        """metrics.json's object: the fields, then the extra blocks at the top level; empty and None
        fields are left out."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            # a training record always shows its metric blocks, empty when not scored (test=false)
            keep_empty = f.name in METRIC_BLOCKS and self.kind is not None
            if f.name == "extra" or v is None or (v in ({}, []) and not keep_empty):
                continue
            out[f.name] = v.value if isinstance(v, ModelKind) else v
        return {**out, **self.extra}

    def write(self, run_dir: str | Path) -> Path:
        """Write `<run_dir>/metrics.json` atomically (a reader never sees half a record); -> its path."""
        self.check()
        path = Path(run_dir) / METRICS_FILE
        write_json(path, self.to_dict())
        return path

    # -------------------------------------------------------------- reading
    def metrics(self) -> dict[str, float]:
        """Every number, flat: "test/vertex_error_cm", "val_best/...", "entries/whole/..." (extra blocks),
        "epochs", "seconds"."""
        out = {f"{b}/{k}": v for b in METRIC_BLOCKS for k, v in getattr(self, b).items()}
        out.update(flatten(self.extra)[0])
        for name in ("epochs", "seconds"):
            if getattr(self, name) is not None:
                out[name] = float(getattr(self, name))
        return out

    def metric(self, split: str, name: str) -> float | None:
        """Metric `name` (unscoped, e.g. VERTEX_ERROR) of block `split`, under this kind's scoped name."""
        block = getattr(self, split) if split in METRIC_BLOCKS else {}
        return block.get(scoped_name(name, self.kind) if self.kind is not None else name)


# the charts a pose range record's angles may be in (pbc.motion.ranges reads them); a record without one: the first
POSE_CHARTS = ("euler_xzy", "swing_twist")


def check_pose_range(record) -> None:
    """A ValueError unless `record` is a pose range record: {"split", "poses", "deg": {joint: {"x" | "y" |
    "z": [min, max]}}} with finite min <= max degrees (pbc.motion.ranges.range_record writes it)."""
    deg = record.get("deg") if isinstance(record, Mapping) else None
    if not isinstance(deg, Mapping) or not deg:
        raise ValueError(f"pose_range is not a joint-angle range record (no 'deg' table of joints): {record!r:.80}")
    if record.get("chart", POSE_CHARTS[0]) not in POSE_CHARTS:
        raise ValueError(f"pose_range/chart: {record['chart']!r} is not a joint-angle chart ({', '.join(POSE_CHARTS)})")
    for joint, axes in deg.items():
        for ax, lo_hi in (axes.items() if isinstance(axes, Mapping) else [(None, axes)]):
            ok = (ax in ("x", "y", "z") and isinstance(lo_hi, list | tuple) and len(lo_hi) == 2
                  and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in lo_hi)
                  and lo_hi[0] <= lo_hi[1])
            if not ok:
                raise ValueError(f"pose_range/deg/{joint}/{ax}: {lo_hi!r} is not a [min, max] of degrees")


def flatten(d: dict, prefix: str = "") -> tuple[dict[str, float], dict]:
    """Nested tables -> ({"a/b": float}, {"a/c": non-scalar})."""
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
        elif isinstance(v, int | float):
            scalars[key] = float(v)
        else:
            other[key] = v
    return scalars, other


# ------------------------------------------------------------------------------------------ run dirs
@dataclass
class Run:
    """One run dir read back: its record (None when the job left none: killed, or still running), Hydra
    choices and overrides, TensorBoard curves and status. `metrics` is flat: "test/vertex_error_cm" -> float."""
    path: Path
    name: str = "."  # path relative to the sweep dir ("." for the dir itself)
    job: str = ""  # hydra.job.name: "train", "evaluate", ...
    choices: dict[str, str] = field(default_factory=dict)  # config-group choices (experiment, loss, ...)
    overrides: dict[str, str] = field(default_factory=dict)  # the job's command-line overrides
    hydra_config: dict = field(default_factory=dict)  # .hydra/config.yaml, unresolved
    record: RunRecord | None = None
    metrics: dict[str, float] = field(default_factory=dict)
    curves: dict[str, list[tuple[int, float]]] = field(default_factory=dict)  # TensorBoard scalars
    sources: dict[str, str] = field(default_factory=dict)  # metric -> TensorBoard tag it was filled from
    status: str = INCOMPLETE
    error: str | None = None

    @property
    def config(self) -> dict:
        """The config the job ran with: its record's (data.dir resolved), else Hydra's .hydra/config.yaml
        (a job killed before it wrote a record; an exported patch run has no .hydra/)."""
        return (self.record.config if self.record is not None else None) or self.hydra_config

    @property
    def kind(self) -> ModelKind | None:
        """The model kind its record names (None: no record, or a job that trains no model)."""
        return self.record.kind if self.record is not None else None

    @property
    def identity(self) -> dict:
        return self.record.identity if self.record is not None else {}

    @property
    def patch_id(self) -> int | None:
        """A patch model's patch id: its record's identity, else its config's (a failed or killed job)."""
        pid = self.identity.get("patch_id")
        if pid is None and self.cfg("model.kind") == ModelKind.PATCH.value:
            pid = self.cfg("model.patch_id")
        return int(pid) if isinstance(pid, int) and not isinstance(pid, bool) else None

    @property
    def garment_hash(self) -> str:
        return str(self.identity.get("garment_hash", ""))

    @property
    def data(self) -> dict | None:
        return self.record.data if self.record is not None else None

    @property
    def checkpoint(self) -> Path | None:
        """The best checkpoint: the recorded one, found in this run dir's checkpoints/ when the run dir was
        moved; else the newest epoch checkpoint, else last.ckpt; None when there is none."""
        ck = self.path / "checkpoints"
        best = self.record.best_checkpoint if self.record is not None else None
        for cand in ([Path(best), ck / Path(best).name] if best else []):
            if cand.is_file():
                return cand
        epochs = sorted(p for p in ck.glob("*.ckpt") if p.name != "last.ckpt") if ck.is_dir() else []
        if epochs:
            return epochs[-1]
        return ck / "last.ckpt" if (ck / "last.ckpt").is_file() else None

    def get(self, key: str) -> str | None:
        """A group choice or override by name ("experiment", "loss", "robustness.trial", ...)."""
        return self.choices.get(key, self.overrides.get(key))

    def cfg(self, dotted: str, default=None):
        """A value of the run's config by dotted key, unresolved."""
        node = self.config
        for part in dotted.split("."):
            if not isinstance(node, dict) or part not in node:
                return default
            node = node[part]
        return node


def read_yaml(path: Path):
    """A YAML file as plain containers (Hydra's .hydra/*.yaml, unresolved), or None when unreadable."""
    try:
        return OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except Exception:  # a missing or corrupt side file: the run is still listed, without it
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
    from tensorboard.backend.event_processing import event_accumulator  # noqa: PLC0415 - tensorboard loads in about a second; only when curves are read

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


def load_run(run_dir: str | Path, root: str | Path | None = None, events: bool = True) -> Run:
    """A run dir read back, whatever state the job left it in (status ok | failed | incomplete, with the
    error); never raises for a bad record, which reads as a failed run. root: the sweep dir its name is
    relative to (default: the run dir itself); events: read the TensorBoard curves."""
    run_dir = Path(run_dir)
    run = Run(path=run_dir, name=os.path.relpath(run_dir, root if root is not None else run_dir))
    hydra_cfg = read_yaml(run_dir / ".hydra" / "hydra.yaml") or {}
    h = hydra_cfg.get("hydra", {}) if isinstance(hydra_cfg, dict) else {}
    run.job = str((h.get("job") or {}).get("name") or "")
    run.choices = {
        k: str(v)
        for k, v in ((h.get("runtime") or {}).get("choices") or {}).items()
        if v is not None and not k.startswith("hydra/")
    }
    run.overrides = _parse_overrides(read_yaml(run_dir / ".hydra" / "overrides.yaml"))
    for k, v in run.overrides.items():
        if "." not in k:  # a group choice typed on the command line (a dotted key is a value override)
            run.choices.setdefault(k, v)
    run.hydra_config = read_yaml(run_dir / ".hydra" / "config.yaml") or {}

    if (run_dir / METRICS_FILE).exists():
        try:
            run.record = RunRecord.read(run_dir)
        except (OSError, ValueError) as e:
            run.status, run.error = FAILED, f"unreadable {METRICS_FILE}: {e}"
        else:
            run.metrics = run.record.metrics()
            run.status = run.record.status
            if run.status == FAILED:
                lines = str(run.record.error).strip().splitlines()
                run.error = lines[-1] if lines else FAILED
    else:
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


def read_run(run_dir: str | Path) -> Run:
    """A finished training run dir (record + best checkpoint), as the predictor needs it; raises a
    ValueError saying what is missing (no record, a failed run, a job that trains no model, no checkpoint)."""
    d = Path(run_dir)
    if not (d / METRICS_FILE).is_file():
        raise ValueError(f"{d}: not a finished training run (no {METRICS_FILE})")
    record = RunRecord.read(d)  # a corrupt file: pbc.core.io.read_json's error naming it
    run = load_run(d, events=False)
    run.record = record
    if record.status != OK:
        raise ValueError(f"{d}: the run failed ({record.error})")
    if record.kind is None:
        raise ValueError(f"{d}: not a training run (its {METRICS_FILE} names no model kind)")
    if run.checkpoint is None:
        raise ValueError(f"{d}: no checkpoint under {d / 'checkpoints'}")
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


def default_sweep_dir(name: str, scale: str) -> Path:
    """Where `python -m pbc.sweeps NAME scale=SCALE` puts a sweep without --dir:
    $PBC_ROOT/runs/sweeps/NAME/SCALE_<date>_<time> (as conf/sweep/*.yaml's hydra.sweep.dir)."""
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    return Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "sweeps" / name / f"{scale}_{stamp}"


def sweep_values(key: str, value: str, conf_dir: Path = CONF_DIR) -> list[str]:
    """What one `hydra.sweeper.params` entry expands to, with Hydra's own override grammar: a comma list,
    a range, or `glob(...)` over the options of config group `key` (read from conf/<key>/*.yaml)."""
    ovr = OverridesParser.create().parse_overrides([f"{key}={value}"])[0]
    if not ovr.is_sweep_override():
        return [str(ovr.value())]
    val = ovr.value()
    if type(val).__name__ == "Glob":
        return val.filter(sorted(p.stem for p in (conf_dir / key.lstrip("+")).glob("*.yaml")))
    return [str(v) for v in ovr.sweep_string_iterator()]


def expected_jobs(sweep_dir: Path) -> dict[str, list[str]]:
    """{key: values} the sweep was launched with (from Hydra's multirun.yaml), for naming missing runs: the
    sweeper's params, each replaced by the command line's value for the same key, as Hydra's sweeper does
    (`robustness.trial=shape_0.0,shape_2.0` runs those two only)."""
    cfg = read_yaml(Path(sweep_dir) / "multirun.yaml")
    hydra = (cfg or {}).get("hydra") or {}
    params = dict((hydra.get("sweeper") or {}).get("params") or {})
    for line in (hydra.get("overrides") or {}).get("task") or []:
        key, sep, value = str(line).partition("=")
        if sep and (key in params or key.lstrip("+") in {k.lstrip("+") for k in params}):
            params = {k: v for k, v in params.items() if k.lstrip("+") != key.lstrip("+")} | {key: value}
    out = {}
    for key, value in params.items():
        try:
            out[key.lstrip("+")] = sweep_values(key, str(value))
        except Exception:  # an unparsable or Optuna-style search space: nothing to enumerate
            continue
    return out


# ------------------------------------------------------------------------------------------ checkpoints
def run_image_config(run: Run, default=None):
    """The `image` config node a run was trained under (its record's config, resolved within the whole
    config), or `default` when the run records none."""
    if not (run.config or {}).get("image"):
        return default

    return OmegaConf.create(run.config).image


def find_runs(paths: Sequence[str | Path] | str | Path) -> list[Path]:
    """Run dirs from a list of run dirs and/or sweep dirs (any dir holding */metrics.json below it).

    A stacked all-patches run dir stands for the single-patch runs it exported (PATCH_EXPORT_DIR)."""
    if isinstance(paths, str | Path):
        paths = [paths]
    out: list[Path] = []
    for p in map(Path, paths):
        if (p / METRICS_FILE).is_file():
            exported = sorted(m.parent for m in (p / PATCH_EXPORT_DIR).glob(f"*/{METRICS_FILE}"))
            out += exported or [p]
        elif p.is_dir():
            # a sweep dir: training runs only (an evaluate run below it has no checkpoints/)
            found = sorted(m.parent for m in p.rglob(METRICS_FILE) if (m.parent / "checkpoints").is_dir())
            if not found:
                raise ValueError(f"{p}: no training runs ({METRICS_FILE}) found below it")
            out += found
        else:
            raise ValueError(f"{p}: no such run or sweep directory")
    return out


def select_patch_runs(paths, garment_hash: str, num_patches: int) -> list[Run]:
    """Exactly one patch run per patch id 0..num_patches-1 for this garment, in id order.

    num_patches: the dataset's cage's patch count (no default: a garment's cage has its own, and a
    default of the shirt's 28 would ask a 10-patch garment for 18 runs that cannot exist).
    Raises one ValueError listing every problem: unreadable runs, runs of another kind or garment,
    unknown patch ids, patches claimed by two runs, and missing patches (with how to train them).
    """
    problems: list[str] = []
    by_id: dict[int, list[Run]] = {}
    named = {Path(p) for p in ([paths] if isinstance(paths, str | Path) else paths)}
    for d in find_runs(paths):
        try:
            r = read_run(d)
        except ValueError as e:
            problems.append(str(e))
            continue
        if r.kind is not ModelKind.PATCH:
            if d in named:  # a whole/fc run found inside a sweep dir is simply not a patch run
                problems.append(f"{d}: a {r.kind.value!r} run, not a patch run")
        elif r.garment_hash != garment_hash:
            problems.append(f"{d}: trained on garment {r.garment_hash!r}, not {garment_hash!r}")
        elif r.patch_id is None or not 0 <= r.patch_id < num_patches:
            problems.append(f"{d}: patch id {r.patch_id} is not in 0..{num_patches - 1}")
        else:
            by_id.setdefault(r.patch_id, []).append(r)
    for k, rs in sorted(by_id.items()):
        if len(rs) > 1:
            problems.append(f"patch {k} is claimed by {len(rs)} runs: " + ", ".join(str(r.path) for r in rs))
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
