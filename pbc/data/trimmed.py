"""A dataset cut down to one split, to ship beside a model (pbc/pretrained/<name>/data/).

A shipped model must predict, be scored and flag unseen poses on a machine without its dataset, but the
whole dataset (6.6 MB of draped vertices for tshirt_small) would outweigh the weights. So it keeps the
files a predictor reads (garment.obj, cage.json, body.npz, embedding.npz), one split's poses and draped
vertices (the test split: `--poses test` and the model card's score), and of the training split only what
is asked of it: its joint-angle range (pbc.motion.ranges compares new poses with it), its mean offsets
(the training mean shape, the no-model baseline) and its poses (pbc.motion.known measures how far a new pose
is from them), in `training.json` + `mean_offsets.npy` + `known_poses.npy` (float16: 0.9 MB for 2,400 poses).

It is an ordinary dataset directory (pbc.data.dataset.load_dataset opens it): the kept split becomes its
only rows, the other splits are empty, and its manifest says what it was cut from (`trimmed_from`).
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from pbc.core.io import load_npy, read_json, save_npy, write_json
from pbc.data.dataset import SPLITS, ClothDataset, dataset_fingerprint
from pbc.geometry.body.skeleton import AXES
from pbc.motion.ranges import EULER, PoseRange

TRAINING_FILE = "training.json"
MEAN_FILE = "mean_offsets.npy"
KNOWN_FILE = "known_poses.npy"  # the training split's poses (M, J, 3, 3) float16: what the model knows
# what a predictor reads besides the arrays (pbc.data.dataset's layout)
GEOMETRY_FILES = ("garment.obj", "cage.json", "body.npz", "embedding.npz")


def range_table(rng: np.ndarray, names: Sequence[str]) -> dict:
    """(J, 3, 2) degrees -> {joint: {axis: [min, max]}}: the layout predict.json's pose_range.range_deg uses
    (pbc.motion.ranges.range_report), so a shipped range reads as a recorded one."""
    return {n: {ax: [float(rng[j, k, 0]), float(rng[j, k, 1])] for k, ax in enumerate(AXES)}
            for j, n in enumerate(names)}


def check_max_rows(max_rows, split: str = "test", name: str = "max_rows") -> None:
    """`trim_dataset`'s max_rows: None or an integer >= 1, else one ValueError saying so under `name`."""
    if max_rows is not None and (isinstance(max_rows, bool) or not isinstance(max_rows, int) or max_rows < 1):
        raise ValueError(f"{name} {max_rows!r}: give the number of {split} poses to ship, an integer >= 1")


