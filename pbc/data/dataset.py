"""Read a finished dataset directory (written by `pbc.data.generate`): memory-mapped arrays plus geometry.

Layout (see docs/interfaces.md):
    manifest.json   format version, seed, hashes, counts, splits
    garment.obj     garment with UV charts;  cage.json  its cage (28 patches on the T-shirt)
    body.npz        body mesh, skinning weights, parts, skeleton
    embedding.npz   body triangle + barycentric weights + collision part of every garment vertex
    poses.npy       (N, J, 3, 3) float32 joint rotations of the kept samples
    verts.npy       (N, V, 3) float32 draped garment vertices (root frame, metres)
  N = counts.kept, plus counts.mirrored rows at the end with `data.mirror` (the mirror images of the training
  rows listed in manifest "mirrored", pbc.data.mirror); with `data.poses` the manifest's "pose_source" holds
  each row's clip (-1: the D.3 sampler) and frame (pbc.data.mocap)
  a dataset of several people (`data.body_shape`, pbc.data.shapes) also has
    shapes.npz      phenotype keys (P,), values (K, P), rest vertices (K, Vb, 3), rest heads (K, J, 3)
    person.npy      (N,) int64 the person each kept sample is draped on
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pbc.core.io import atomic_path, load_npy, load_npz, read_json
from pbc.core.validate import ROTATION_TOL, identity_diff, rotation_errors
from pbc.data.shapes import BodyShapes, load_shapes, person_body
from pbc.geometry.body.base import Body, load_body
from pbc.geometry.cage.base import Cage, load_cage
from pbc.geometry.garment.base import Garment, load_garment_obj
from pbc.geometry.shrinkwrap import Embedding

FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")


@dataclass
class ClothDataset:
    """A dataset on disk. Arrays are memory-mapped: indexing them reads only what is used."""

    dir: Path
    manifest: dict
    poses: np.ndarray  # (N, J, 3, 3)
    verts: np.ndarray  # (N, V, 3)
    garment: Garment
    cage: Cage
    body: Body
    embedding: Embedding
    # a dataset of several people (`data.body_shape`): the people and each sample's person (N,); else None
    shapes: BodyShapes | None = None
    person: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.poses)

    def person_body(self, k: int | None = None) -> Body:
        """The Body of person k (None: the base person, body.npz). Refused on a single-body dataset."""
        if k is None:
            return self.body
        if self.shapes is None:
            raise ValueError(f"dataset {self.dir} has one body (made without data.body_shape): no person {k}")
        return person_body(self.body, self.shapes, int(k))

    def person_kw(self, rows) -> dict:
        """The keyword a Skinner call takes for sample rows `rows` (module function `person_kw`)."""
        return person_kw(self, rows)

    def split(self, name: str) -> np.ndarray:
        """Sample indices of split `name` ('train', 'val' or 'test')."""
        if name not in SPLITS:
            raise ValueError(f"unknown split {name!r}; choose one of {SPLITS}")
        return np.asarray(self.manifest["splits"][name], dtype=np.int64)


def num_rows(manifest: dict) -> int:
    """Rows of a dataset's arrays: its kept drapes, then the mirror images of its training rows (data.mirror)."""
    counts = manifest["counts"]
    return int(counts["kept"]) + int(counts.get("mirrored", 0))


def person_kw(data, rows) -> dict:
    """The keyword a Skinner call takes for sample rows `rows` (B,) of `data`: {} for one body (or a stand-in
    dataset without people), {"person": (B,) long} for a dataset of several people, so that each sample is
    skinned on its own person."""
    person = getattr(data, "person", None)
    if person is None:
        return {}
    return {"person": torch.from_numpy(np.asarray(person[np.asarray(rows)], np.int64))}


def save_embedding(emb: Embedding, path: str | Path) -> None:
    """Write the embedding to .npz, atomically."""
    with atomic_path(path, suffix=".npz") as tmp:
        lift = {} if emb.lift is None else {"lift": emb.lift.numpy()}  # only layered garments have one
        np.savez(tmp, face=emb.face.numpy(), bary=emb.bary.numpy(), part=emb.part.numpy(), **lift)


def load_embedding(path: str | Path) -> Embedding:
    """Read an embedding written by `save_embedding`, with a clear error when missing or corrupt."""
    z = load_npz(path, ("face", "bary", "part"), "embedding", "regenerate the dataset")
    z["lift"] = load_npz(path, None, "embedding", "regenerate the dataset").get("lift")  # a layered garment's
    return Embedding(
        face=torch.from_numpy(z["face"]).long(),
        bary=torch.from_numpy(z["bary"]).float(),
        part=torch.from_numpy(z["part"]).long(),
        lift=torch.from_numpy(z["lift"]).float() if z["lift"] is not None else None,
    )


