"""`pbc train +experiment=NAME [overrides]` (also `python -m pbc.train`): train one model, test it on its
best checkpoint, write metrics.json; see pbc/jobs/train.py for what a run dir holds and how resume works.

Returns (to a Hydra sweeper) the best value of the checkpoint monitor, so Optuna can minimise it. A failed
run still writes metrics.json with "status": "failed", the error and its traceback; in a multirun the
launcher marks that job failed and runs the others.
"""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from pbc.cli.errors import entry_point, run_hydra
from pbc.core import stops
from pbc.core.io import write_text
from pbc.jobs.train import output_dir, record_failure, train

log = logging.getLogger(__name__)


# Hydra writes .hydra/ into the run dir before the job runs, so a job refused there (the dir in use, holding a
# finished training, another dataset) would overwrite that run's config; pbc writes it once the door is passed
HYDRA_SUBDIR = ".hydra"
# the overrides pbc adds to the user's (after them: they win): Hydra writes no .hydra/ of its own
OWN_OVERRIDES = ("hydra.output_subdir=null",)


def write_hydra_files(cfg: DictConfig, out: Path) -> None:
    """`<out>/.hydra/{config,hydra,overrides}.yaml` as Hydra writes them (unresolved), each atomically."""
    hydra_cfg = HydraConfig.get()
    files = {"config.yaml": cfg, "hydra.yaml": OmegaConf.create({"hydra": hydra_cfg}),
             "overrides.yaml": hydra_cfg.overrides.task}
    for name, node in files.items():
        write_text(Path(out) / HYDRA_SUBDIR / name, OmegaConf.to_yaml(node))


def resume_note(out: Path) -> str:
    """How a stopped training goes on: from its last.ckpt (Lightning writes it at the step a SIGTERM reached)."""
    last = Path(out) / "checkpoints" / "last.ckpt"
    if last.is_file():
        return f"with ckpt_path=last added: it resumes from {last}"
    return "no checkpoint was written yet: the same command starts it again"


def train_job(cfg: DictConfig) -> float:
    out = output_dir(cfg)
    try:
        with stops.step(f"the training in {out}", lambda: resume_note(out)):
            metrics = train(cfg, past_the_door=lambda out: write_hydra_files(cfg, out))
    except Exception as e:
        record_failure(cfg, e)
        raise
    return metrics["val_best"][metrics["optimized_metric"].split("/", 1)[1]]


def run(args: list[str]) -> None:
    run_hydra(train_job, args, own_overrides=OWN_OVERRIDES)


main = entry_point("train", run)

if __name__ == "__main__":
    main()
