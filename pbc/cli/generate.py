"""`pbc generate data=tshirt_small [preview=true]` (also `python -m pbc.generate`): make (or resume, or
merge) a dataset under `paths.data_dir`, with its preview figures and meshes when `preview=true`.

A refused generation leaves no trace: a dataset folder this command created is removed when it is left empty
(a refusal before any drape was written), and a folder holding a dataset made with other settings is refused
naming each setting that differs, its value there and here, and the override that goes on with it."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

from omegaconf import DictConfig

from pbc.cli.errors import entry_point, run_hydra
from pbc.data.generate import dataset_dir, generate
from pbc.data.preview import write_preview

log = logging.getLogger(__name__)


def generate_job(cfg: DictConfig) -> None:
    out = dataset_dir(cfg)
    created = not out.exists()
    try:
        out = generate(cfg)
    finally:
        if created:
            remove_if_empty(out)
    log.info("dataset ready: %s", out)
    if cfg.preview and cfg.data.shard is None:
        log.info("writing the preview figures and meshes to %s/preview", out)
        for path in write_preview(out, cfg):
            log.info("wrote %s", path)


def remove_if_empty(folder: Path) -> None:
    """Remove `folder` (one this command created) when it holds no drape: a generation refused before its first
    leaves at most an empty work/samples/ and work/fingerprint.json (its lock file is removed on release)."""
    bare = {Path("work") / "fingerprint.json"}
    if folder.is_dir() and not any((p.is_file() or p.is_symlink()) and p.relative_to(folder) not in bare
                                   for p in folder.rglob("*")):
        shutil.rmtree(folder, ignore_errors=True)


def run(args: list[str]) -> None:
    run_hydra(generate_job, args)


main = entry_point("generate", run)

if __name__ == "__main__":
    main()