def load_dataset(directory: str | Path, check: bool = True) -> ClothDataset:
    """Open the dataset in `directory`, checking it is complete and self-consistent.

    check: also read every sample once (`check_dataset`: finite, rotations, vertices near the body), so a
    bad sample is named when the dataset opens, not blamed on another one epochs later. Once per process
    per dataset file version.
    """
    d = Path(directory)
    manifest_path = d / "manifest.json"
    if not manifest_path.is_file():
        if (d / "work").exists():
            hint = "generation is unfinished: re-run the same `pbc generate ...` to resume"
        else:  # say where data is looked for: a command run outside the project dir finds none
            hint = (f"make it with `pbc generate data=...` (data is looked for under paths.data_dir, "
                    f"$PBC_ROOT/data or ./data; this one resolves to {d.resolve()})")
        raise FileNotFoundError(f"no dataset at {d}: {manifest_path.name} is missing; {hint}")
    manifest = read_json(manifest_path, "dataset manifest")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise ValueError(
            f"dataset {d} has format version {manifest.get('format_version')}, this pbc reads {FORMAT_VERSION}; "
            "regenerate it with `python -m pbc.generate`"
        )
    garment = load_garment_obj(d / "garment.obj")
    cage = load_cage(d / "cage.json", garment)
    body = load_body(d / "body.npz")
    emb = load_embedding(d / "embedding.npz")
    n, v, j = num_rows(manifest), garment.vertices.shape[0], len(body.skeleton.names)
    poses = load_npy(d / "poses.npy", shape=(n, j, 3, 3))
    verts = load_npy(d / "verts.npy", shape=(n, v, 3))
    if emb.face.shape[0] != v:
        raise ValueError(f"embedding in {d} has {emb.face.shape[0]} vertices, the garment {v}; regenerate the dataset")
    shapes = person = None
    if manifest.get("body_shapes") is not None:
        shapes = load_shapes(d / "shapes.npz")
        person = load_npy(d / "person.npy", shape=(n,))
        if shapes.vertices.shape[1:] != body.vertices.shape or (len(person) and not (
                0 <= int(person.min()) and int(person.max()) < len(shapes))):
            raise ValueError(f"{d}: shapes.npz / person.npy do not fit its body or its {len(shapes)} people; "
                             "regenerate the dataset")
    data = ClothDataset(d, manifest, poses, verts, garment, cage, body, emb, shapes, person)
    if check:
        check_dataset(data)
    return data


# ----------------------------------------------------------------------------------------- whole-data check
# A draped shirt hangs within centimetres of the body, and skinning moves body points along rigid bone
# chains, so no garment vertex can be much further from the root than the rest body's farthest point.
# 1.5x leaves room for loose cloth and refuses centimetre-scaled, exploded or garbage rows by far.
PLAUSIBLE_REACH = 1.5
CHUNK_BYTES = 64 << 20  # rows read per step: bounded memory on paper-scale memory-mapped arrays

_CHECKED: dict[tuple, None] = {}  # dataset file versions already checked in this process


