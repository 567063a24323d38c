"""Models shipped inside pbc, so prediction, motion and the viewer work on a fresh clone (or a wheel
install) without training: `pbc predict --pretrained tshirt`, `ClothPredictor.from_pretrained("tshirt")`.

Each shipped model is a folder here (pbc/pretrained/<name>/) laid out as a training run dir, so every
reader of runs opens it unchanged: metrics.json (a pbc.core.runs.RunRecord whose data record points at its own
data/ folder, relative to the run, and whose pose_range is the training poses' joint-angle range),
checkpoints/weights_fp16.ckpt (the network's state dict in half precision), data/ (the dataset cut to its
test split plus the training split's range and mean offsets: pbc.data.trimmed) and MODEL_CARD.md (what it
was trained on, how, and its scores). `pbc pretrained pack` (pbc.pretrained.pack) makes one from a run.
This module only finds them: it imports nothing of pbc.
"""

from __future__ import annotations

from pathlib import Path

SHIPPED_DIR = Path(__file__).resolve().parent
# a name given as `--pretrained NAME` or `whole_run=pretrained:NAME`
PREFIX = "pretrained:"


def shipped_models() -> list[str]:
    """The names of the models shipped with this pbc (folders holding a metrics.json), sorted."""
    return sorted(p.parent.name for p in SHIPPED_DIR.glob("*/metrics.json"))


def pretrained_dir(name: str) -> Path:
    """The run dir of shipped model `name`; a ValueError listing the shipped ones for any other name."""
    names = shipped_models()
    if not isinstance(name, str) or name not in names:
        raise ValueError(f"no shipped model named {name!r}; pbc ships {', '.join(names) or 'none'} "
                         "(give one of those, or a trained run dir instead)")
    return SHIPPED_DIR / name


def resolve_run(run):
    """`run` as a run dir: "pretrained:NAME" -> the shipped model's folder; anything else unchanged."""
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


def repair_advice(name: str) -> str:
    """How to get a damaged shipped model back: it has no other checkpoint to fall back on, and no run to retrain."""
    return (f"it belongs to the model {name!r} shipped with pbc, damaged on disk: reinstall pbc (pip install "
            f"--force-reinstall pbc; in a clone, git checkout -- pbc/pretrained/{name}) or pack it again from its "
            f"training run (pbc pretrained pack RUN --name {name})")
