"""`python -m pbc.generate data=tshirt_small [preview=true]`: make (or resume, or merge) a dataset."""

from __future__ import annotations

import logging

import hydra
from omegaconf import DictConfig

log = logging.getLogger(__name__)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from pbc.data.generate import generate

    out = generate(cfg)
    log.info("dataset ready: %s", out)
    if cfg.preview and cfg.data.shard is None:
        from pbc.data.preview import write_preview

        log.info("writing the preview figures and meshes to %s/preview", out)
        for path in write_preview(out, cfg):
            log.info("wrote %s", path)


if __name__ == "__main__":
    main()
