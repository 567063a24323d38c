"""`pbc train +experiment=NAME [overrides]` (also `python -m pbc.train`): train one model, test it on its
best checkpoint, write metrics.json; see pbc/jobs/train.py for what a run dir holds and how resume works.

Returns (to a Hydra sweeper) the best value of the checkpoint monitor, so Optuna can minimise it. A failed
run still writes metrics.json with "status": "failed", the error and its traceback; in a multirun the
launcher marks that job failed and runs the others.
"""

from __future__ import annotations

import logging

from omegaconf import DictConfig

from pbc.cli.errors import entry_point, run_hydra
from pbc.jobs.train import record_failure, train

log = logging.getLogger(__name__)


def train_job(cfg: DictConfig) -> float:
    try:
        metrics = train(cfg)
    except Exception as e:
        record_failure(cfg, e)
        raise
    return metrics["val_best"][metrics["optimized_metric"].split("/", 1)[1]]


def run(args: list[str]) -> None:
    run_hydra(train_job, args)


main = entry_point("train", run)

if __name__ == "__main__":
    main()
