"""`pbc main [overrides]` (also `python -m pbc.main`): the README's main job (pbc.jobs.main): make the default
dataset with its previews, train the whole-shirt model and one patch model on it, print their test metrics."""

from __future__ import annotations

import pbc.jobs.main as job
from pbc.cli.errors import entry_point


def usage() -> str:
    steps = "\n".join(f"  {i + 1}. {title}: python -m {' '.join(cmd)} hydra.run.dir=<run dir>/{name}"
                      for i, (title, name, cmd) in enumerate(job.STEPS))
    return (f"usage: python -m pbc.main [HYDRA OVERRIDES...]\n\n{job.__doc__.strip()}\n\nsteps:\n{steps}\n\n"
            "Each step's own options: python -m pbc.train --help, python -m pbc.generate --help.")


def run(extra: list[str]) -> None:
    if any(a in ("-h", "--help") for a in extra):
        print(usage())
        return
    job.run_steps(extra)


main = entry_point("main", run)

if __name__ == "__main__":
    main()
