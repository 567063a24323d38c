"""The README's main job: make the default dataset with its previews, train the whole-shirt model and one
patch model on it (CPU schedule), and print their test metrics.

    python -m pbc.main data=tshirt_tiny trainer=smoke      # a quick look (minutes)

Each step is the command a user would type, run as its own process with its own Hydra run dir under a
fresh `runs/main/<date>_<time>/` per invocation (`runs/main/latest` points at the newest; under $PBC_ROOT
when set, as `paths.log_dir`), so a quick look never overwrites a real run. The overrides go to every
step (`pbc.generate`, then `pbc.train` twice).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from pbc.core import stops
from pbc.core.runs import ModelKind, RunRecord, scoped_name
from pbc.data.baselines import mean_shape_errors
from pbc.data.dataset import load_dataset

RUNS = Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "main"  # conf/paths: ${paths.log_dir}/main
STEPS = [
    ("make the dataset and its preview figures", "generate", ["pbc.generate", "preview=true"]),
    ("train the whole-shirt model", "whole", ["pbc.train", "+experiment=whole"]),
    ("train patch model 7", "patch_07", ["pbc.train", "+experiment=patch_07"]),
]
# what a stop line adds to `pbc main ARGS`: generate resumes from the finished drapes, training starts again
RESUME = "in a new run dir: the dataset's finished drapes are kept, the trainings start again"
SHOWN = ("vertex_error_cm", "normal_distance", "image_loss")


def fresh_run_dir(root: Path = RUNS) -> Path:
    """A new `<root>/<date>_<time>[_N]` for this invocation, and `<root>/latest` pointing at it."""
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    out, n = root / stamp, 1
    while out.exists():
        out, n = root / f"{stamp}_{n}", n + 1
    out.mkdir(parents=True)
    latest = root / "latest"
    try:  # a convenience only: a file system without symlinks still gets the run
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(out.name, target_is_directory=True)
    except OSError:
        pass
    return out


def closing_table(runs: Path) -> str:
    """The test scores of the two models beside the training mean shape's, each over the vertices its model
    is scored on (a patch model: its patch only): an error in cm means little without the no-model level."""
    header = f"{'run':<10}{'scored over':>16}{'model cm':>12}{'mean shape cm':>15}" + "".join(
        f"{k:>18}" for k in SHOWN[1:])
    rows = [header, "-" * len(header)]
    for run in ("whole", "patch_07"):
        path = runs / run / "metrics.json"
        if not path.is_file():
            raise FileNotFoundError(f"{path} is missing: the {run} step ran but did not train (an override "
                                    "such as --cfg or --help stops pbc.train before training)")
        record = RunRecord.read(path)
        patch = record.kind == ModelKind.PATCH  # scored over its patch's vertices only (patch_vertex_error_cm)
        values = [record.test.get(scoped_name(k, "patch") if patch else k, float("nan")) for k in SHOWN]
        ds = load_dataset(record.data["dir"], check=False)
        vertices = ds.cage.patches[int(record.config["model"]["patch_id"])].vertices if patch else None
        mean_cm = mean_shape_errors(ds, ("test",), vertices)["test"]
        scope = f"patch {record.config['model']['patch_id']}" if patch else "whole garment"
        rows.append(f"{run:<10}{scope:>16}{values[0]:>12.3f}{mean_cm:>15.3f}"
                    + "".join(f"{v:>18.4f}" for v in values[1:]))
    return "\n".join(rows)


def run_steps(extra: list[str]) -> Path:
    """Every step in a fresh run dir with the overrides `extra`, then the closing table. A failed step stops
    the job naming the step and its run dir (the step printed its own error above); a stop (SIGINT, SIGTERM)
    stops the step's process and its own (pbc.core.stops.child). Returns the run dir."""
    runs = fresh_run_dir()
    print(f"== run dir {runs}", flush=True)
    t_start = time.time()
    for n, (title, name, step) in enumerate(STEPS, 1):
        print(f"== {title}", flush=True)
        t0 = time.time()
        with (stops.step(f"step {n}/{len(STEPS)} '{title}' (its run dir: {runs / name})", RESUME),
              stops.child([sys.executable, "-m", *step, f"hydra.run.dir={runs}/{name}", *extra]) as proc):
            rc = proc.wait()
        if rc:  # the step printed its own error above; say which step and where its log is, no traceback here
            sys.exit(f"pbc.main: step '{title}' failed (exit {rc}); its run dir: {runs / name}")
        print(f"   ({time.time() - t0:.0f} s)", flush=True)
    print(f"== test metrics (done in {(time.time() - t_start) / 60:.1f} min)")
    print(closing_table(runs))
    print(f"TensorBoard: tensorboard --logdir {runs}")
    return runs
