"""A dataset that trains on fewer poses: the first n of another dataset's training split, tested as it is.

A learning curve (test error against the number of training poses) needs one model per size, each scored on
the same validation and test poses, each with the training mean shape *of its own* training poses. Every
consumer of a dataset (the datamodule, the mean-shape baseline, the recorded training pose range, the model
card) reads "the training split" from the manifest, so the one honest way to train on n poses is a dataset
whose training split is those n: this module writes one, without copying the arrays.

The subset's directory holds the source's geometry files (copied: a few MB) and links to its arrays
(poses.npy, verts.npy and the rest, read-only memory maps), and a manifest whose training split is the first
`train` rows of the source's (in the source's own, seeded, order) and, with mirrors, the mirror rows of those
(data.mirror, pbc.data.mirror); the validation and test splits are the source's. The manifest says what it
was cut from (`subset_of`), so its fingerprint differs from the source's and a run records which it saw.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from pbc.core.io import write_json
from pbc.data.dataset import SPLITS, ClothDataset, dataset_fingerprint
from pbc.data.trimmed import GEOMETRY_FILES

# the arrays a dataset may hold (pbc.data.dataset's layout): linked, never copied
ARRAY_FILES = ("poses.npy", "verts.npy", "angles.npy", "person.npy", "shapes.npz")


def originals_and_mirrors(ds: ClothDataset) -> tuple[list[int], dict[int, int]]:
    """The training split's drapes in split order, and {original row: its mirror row} (empty without
    data.mirror)."""
    mirrored = ds.manifest.get("mirrored") or {}
    mirror_of = {int(o): int(r) for r, o in zip(mirrored.get("rows", ()), mirrored.get("of", ()), strict=True)}
    mirror_rows = set(mirror_of.values())
    return [int(i) for i in ds.split("train") if int(i) not in mirror_rows], mirror_of


def subset_dataset(ds: ClothDataset, out: str | Path, train: int, mirrors: bool = True) -> Path:
    """Write a dataset under `out` (replaced if it exists) that trains on the first `train` drapes of `ds`'s
    training split and, when `mirrors` and `ds` has them, their mirror images; validated and tested on `ds`'s
    own splits. Returns `out`. Refuses a size the source cannot give and an `out` inside the source."""
    originals, mirror_of = originals_and_mirrors(ds)
    if not 1 <= int(train) <= len(originals):
        raise ValueError(f"a subset of {train} training poses: {ds.dir} has {len(originals)} "
                         f"(its training split, mirror images not counted); ask for 1..{len(originals)}")
    if mirrors and not mirror_of:
        raise ValueError(f"{ds.dir} has no mirror images to train on (it was made without data.mirror=true): "
                         "ask for mirrors=False, or regenerate it with data.mirror=true")
    src, out = Path(ds.dir).resolve(), Path(out).resolve()
    if out == src or src in out.parents:
        raise ValueError(f"the subset's directory {out} lies inside its source {src}: choose another place")
    rows = originals[: int(train)]
    train_rows = rows + ([mirror_of[i] for i in rows if i in mirror_of] if mirrors else [])
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for name in GEOMETRY_FILES:
        shutil.copy2(src / name, out / name)
    for name in ARRAY_FILES:
        if (src / name).is_file():
            os.symlink(src / name, out / name)
    manifest = dict(ds.manifest)
    manifest["splits"] = {s: (train_rows if s == "train" else [int(i) for i in ds.split(s)]) for s in SPLITS}
    manifest["subset_of"] = {"dir": str(src), "fingerprint": dataset_fingerprint(ds), "train_poses": len(rows),
                             "mirrors": bool(mirrors and mirror_of), "train_rows": len(train_rows)}
    write_json(out / "manifest.json", manifest)  # last: a directory without it is not a dataset
    return out