def trim_dataset(ds: ClothDataset, out: str | Path, pose_range: PoseRange, mean_offsets: torch.Tensor | np.ndarray,
                 space: str, split: str = "test", max_rows: int | None = None) -> Path:
    """Write `ds` cut to `split` (its first `max_rows` rows; None: all) under `out` (replaced if it exists), with
    the training split's joint-angle range `pose_range` (deg (J, 3, 2)) and mean offsets (V, 3) in the models'
    `space`. Returns `out`."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; choose one of {SPLITS}")
    check_max_rows(max_rows, split)
    idx = ds.split(split)[:max_rows]
    if len(idx) == 0:
        raise ValueError(f"split {split!r} of {ds.dir} is empty: nothing to ship for scoring")
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for name in GEOMETRY_FILES:
        src = Path(ds.dir) / name
        if src.suffix == ".npz":  # the same arrays, zip-compressed: the body shrinks 0.78 -> ~0.3 MB
            with np.load(src, allow_pickle=False) as z:
                np.savez_compressed(out / name, **{k: z[k] for k in z.files})
        else:
            shutil.copy2(src, out / name)
    save_npy(out / "poses.npy", np.asarray(ds.poses[idx], np.float32))
    save_npy(out / "verts.npy", np.asarray(ds.verts[idx], np.float32))
    if getattr(ds, "shapes", None) is not None:  # several people (data.body_shape): theirs, the rows' persons
        shutil.copy2(Path(ds.dir) / "shapes.npz", out / "shapes.npz")
        save_npy(out / "person.npy", np.asarray(ds.person[idx], np.int64))
    names = list(ds.body.skeleton.names)
    mean = np.asarray(mean_offsets, np.float32)
    if mean.shape != (len(ds.garment.vertices), 3):
        raise ValueError(f"mean offsets {mean.shape}, the garment has {len(ds.garment.vertices)} vertices")
    save_npy(out / MEAN_FILE, mean)
    train = np.asarray(ds.split("train"))
    save_npy(out / KNOWN_FILE, np.asarray(ds.poses[train], np.float16))
    write_json(out / TRAINING_FILE, {
        "num_train": int(len(ds.split("train"))), "space": space, "mean_offsets": MEAN_FILE,
        "pose_range_deg": range_table(np.asarray(pose_range.deg), names), "pose_range_chart": pose_range.chart})
    manifest = dict(ds.manifest)
    src = manifest.get("source_index")
    if src and len(src) == len(ds):
        manifest["source_index"] = [src[int(i)] for i in idx]
    manifest["counts"] = dict(manifest.get("counts") or {}, kept=int(len(idx)))
    manifest["counts"].pop("mirrored", None)  # the rows kept are numbered afresh: none is a mirror row any more
    manifest.pop("mirrored", None)
    source = manifest.get("pose_source")
    if source and len(source.get("clip", ())) == len(ds):
        manifest["pose_source"] = dict(source, **{k: [source[k][int(i)] for i in idx] for k in ("clip", "frame")})
    manifest["splits"] = {s: (list(range(len(idx))) if s == split else []) for s in SPLITS}
    manifest["trimmed_from"] = {"dir": str(Path(ds.dir).resolve()), "fingerprint": dataset_fingerprint(ds),
                                "split": split, "rows": [int(i) for i in idx],
                                "splits": {s: int(len(ds.split(s))) for s in SPLITS}}
    write_json(out / "manifest.json", manifest)
    return out


def is_trimmed(ds: ClothDataset) -> bool:
    """Whether `ds` is a cut-down copy (its training split lives on only as training.json's summary)."""
    return "trimmed_from" in ds.manifest and (Path(ds.dir) / TRAINING_FILE).is_file()


def _summary(ds: ClothDataset) -> dict | None:
    return read_json(Path(ds.dir) / TRAINING_FILE, "shipped training summary") if is_trimmed(ds) else None


def recorded_training_range(ds: ClothDataset) -> PoseRange | None:
    """The training split's joint-angle range, as recorded by `trim_dataset`, in the body's joint order (a
    record without a chart is of the Euler angles); None for a full dataset (take it from its training
    poses)."""
    s = _summary(ds)
    if s is None:
        return None
    table = s["pose_range_deg"]
    names = list(ds.body.skeleton.names)
    missing = [n for n in names if n not in table]
    if missing:
        raise ValueError(f"{Path(ds.dir) / TRAINING_FILE} has no range for joints {missing}: pack the model again "
                         "(pbc pretrained pack RUN --name NAME)")
    return PoseRange(np.array([[table[n][ax] for ax in AXES] for n in names], dtype=np.float64),
                     s.get("pose_range_chart", EULER))


def recorded_known_poses(ds: ClothDataset) -> np.ndarray | None:
    """The training split's poses (M, J, 3, 3) float32 as recorded by `trim_dataset`; None for a full dataset
    (take its training split) or a cut-down copy written before it recorded them."""
    if not is_trimmed(ds) or not (Path(ds.dir) / KNOWN_FILE).is_file():
        return None
    known = load_npy(Path(ds.dir) / KNOWN_FILE, mmap=False)
    j = ds.body.skeleton.num_joints
    if known.ndim != 4 or known.shape[1:] != (j, 3, 3):
        raise ValueError(f"{Path(ds.dir) / KNOWN_FILE}: shape {known.shape}, not (M, {j}, 3, 3) for the body's "
                         f"{j} joints: pack the model again (pbc pretrained pack RUN --name NAME)")
    return np.asarray(known, np.float32)


def recorded_mean_offsets(ds: ClothDataset) -> tuple[torch.Tensor, str] | None:
    """The training split's mean offsets (V, 3) and the space they are in, as recorded by `trim_dataset`;
    None for a full dataset (average its training split)."""
    s = _summary(ds)
    if s is None:
        return None
    mean = load_npy(Path(ds.dir) / s["mean_offsets"], mmap=False, shape=(len(ds.garment.vertices), 3))
    return torch.from_numpy(np.array(mean, np.float32)), str(s["space"])
