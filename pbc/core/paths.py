"""Where pbc's shipped files live: `conf/` (the Hydra configs) and `patches/` (the committed cages).

A source checkout (and the editable install `make venv` makes) keeps them at the top of the repository,
the layout users edit; a wheel ships the same files inside the package (pyproject.toml maps them to
`pbc/conf` and `pbc/patches`), so an installed pbc runs every command from any directory. Everything that
reads a shipped file asks here, so the two layouts never disagree.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # pbc/ (this file is pbc/core/paths.py)


def _shipped(name: str) -> Path:
    source = PACKAGE_DIR.parent / name  # the checkout's own copy wins: it is the one being edited
    return source if source.is_dir() else PACKAGE_DIR / name


CONF_DIR = _shipped("conf")
PATCHES_DIR = _shipped("patches")
# the folder shipped relative paths in configs (e.g. `garment.cage: patches/tshirt.json`) are read against
SHIPPED_ROOT = PATCHES_DIR.parent


def resolve_path(path: str | os.PathLike) -> Path:
    """A path from a config: as given when it exists or is absolute, else one of pbc's shipped files
    (`patches/...`, `conf/...`) wherever this install keeps them."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    if p.parts and p.parts[0] == "conf":
        return CONF_DIR.joinpath(*p.parts[1:])
    return SHIPPED_ROOT / p


def corpus_dir() -> Path:
    """The real-world corpus (motion clips and garments as other tools wrote them): $PBC_CORPUS, else
    `../shared/corpus` beside the checkout."""
    return Path(os.environ.get("PBC_CORPUS") or SHIPPED_ROOT.parent / "shared" / "corpus")
