"""The Lightning DataModule: serves (pose, draped vertices) from a dataset directory and renders cloth
images per batch, on the batch's device.

One job: turn a dataset directory into train/val/test batches. Only per-vertex data is read from disk
(memory-mapped); targets are made in `on_after_batch_transfer` by the run's cloth target
(`pbc.pixels.target`, `dm.target`), never written to disk: with `cache_targets` (the default) every
sample's targets are rendered once on the training device and looked up per batch; without, rendered
per batch. It only reads: a missing dataset is an error that
says how to make it (`python -m pbc.generate`; `python -m pbc.train` makes it first when missing).

Batch dict (B = batch size, V garment vertices, H = W = image.whole_resolution, S = crop size):
    pose     (B, 90)          float32  10 joint rotations, row-major 3x3, joint order of conf/body
    verts    (B, V, 3)        float32  draped garment vertices (root frame, metres): metrics ground truth
    index    (B,)             int64    sample index in the dataset arrays
    person   (B,)             int64    the sample's person (only in a dataset of several, `data.body_shape`)
  added on the device by `dm.target.render` when `render` is true (the default):
    anchors  (B, V, 3)        float32  skinned cloth pixels (embedded points on the posed body)
    frames   (B, V, 3, 3)     float32  their local frames, rows (t, b, n)
    offsets  (B, V, 3)        float32  `verts` in `space` (local (du,dv,dn) | root | position)
    target=whole:
      image  (B, 6, H, W)     float32  front (du,dv,dn) then back; zero outside the padded charts
      mask   (1, 6, H, W)     float32  padded chart mask (eq. 1's W), broadcast over the batch
    target=patch (patch_id k):
      image  (B, 3, S, S)     float32  crop of patch k's side of the patch_resolution image
      mask   (1, 3, S, S)     float32  patch k's pixels dilated by `margin`, inside the padded chart
      vertices (Vk,)          int64    garment vertex ids of patch k
    target=fc: no image (the per-vertex baselines)
  added from the target cache (`cache_targets`, the default) besides the above:
    normals  (B, V, 3)        float32  ground-truth unit vertex normals of `verts` (the normal loss's n_gt)
`dm.target.positions(pred, batch)` maps a prediction back to 3D; `dm.target.values(pred)` to offsets.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from pbc.data.dataset import ClothDataset, load_dataset, person_kw
from pbc.pixels.frames import SPACES
from pbc.pixels.target import KINDS, TargetCache, VertexTarget, build_cache, make_target

log = logging.getLogger(__name__)
TARGETS = KINDS
CACHE_DTYPES = {"float32": torch.float32, "float16": torch.float16, "bfloat16": torch.bfloat16}


class PoseVerts(Dataset):
    """Samples `indices` of a dataset: pose (90,), verts (V, 3), index. Reads only the rows it serves."""

    def __init__(self, data: ClothDataset, indices: np.ndarray):
        self.poses, self.verts, self.indices = data.poses, data.verts, np.asarray(indices, np.int64)
        # (N,) or None: one body, and no `person` key (the single-body batch)
        self.person = getattr(data, "person", None)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        k = int(self.indices[i])
        item = {
            "pose": torch.from_numpy(np.array(self.poses[k], np.float32).reshape(-1)),
            "verts": torch.from_numpy(np.array(self.verts[k], np.float32)),
            "index": torch.tensor(k),
        }
        if self.person is not None:
            item["person"] = torch.tensor(int(self.person[k]))
        return item


class ClothDataModule(L.LightningDataModule):
    """Hydra-configured DataModule (conf/datamodule/default.yaml); see the module docstring for batches.

    Args:
        data_dir: the dataset directory (written by `python -m pbc.generate`).
        image: the `image` config node (resolutions, crop_size, margin, pad, exact_sample, method).
        target: what is served, the model's kind: "whole" (6-channel images), "patch" (one patch's crop)
            or "fc" (per-vertex offsets only).
        patch_id: the patch for target=patch (0 .. number of patches - 1).
        space: offset space of the targets ("local", "root", "position").
        batch_size, num_workers, pin_memory: DataLoader settings.
        render: render targets in `on_after_batch_transfer` (False: only pose/verts/index).
        cache_targets: render every sample's targets once, on the device of the first batch, and look
            them up per batch (`pbc.pixels.target.TargetCache`); same values as rendering per batch.
            Falls back to per-batch rendering (with a warning) when the cache would exceed cache_max_gb.
        cache_dtype: storage of the cached cloth images, "float32" (exact) or "float16" (half the memory;
            error measured by bench/train.py). Per-vertex values are always float32.
        cache_max_gb: largest cache built on a device, in GiB.
        cache_chunk: samples rendered at a time while building the cache.
        garment_hash: if set, the dataset must have been made for this garment (manifest garment_hash).
        train_repeats: the training split served this many times an epoch (1: once; more: an epoch's time at
            more rows than a few drapes give, as `pbc garment fit`'s plan times it).
    """

    def __init__(
        self,
        data_dir: str,
        image,
        target: str = "whole",
        patch_id: int | None = None,
        space: str = "local",
        batch_size: int = 32,
        num_workers: int = 0,
        pin_memory: bool = False,
        render: bool = True,
        garment_hash: str | None = None,
        cache_targets: bool = True,
        cache_dtype: str = "float32",
        cache_max_gb: float = 8.0,
        cache_chunk: int = 64,
        train_repeats: int = 1,
    ):
        super().__init__()
        if target not in TARGETS:
            raise ValueError(f"datamodule.target must be one of {TARGETS}, got {target!r}")
        if space not in SPACES:
            raise ValueError(f"datamodule.space must be one of {SPACES}, got {space!r}")
        self.data_dir = Path(data_dir)
        self.image_cfg = image
        self.kind, self.space = target, space
        self.patch_id = None if patch_id is None else int(patch_id)  # read by the patch target only
        self.batch_size, self.num_workers, self.pin_memory = int(batch_size), int(num_workers), bool(pin_memory)
        self.render, self.garment_hash = bool(render), garment_hash
        if cache_dtype not in CACHE_DTYPES:
            raise ValueError(f"datamodule.cache_dtype must be one of {tuple(CACHE_DTYPES)}, got {cache_dtype!r}")
        self.cache_targets, self.cache_dtype = bool(cache_targets), CACHE_DTYPES[cache_dtype]
        self.cache_max_gb, self.cache_chunk = float(cache_max_gb), int(cache_chunk)
        self._cache_refused: set[str] = set()
        if int(train_repeats) < 1:
            raise ValueError(f"datamodule.train_repeats must be >= 1, got {train_repeats}")
        self.train_repeats = int(train_repeats)
        self.data: ClothDataset | None = None
        self.target: VertexTarget | None = None
        self.splits: dict[str, np.ndarray] = {}

    @property
    def ops(self):
        """The target's render/sample operators (ImageOperators, PatchCrop, or None for fc)."""
        return None if self.target is None else self.target.ops

    @property
    def skinner(self):
        return None if self.target is None else self.target.skinner

    # ----------------------------------------------------------------------------------- lifecycle
    def prepare_data(self) -> None:
        """Check that the dataset exists; making it is the entry point's job (it can take many minutes)."""
        if not (self.data_dir / "manifest.json").is_file():
            raise FileNotFoundError(
                f"no dataset at {self.data_dir}: make it with `python -m pbc.generate data=NAME` "
                f"(or `data.dir=...` to point at an existing one); `python -m pbc.train` makes it when missing"
            )

    def setup(self, stage: str | None = None) -> None:
        if self.data is not None:
            return
        self.prepare_data()
        data = load_dataset(self.data_dir)  # memory-maps; clear errors for missing/corrupt/misshapen arrays
        self._check(data)
        self.data = data
        self.splits = {name: data.split(name) for name in ("train", "val", "test")}
        self.target = make_target(data, self.image_cfg, self.kind, self.patch_id, self.space)

    def _check(self, data: ClothDataset) -> None:
        """One clear error for a dataset that cannot serve this configuration."""
        where = f"dataset {self.data_dir}"
        if self.garment_hash is not None and data.manifest.get("garment_hash") != self.garment_hash:
            raise ValueError(
                f"{where} was made for garment {data.manifest.get('garment_hash')}, this run "
                f"expects {self.garment_hash}; set data.dir to that garment's dataset or regenerate"
            )
        n = len(data)
        for name in ("train", "val", "test"):
            idx = np.asarray(data.manifest["splits"][name], np.int64)
            if len(idx) and (idx.min() < 0 or idx.max() >= n):
                raise ValueError(f"{where}: split {name} indexes samples outside 0..{n - 1}; regenerate it")
        # non-finite or implausible rows anywhere were refused when the dataset opened (check_dataset)

    def loader(self, split: str, shuffle: bool = False, repeats: int = 1) -> DataLoader:
        """A DataLoader over any split ('train', 'val', 'test'), each of its samples `repeats` times."""
        if self.data is None:
            self.setup()
        return DataLoader(
            PoseVerts(self.data, np.tile(self.splits[split], repeats)),
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory,
            persistent_workers=self.num_workers > 0,
            drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        return self.loader("train", shuffle=True, repeats=self.train_repeats)

    def val_dataloader(self) -> DataLoader:
        return self.loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self.loader("test", shuffle=False)

    def scoring_dataloaders(self) -> list[DataLoader]:
        """The final scoring pass: the test split, then the training split in order (Table 1's training
        error), matching `pbc.models.module.TEST_SPLITS`."""
        return [self.loader("test", shuffle=False), self.loader("train", shuffle=False)]

    # ----------------------------------------------------------------------------------- rendering
    def on_after_batch_transfer(self, batch: dict, dataloader_idx: int) -> dict:
        """Render the batch's targets where the batch now lives (the GPU in training)."""
        if not self.render:
            return batch
        if self.target is None:
            self.setup()
        if self.cache_targets:
            self.ensure_cache(batch["pose"].device)
        return self.target.fetch(batch)

    def ensure_cache(self, device) -> TargetCache | None:
        """Attach to the target a cache of every split's targets on `device` (built once, chunked), or
        None when it would exceed `cache_max_gb` (then batches are rendered as they come)."""
        if self.target is None:
            self.setup()
        device = torch.device(device)
        if device.type == "cuda" and device.index is None:  # batches live on an indexed device
            device = torch.device("cuda", torch.cuda.current_device())
        cache = self.target.cache
        if cache is not None and cache.device == device:
            return cache
        if str(device) in self._cache_refused:
            return None
        index = np.unique(np.concatenate([self.splits[s] for s in ("train", "val", "test")]))
        person = person_kw(self.data, index).get("person")
        one = self.target.render({"pose": torch.from_numpy(np.array(self.data.poses[index[:1]], np.float32)),
                                  "verts": torch.from_numpy(np.array(self.data.verts[index[:1]], np.float32)),
                                  "person": None if person is None else person[:1]})
        per = sum(v.numel() * (self.cache_dtype.itemsize if k == "image" else v.element_size())
                  for k, v in one.items() if k not in ("pose", "verts", "person", *self.target.constant_keys))
        per += one["verts"].numel() * 4  # the ground-truth normals
        gib = per * len(index) / 2**30
        if gib > self.cache_max_gb:
            log.warning("target cache of %d samples would take %.1f GiB > datamodule.cache_max_gb=%.1f: "
                        "rendering per batch instead (raise cache_max_gb or set cache_dtype=float16)",
                        len(index), gib, self.cache_max_gb)
            self._cache_refused.add(str(device))
            return None
        t0 = time.perf_counter()
        self.target.cache = build_cache(
            self.target, torch.from_numpy(np.array(self.data.poses[index], np.float32)).reshape(len(index), -1),
            torch.from_numpy(np.array(self.data.verts[index], np.float32)), torch.from_numpy(index), device,
            chunk=self.cache_chunk, image_dtype=self.cache_dtype, person=person)
        log.info("target cache: %d samples, %.2f GiB on %s, built in %.1f s", len(index),
                 self.target.cache.nbytes / 2**30, device, time.perf_counter() - t0)
        return self.target.cache
