"""The README's main job: make the default dataset with its previews, train the whole-shirt model and one
patch model on it (CPU schedule), and print their test metrics.

Each step is the command a user would type, run as its own process with its own Hydra run dir under
`runs/main/`. Extra arguments go to every step, e.g. `python -m pbc.main data=tshirt_tiny trainer=smoke`.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from pbc.runs import scoped_name

RUNS = Path("runs/main")
STEPS = [
    ("make the dataset and its preview figures", ["pbc.generate", "preview=true", f"hydra.run.dir={RUNS}/generate"]),
    ("train the whole-shirt model", ["pbc.train", "+experiment=whole", f"hydra.run.dir={RUNS}/whole"]),
    ("train patch model 7", ["pbc.train", "+experiment=patch_07", f"hydra.run.dir={RUNS}/patch_07"]),
]
SHOWN = ("vertex_error_cm", "normal_distance", "image_loss")


def main(argv: list[str] | None = None) -> None:
    extra = list(sys.argv[1:] if argv is None else argv)
    t_start = time.time()
    for title, step in STEPS:
        print(f"== {title}", flush=True)
        t0 = time.time()
        subprocess.run([sys.executable, "-m", *step, *extra], check=True)
        print(f"   ({time.time() - t0:.0f} s)", flush=True)
    print(f"== test metrics (done in {(time.time() - t_start) / 60:.1f} min)")
    print(f"{'run':<10}{'scope':>16}" + "".join(f"{k:>18}" for k in SHOWN))
    for run in ("whole", "patch_07"):
        test = json.loads((RUNS / run / "metrics.json").read_text())["test"]
        # a patch model is scored over its patch's vertices only (patch_vertex_error_cm): say so
        patch = scoped_name(SHOWN[0], "patch") in test
        values = [test.get(scoped_name(k, "patch") if patch else k, float("nan")) for k in SHOWN]
        scope = "its patch only" if patch else "whole garment"
        print(f"{run:<10}{scope:>16}" + "".join(f"{v:>18.4f}" for v in values))
    print(f"TensorBoard: tensorboard --logdir {RUNS}")


if __name__ == "__main__":
    main()