def bad_samples(poses: np.ndarray, verts: np.ndarray, radius: float, tol: float = ROTATION_TOL,
                chunk_bytes: int = CHUNK_BYTES) -> dict[str, np.ndarray]:
    """Row ids of samples that cannot be right, vectorised over chunks of rows.

    poses (N, J, 3, 3), verts (N, V, 3) (memory-mapped is fine: each row is read once), `radius` metres:
    a vertex with any coordinate beyond it (root frame) is implausible. Returns {problem: sorted row ids}
    for the problems found: "pose not finite", "pose not a rotation", "vertices not finite", "vertices beyond reach".
    """
    n = len(poses)
    if len(verts) != n:
        raise ValueError(f"poses has {n} rows, verts {len(verts)}")
    found: dict[str, list[np.ndarray]] = {}

    def add(name: str, mask: np.ndarray, start: int) -> None:
        if mask.any():
            found.setdefault(name, []).append(np.flatnonzero(mask) + start)

    row_bytes = max(1, verts[0].nbytes if n else 1)
    step = max(1, chunk_bytes // row_bytes)
    for a in range(0, n, step):
        p = np.asarray(poses[a : a + step], np.float32)
        v = np.asarray(verts[a : a + step], np.float32)
        p_fin = np.isfinite(p).reshape(len(p), -1).all(1)
        add("pose not finite", ~p_fin, a)
        ortho, det = rotation_errors(torch.from_numpy(np.where(np.isfinite(p), p, 0)))
        add("pose not a rotation", p_fin & ((ortho > tol) | (det > tol)).any(1).numpy(), a)
        # per-row max and min: NaN and inf propagate into them, and they bound every coordinate, so two
        # streaming passes give finiteness and a box of half-width `radius` (3.5x faster than the norms)
        flat = v.reshape(len(v), -1)
        hi, lo = (flat.max(1), flat.min(1)) if flat.shape[1] else (np.zeros(len(v)), np.zeros(len(v)))
        v_fin = np.isfinite(hi) & np.isfinite(lo)
        add("vertices not finite", ~v_fin, a)
        with np.errstate(invalid="ignore"):
            add("vertices beyond reach", v_fin & (np.maximum(hi, -lo) > radius), a)
    return {k: np.concatenate(ids) for k, ids in found.items()}


def _file_version(d: Path) -> tuple:
    return (str(d.resolve()),) + tuple(
        (st.st_size, st.st_mtime_ns) for st in (os.stat(d / f) for f in ("poses.npy", "verts.npy", "manifest.json"))
    )


def check_dataset(data: ClothDataset, force: bool = False) -> None:
    """Read every sample once; one ValueError naming the bad sample ids and the fix.

    Checked: poses finite and rotations (pbc.core.validate.ROTATION_TOL), vertices finite and every coordinate
    within PLAUSIBLE_REACH x the rest body's farthest point from the root. Skipped when this process already
    checked the same files (same size and mtime), unless `force`.
    """
    key = _file_version(Path(data.dir))
    if key in _CHECKED and not force:
        return
    radius = PLAUSIBLE_REACH * float(data.body.vertices.norm(dim=-1).max())
    bad = bad_samples(data.poses, data.verts, radius)
    if bad:
        src = data.manifest.get("source_index")
        lines = []
        for what, ids in bad.items():
            more = f" ... ({len(ids)} in all)" if len(ids) > 10 else ""
            gen = f" (generation samples {[int(src[i]) for i in ids[:10]]})" if src and len(src) == len(data) else ""
            lines.append(f"{what}: rows {ids[:10].tolist()}{more}{gen}")
        raise ValueError(
            f"dataset {data.dir} holds bad samples (reach limit {radius:.2f} m from the root):\n  - "
            + "\n  - ".join(lines)
            + f"\nThe arrays are corrupt or the drape diverged: delete {data.dir} and regenerate it with "
            "`python -m pbc.generate` (same overrides)."
        )
    _CHECKED[key] = None


# ----------------------------------------------------------------------------------------- fingerprints
# What makes two datasets the same data (the generation fingerprint of pbc.data.generate.fingerprint)
FINGERPRINT_KEYS = ("format_version", "seed", "num_samples", "garment_hash", "body_hash", "embedding_hash", "sim")


def dataset_fingerprint(data: ClothDataset) -> dict:
    """What identifies a dataset's content, independent of where it lives: the generation fingerprint
    (seed, sample count, garment/body/embedding hashes, sim settings), the kept count and a hash of the
    manifest file (splits, source indices, stats). Equal fingerprints = the same arrays (generation is
    deterministic). JSON-able; store it in a run (`run_data_record`), compare with `fingerprint_diff`."""
    fp: dict[str, Any] = {k: data.manifest.get(k) for k in FINGERPRINT_KEYS}
    if data.manifest.get("body_shapes") is not None:  # only then: single-body fingerprints stay as they were
        fp["body_shapes"] = data.manifest["body_shapes"]
    fp["kept"] = int(data.manifest.get("counts", {}).get("kept", len(data)))
    fp["manifest_hash"] = hashlib.sha256((Path(data.dir) / "manifest.json").read_bytes()).hexdigest()[:16]
    return fp


def run_data_record(data: ClothDataset) -> dict:
    """What a run writes about its data (metrics.json "data", the checkpoint's hyper-parameters): the
    resolved directory (no ${oc.env:...} left to re-resolve in another shell) and the fingerprint."""
    return {"dir": str(Path(data.dir).resolve()), "fingerprint": dataset_fingerprint(data)}


def fingerprint_diff(recorded: Mapping, current: Mapping) -> list[str]:
    """Differing fingerprint keys, one readable line each (empty: the same data)."""
    return identity_diff(recorded, current, names=("recorded", "found"))


def open_recorded_dataset(record: Mapping, directory: str | Path | None = None, check: bool = True) -> ClothDataset:
    """The dataset a run was trained on: `record` = run_data_record(...) read back from the run.

    `directory` overrides where to look (a moved copy); by default the recorded resolved dir. Refuses a
    dataset whose fingerprint differs, printing both fingerprints' differences and the fix.
    """
    d = Path(directory if directory is not None else record["dir"])
    if not (d / "manifest.json").is_file():
        raise FileNotFoundError(
            f"the run's dataset is not at {d}: {d / 'manifest.json'} is missing; copy the dataset there, or pass "
            "the directory of a copy (data.dir=...), or regenerate it with the run's config (`python -m pbc.generate`)"
        )
    data = load_dataset(d, check=check)
    diff = fingerprint_diff(record["fingerprint"], dataset_fingerprint(data))
    if diff:
        raise ValueError(
            f"dataset {d} is not the data the run was trained on:\n  - " + "\n  - ".join(diff)
            + f"\nPoint data.dir at the run's dataset (recorded at {record['dir']}) or regenerate it with the run's "
            "config; scoring on other data would be silently wrong."
        )
    return data
