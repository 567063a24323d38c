"""Compose the Hydra config outside an entry point (tests, notebooks, workers): same files, same overrides."""

from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import DictConfig, OmegaConf

from pbc.core.paths import CONF_DIR, corpus_dir, resolve_path
from pbc.core.runs import monitor
from pbc.core.validate import suggest_config_key


def register_resolvers() -> None:
    """pbc's OmegaConf resolvers: ``${pbc.monitor:${model.kind}}`` (the checkpoint monitor of a model kind,
    pbc.core.runs.monitor) and ``${pbc.corpus:}`` (the real-world corpus, pbc.core.paths.corpus_dir).
    Importing pbc.core.config registers them; every entry point that instantiates callbacks imports it."""
    OmegaConf.register_new_resolver("pbc.monitor", monitor, replace=True)
    OmegaConf.register_new_resolver("pbc.corpus", lambda: str(corpus_dir()), replace=True)


register_resolvers()


def load_config(overrides: list[str] | None = None, config_name: str = "config") -> DictConfig:
    """The root config with command-line style `overrides`, e.g. ["data=tshirt_tiny", "data.seed=3"].

    A mistyped key (`body.phenotype.hight=0.5`) is a ValueError naming the key meant ("did you mean
    body.phenotype.height?", `override_hint`), not Hydra's advice to add it with "+".
    `${hydra:...}` interpolations (the run dir) only resolve inside an entry point; read those keys there.
    """
    overrides = list(overrides or [])
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
            return compose(config_name, overrides=overrides)
    except ConfigCompositionException as exc:
        hint = override_hint(str(exc), overrides, config_name)
        if hint is None:
            raise
        raise ValueError(hint) from exc


def override_hint(message: str, overrides: list[str], config_name: str = "config") -> str | None:
    """For Hydra's error on a mistyped override (`trainer.max_epoch=3`): the key meant, from the config the
    other overrides compose (pbc.core.validate.suggest_config_key); None when that is not the error."""
    key = message.split("'")[1] if message.startswith("Could not override '") else None
    if key is None:
        return suggest_config_key(message)
    if (CONF_DIR / key.lstrip("+~").replace(".", "/")).is_dir():
        return None  # a config group outside the defaults (scale=paper): Hydra's "+scale=paper" is the fix
    others = [a for a in overrides if "=" in a and not a.lstrip("+~").startswith(key + "=")
              and not a.startswith(("hydra.", "hydra/", "-"))]
    try:
        cfg = load_config(others, config_name=config_name)
    except Exception:  # another override is wrong too: judge this one without a config
        cfg = None
    return suggest_config_key(message, cfg)


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
