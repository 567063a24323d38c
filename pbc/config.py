"""Compose the Hydra config outside an entry point (tests, notebooks, workers): same files, same overrides."""

from __future__ import annotations

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf

from pbc.paths import CONF_DIR
from pbc.runs import monitor


def register_resolvers() -> None:
    """pbc's OmegaConf resolvers: ``${pbc.monitor:${model.kind}}`` (the checkpoint monitor of a model kind,
    pbc.runs.monitor). Importing pbc.config registers them; every entry point that instantiates
    callbacks imports it."""
    OmegaConf.register_new_resolver("pbc.monitor", monitor, replace=True)


register_resolvers()


def load_config(overrides: list[str] | None = None, config_name: str = "config") -> DictConfig:
    """The root config with command-line style `overrides`, e.g. ["data=tshirt_tiny", "data.seed=3"].

    `${hydra:...}` interpolations (the run dir) only resolve inside an entry point; read those keys there.
    """
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose(config_name, overrides=list(overrides or []))
