"""`pbc generate data=tshirt_small [preview=true]` (also `python -m pbc.generate`): make (or resume, or
merge) a dataset under `paths.data_dir`, with its preview figures and meshes when `preview=true`."""

from __future__ import annotations

import logging

from omegaconf import DictConfig

from pbc.cli.errors import entry_point, run_hydra
from pbc.data.generate import generate
from pbc.data.preview import write_preview

log = logging.getLogger(__name__)


def generate_job(cfg: DictConfig) -> None:
    out = generate(cfg)
    log.info("dataset ready: %s", out)
    if cfg.preview and cfg.data.shard is None:
        log.info("writing the preview figures and meshes to %s/preview", out)
        for path in write_preview(out, cfg):
            log.info("wrote %s", path)


def run(args: list[str]) -> None:
    run_hydra(generate_job, args)


main = entry_point("generate", run)

if __name__ == "__main__":
    main()
