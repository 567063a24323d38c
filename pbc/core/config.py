"""Compose the Hydra config outside an entry point (tests, notebooks, workers): same files, same overrides."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig, OmegaConf

from pbc.core.paths import CONF_DIR, resolve_path
from pbc.core.runs import monitor


def register_resolvers() -> None:
    """pbc's OmegaConf resolvers: ``${pbc.monitor:${model.kind}}`` (the checkpoint monitor of a model kind,
    pbc.core.runs.monitor). Importing pbc.core.config registers them; every entry point that instantiates
    callbacks imports it."""
    OmegaConf.register_new_resolver("pbc.monitor", monitor, replace=True)


register_resolvers()


def load_config(overrides: list[str] | None = None, config_name: str = "config") -> DictConfig:
    """The root config with command-line style `overrides`, e.g. ["data=tshirt_tiny", "data.seed=3"].

    `${hydra:...}` interpolations (the run dir) only resolve inside an entry point; read those keys there.
    """
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose(config_name, overrides=list(overrides or []))


def load_garment_config(garment_yaml, image_yaml=None):
    """The garment config node from its YAML file, its ``${image.*}`` keys filled from the image config
    (default: conf/image/default.yaml next to it). For scripts and tests outside a Hydra run."""
    garment_yaml = resolve_path(garment_yaml)
    if image_yaml is None:
        image_yaml = garment_yaml.parents[1] / "image" / "default.yaml"
    image_yaml = resolve_path(image_yaml)
    root = OmegaConf.create({"garment": _load_with_defaults(garment_yaml), "image": OmegaConf.load(image_yaml)})
    return root.garment


def _load_with_defaults(path):
    """A config file merged over the sibling files its ``defaults:`` list names (as Hydra composes a group
    option that inherits from another, e.g. tshirt_coarse.yaml over tshirt.yaml)."""
    node = OmegaConf.load(path)
    defaults = list(node.pop("defaults", None) or [])
    if "_self_" not in defaults:
        defaults.append("_self_")
    parts = [node if d == "_self_" else _load_with_defaults(Path(path).parent / f"{d}.yaml") for d in defaults]
    return OmegaConf.merge(*parts)
