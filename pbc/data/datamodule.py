"""The Lightning DataModule: serves (pose, draped vertices) from a dataset directory and renders cloth
images per batch, on the batch's device.

One job: turn a dataset directory into train/val/test batches. Only per-vertex data is read from disk
(memory-mapped); images are rendered in `on_after_batch_transfer` with the garment's sparse operators
(pbc.pixels.operators), never stored.

Batch dict (B = batch size, V garment vertices, H = W = image.whole_resolution, S = crop size):
    pose     (B, 90)          float32  10 joint rotations, row-major 3x3, joint order of conf/body
    verts    (B, V, 3)        float32  draped garment vertices (root frame, metres): metrics ground truth
    index    (B,)             int64    sample index in the dataset arrays
  added on the device when `render` is true (the default):
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
`images_to_positions(image, dm.ops, anchors, frames, space)` (pbc.pixels.reconstruct) inverts a whole
image; for a patch, `dm.ops.sample(crop)` gives the patch vertices' offsets.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from pbc.data.dataset import ClothDataset, load_dataset
from pbc.pixels.frames import SPACES, to_offsets
from pbc.pixels.operators import ImageOperators, PatchCrop, image_sizes
from pbc.pixels.reconstruct import Skinner

TARGETS = ("whole", "patch")


class PoseVerts(Dataset):
    """Samples `indices` of a dataset: pose (90,), verts (V, 3), index. Reads only the rows it serves."""

    def __init__(self, data: ClothDataset, indices: np.ndarray):
        self.poses, self.verts, self.indices = data.poses, data.verts, np.asarray(indices, np.int64)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        k = int(self.indices[i])
        return {
            "pose": torch.from_numpy(np.array(self.poses[k], np.float32).reshape(-1)),
            "verts": torch.from_numpy(np.array(self.verts[k], np.float32)),
            "index": torch.tensor(k),
        }


class ClothDataModule(L.LightningDataModule):
    """Hydra-configured DataModule (conf/datamodule/default.yaml); see the module docstring for batches.

    Args:
        data_dir: the dataset directory (written by `python -m pbc.generate`).
        image: the `image` config node (resolutions, crop_size, margin, pad, exact_sample, method).
        target: "whole" (256 x 6 channel images) or "patch" (one patch's crop).
        patch_id: the patch for target=patch (0 .. number of patches - 1).
        space: offset space of the images ("local", "root", "position").
        batch_size, num_workers, pin_memory: DataLoader settings.
        render: render images in `on_after_batch_transfer` (False: only pose/verts/index).
        garment_hash: if set, the dataset must have been made for this garment (manifest garment_hash).
        generate_cfg: the full root config; `prepare_data` generates the dataset from it when missing.
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
        generate_cfg=None,
    ):
        super().__init__()
        if target not in TARGETS:
            raise ValueError(f"datamodule.target must be one of {TARGETS}, got {target!r}")
        if space not in SPACES:
            raise ValueError(f"datamodule.space must be one of {SPACES}, got {space!r}")
        if target == "patch" and patch_id is None:
            raise ValueError("datamodule.target=patch needs a patch_id")
        self.data_dir = Path(data_dir)
        self.image_cfg = image
        self.target, self.patch_id, self.space = target, (None if patch_id is None else int(patch_id)), space
        self.batch_size, self.num_workers, self.pin_memory = (
            int(batch_size),
            int(num_workers),
            bool(pin_memory),
        )
        self.render, self.garment_hash, self.generate_cfg = bool(render), garment_hash, generate_cfg
        self.data: ClothDataset | None = None
        self.ops: ImageOperators | PatchCrop | None = None
        self.skinner: Skinner | None = None
        self.splits: dict[str, np.ndarray] = {}

    # ----------------------------------------------------------------------------------- lifecycle
    def prepare_data(self) -> None:
        """Generate the dataset if its directory has no manifest (a fresh machine just works)."""
        if (self.data_dir / "manifest.json").is_file():
            return
        if self.generate_cfg is None:
            raise FileNotFoundError(
                f"no dataset at {self.data_dir} and no config to generate it from; "
                "run `python -m pbc.generate` first"
            )
        from pbc.data.generate import generate  # GENERATION: the lead's pipeline makes the directory

        generate(self.generate_cfg)

    def setup(self, stage: str | None = None) -> None:
        if self.data is not None:
            return
        data = load_dataset(self.data_dir)  # memory-maps; clear errors for missing/corrupt/misshapen arrays
        self._check(data)
        self.data = data
        self.splits = {name: data.split(name) for name in ("train", "val", "test")}
        if not self.render:
            return
        self.skinner = Skinner(data.body, data.garment, data.embedding)
        self.ops = operators_for(data, self.image_cfg, self.target, self.patch_id)

    def _check(self, data: ClothDataset) -> None:
        """One clear error for a dataset that cannot serve this configuration."""
        where = f"dataset {self.data_dir}"
        if self.garment_hash is not None and data.manifest.get("garment_hash") != self.garment_hash:
            raise ValueError(
                f"{where} was made for garment {data.manifest.get('garment_hash')}, this run "
                f"expects {self.garment_hash}; set data.dir to that garment's dataset or regenerate"
            )
        if self.target == "patch":
            n = len(data.cage.patches)
            if not 0 <= self.patch_id < n:
                raise ValueError(f"unknown patch_id {self.patch_id}: {where} has patches 0..{n - 1}")
        n = len(data)
        for name in ("train", "val", "test"):
            idx = np.asarray(data.manifest["splits"][name], np.int64)
            if len(idx) and (idx.min() < 0 or idx.max() >= n):
                raise ValueError(f"{where}: split {name} indexes samples outside 0..{n - 1}; regenerate it")
        # A torn or bit-rotted array reads as garbage, not as an exception: spot-check the ends.
        for arr, what in ((data.poses, "poses.npy"), (data.verts, "verts.npy")):
            rows = np.asarray(arr[[0, n - 1]])
            if not np.isfinite(rows).all():
                raise ValueError(
                    f"{where}: {what} holds non-finite values; it is corrupt, regenerate the dataset"
                )

    def loader(self, split: str, shuffle: bool = False) -> DataLoader:
        """A DataLoader over any split ('train', 'val', 'test'), e.g. to score a model on the train split."""
        if self.data is None:
            self.setup()
        return DataLoader(
            PoseVerts(self.data, self.splits[split]),
            batch_size=self.batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory,
            persistent_workers=self.num_workers > 0,
            drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        return self.loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self.loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self.loader("test", shuffle=False)

    # ----------------------------------------------------------------------------------- rendering
    def on_after_batch_transfer(self, batch: dict, dataloader_idx: int) -> dict:
        """Render the batch's images where the batch now lives (the GPU in training)."""
        return self.render_batch(batch) if self.render else batch

    @torch.no_grad()
    def render_batch(self, batch: dict) -> dict:
        """Add anchors, frames, offsets, image and mask to a batch of pose/verts (any device)."""
        if self.ops is None or self.skinner is None:
            self.setup()
        pose, verts = batch["pose"], batch["verts"]
        anchors, frames = self.skinner(pose.reshape(pose.shape[0], -1, 3, 3))
        offsets = to_offsets(verts, anchors, frames, self.space)
        out = dict(batch, anchors=anchors, frames=frames, offsets=offsets)
        out["image"] = self.ops.render(offsets)
        out["mask"] = self.ops.image_mask(verts.device, verts.dtype)
        if isinstance(self.ops, PatchCrop):
            out["vertices"] = self.ops.vertices.to(verts.device)
        return out


def operators_for(data: ClothDataset, image_cfg, target: str, patch_id: int | None = None):
    """The render/sample operators for `target`, cached under `<dataset>/operators/`.

    whole -> ImageOperators at image.whole_resolution; patch -> PatchCrop of patch `patch_id` at
    image.patch_resolution (crop_size, margin and pad scaled from image.reference_resolution).
    """
    sizes = image_sizes(image_cfg)
    which = "whole" if target == "whole" else "patch"
    ops = ImageOperators.for_garment(
        data.garment,
        sizes[f"{which}_resolution"],
        sizes[f"{which}_pad"],
        exact=bool(image_cfg.get("exact_sample", True)),
        cache_dir=Path(data.dir) / "operators",
        method=str(image_cfg.get("method", "gather")),
    )
    if target == "whole":
        return ops
    return ops.crop(data.cage.patches[int(patch_id)], sizes["crop_size"], sizes["margin"])


def from_config(cfg) -> ClothDataModule:
    """Build the DataModule from the root config (uses cfg.datamodule, cfg.image, cfg.data.dir)."""
    dm = cfg.datamodule
    return ClothDataModule(
        data_dir=str(cfg.data.dir),
        image=cfg.image,
        target=dm.target,
        patch_id=dm.get("patch_id"),
        space=dm.space,
        batch_size=dm.batch_size,
        num_workers=dm.num_workers,
        pin_memory=dm.get("pin_memory", False),
        render=dm.get("render", True),
        garment_hash=dm.get("garment_hash"),
        generate_cfg=cfg,
    )
