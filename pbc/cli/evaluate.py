"""`pbc evaluate [whole_run=... patch_runs=... stitch.method=...]` (also `python -m pbc.evaluate`): the whole
model and the stitched patch models on one dataset split (conf/evaluate.yaml), as tables, figures and
meshes in the run dir. Returns (to a sweeper) the vertex error of the model it compared best."""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from pbc.cli.errors import entry_point, run_hydra
from pbc.core.io import naming_full_disk
from pbc.core.validate import check_config
from pbc.jobs.evaluate import evaluate, markdown_table

log = logging.getLogger(__name__)


def evaluate_job(cfg: DictConfig) -> float:
    check_config(cfg)
    out = Path(HydraConfig.get().runtime.output_dir)
    with naming_full_disk(out, "evaluation dir", "free space there or give the evaluation another folder "
                          "(hydra.run.dir=...); every file written is whole (written, then renamed)"):
        metrics = evaluate(cfg, out)
    log.info("\n%s", markdown_table(metrics))
    best = f"patches_{cfg.stitch.method}" if metrics["patch_runs"] is not None else "whole"
    return metrics["entries"].get(best, {}).get("vertex_error_cm", float("nan"))


def run(args: list[str]) -> None:
    run_hydra(evaluate_job, args, config_name="evaluate")


main = entry_point("evaluate", run)

if __name__ == "__main__":
    main()
