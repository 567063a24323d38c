"""Pretrained models by name: the ones shipped inside pbc, so prediction, motion and the viewer work on a fresh
clone (or a wheel install) without training, and the user's own, packed from their runs:
`pbc predict --pretrained tshirt`, `ClothPredictor.from_pretrained("tshirt")`.

Each model is a folder laid out as a training run dir, so every reader of runs opens it unchanged: metrics.json
(a pbc.core.runs.RunRecord whose data record points at its own data/ folder, relative to the run, and whose
pose_range is the training poses' joint-angle range), checkpoints/weights_fp16.ckpt (the network's state dict
in half precision), data/ (the dataset cut to its test split plus the training split's range and mean offsets:
pbc.data.trimmed) and MODEL_CARD.md (what it was trained on, how, and its scores).

Two places hold them. The shipped models are pbc/pretrained/<name>/ (SHIPPED_DIR), read-only to pbc: only a
reinstall (or git, in a clone) brings one back. The user's models are <user_models_dir()>/<name>/, outside the
package: `pbc pretrained pack` (pbc.pretrained.pack) writes there, and a user model shadows a shipped one of
the same name. This module only finds them: it imports nothing of pbc.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

SHIPPED_DIR = Path(__file__).resolve().parent
# a name given as `--pretrained NAME` or `whole_run=pretrained:NAME`
PREFIX = "pretrained:"
# the user's models folder, in the order looked at: this variable; else `models` under $PBC_ROOT (where runs/ and
# data/ go) when it is set; else pbc's folder in the user's data dir ($XDG_DATA_HOME, else ~/.local/share)
MODELS_ENV = "PBC_MODELS"
ROOT_ENV = "PBC_ROOT"
MODELS_FOLDER = "models"
# a model's name: letters, digits, - and _ (so a kept copy, NAME.previous-<time>, or a half-written .NAME.* is none)
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]+")
SHIPPED, USER = "shipped", "yours"


@dataclass(frozen=True)
class PretrainedModel:
    """One model found by name: where it lives (`kind`: SHIPPED or USER), and whether a model of the same name
    in the other place hides it (`shadowed`: a shipped one under the user's) or is hidden by it (`shadows`)."""

    name: str
    kind: str
    path: Path
    shadows: bool = False
    shadowed: bool = False


def is_model_name(name) -> bool:
    """True for a string a model may be named: letters, digits, - and _ only."""
    return isinstance(name, str) and NAME_PATTERN.fullmatch(name) is not None


def user_models_dir() -> Path:
    """The folder of the user's models: $PBC_MODELS, else $PBC_ROOT/models when PBC_ROOT is set, else
    $XDG_DATA_HOME/pbc/models, else ~/.local/share/pbc/models. It need not exist."""
    if os.environ.get(MODELS_ENV):
        return Path(os.environ[MODELS_ENV]).expanduser()
    if os.environ.get(ROOT_ENV):
        return Path(os.environ[ROOT_ENV]).expanduser() / MODELS_FOLDER
    data = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
    return Path(data) / "pbc" / MODELS_FOLDER


def models_in(folder: str | os.PathLike) -> list[str]:
    """The names of the models in `folder` (sub-folders with a model name holding a metrics.json), sorted; none
    for a folder that does not exist."""
    return sorted(p.parent.name for p in Path(folder).glob("*/metrics.json") if is_model_name(p.parent.name))


def shipped_models() -> list[str]:
    """The names of the models shipped with this pbc, sorted."""
    return models_in(SHIPPED_DIR)


def shipped_model_dir(name: str) -> Path:
    """The folder of the model shipped with pbc as `name` (SHIPPED_DIR/<name>), whether pbc ships it or not."""
    return SHIPPED_DIR / name


def user_models() -> list[str]:
    """The names of the user's models (in user_models_dir()), sorted."""
    return models_in(user_models_dir())


def all_models() -> list[PretrainedModel]:
    """Every model `--pretrained NAME` can name, by name, the user's before the shipped one of the same name."""
    shipped, user = set(shipped_models()), set(user_models())
    models = [PretrainedModel(n, USER, user_models_dir() / n, shadows=n in shipped) for n in user]
    models += [PretrainedModel(n, SHIPPED, shipped_model_dir(n), shadowed=n in user) for n in shipped]
    return sorted(models, key=lambda m: (m.name, m.kind != USER))


def unknown_model_message(name, shipped: list[str], user: list[str], user_dir: Path) -> str:
    """The refusal of a name no model has, listing the shipped models and the user's (and where those live)."""
    return (f"no pretrained model named {name!r}: pbc ships {', '.join(shipped) or 'none'}; your models folder "
            f"({user_dir}) holds {', '.join(user) or 'none'} (give one of those, or a trained run dir instead)")


def pretrained_dir(name: str) -> Path:
    """The run dir of model `name`: the user's (user_models_dir()/name), which shadows a shipped model of that
    name, else the shipped one; a ValueError listing both kinds for any other name."""
    user, shipped = user_models(), shipped_models()
    if is_model_name(name) and name in user:
        return user_models_dir() / name
    if is_model_name(name) and name in shipped:
        return shipped_model_dir(name)
    raise ValueError(unknown_model_message(name, shipped, user, user_models_dir()))


def resolve_run(run):
    """`run` as a run dir: "pretrained:NAME" -> the model's folder (pretrained_dir); anything else unchanged."""
    if isinstance(run, str) and run.startswith(PREFIX):
        return pretrained_dir(run[len(PREFIX):])
    return run


def shipped_model_of(path) -> str | None:
    """The name of the shipped model whose folder holds `path` (a file or dir), None for any other path."""
    try:
        rel = Path(path).resolve().relative_to(SHIPPED_DIR)
    except ValueError:
        return None
    return rel.parts[0] if rel.parts and (SHIPPED_DIR / rel.parts[0] / "metrics.json").is_file() else None


def in_shipped_dir(path: str | os.PathLike) -> bool:
    """True when `path` is pbc's folder of shipped models or anything inside it."""
    resolved = Path(path).resolve()
    return resolved == SHIPPED_DIR or SHIPPED_DIR in resolved.parents


def repair_advice(name: str) -> str:
    """How to get a damaged shipped model back: it has no other checkpoint to fall back on, and no run to retrain."""
    return (f"it belongs to the model {name!r} shipped with pbc, damaged on disk: reinstall pbc (pip install "
            f"--force-reinstall pbc; in a clone, git checkout -- pbc/pretrained/{name}) or pack it again from its "
            f"training run as your own, which shadows it (pbc pretrained pack RUN --name {name} --force)")
