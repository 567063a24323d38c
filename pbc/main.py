"""The README's main job: make the default dataset with its previews, then train and test on it.

Each step is the command a user would type, run as its own process so that each gets its own Hydra run
dir; extra arguments are passed to every step (e.g. `python -m pbc.main data=tshirt_tiny`).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

STEPS = [
    ("generate the dataset and its preview figures", ["pbc.generate", "preview=true"]),
]


def run(step: list[str], extra: list[str]) -> None:
    cmd = [sys.executable, "-m", *step, *extra]
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def main(argv: list[str] | None = None) -> None:
    extra = list(sys.argv[1:] if argv is None else argv)
    t0 = time.time()
    for title, step in STEPS:
        print(f"== {title}", flush=True)
        run(step, extra)
    print(f"== done in {time.time() - t0:.0f} s")
    for metrics in sorted(Path("runs").glob("train/*/metrics.json"))[-2:]:
        print(metrics.parent.name, json.dumps(json.loads(metrics.read_text()).get("test", {}), indent=1))


if __name__ == "__main__":
    main()
