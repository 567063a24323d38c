"""The cloth target: what a model predicts, and the one way to go pose/vertices <-> target <-> 3D.

One job: own, for one (dataset, image config, kind, patch id, offset space), the operators and the
skinner that every caller needs, so the DataModule, the LightningModule, the predictor, `pbc.evaluate`,
the previews and the benchmarks cannot build them differently (docs/architecture.md, "The cloth target").

Kinds (the only place that switches on them is :func:`make_target`):
    whole  `(B, 6, H, W)` front (du,dv,dn) then back, H = W = image.whole_resolution
    patch  `(B, 3, S, S)` one patch's crop of the image.patch_resolution image (S = scaled crop_size)
    fc     `(B, V, 3)`    per-vertex values (the fully connected baselines of appendix E.3)
    patches `(B, P*3, S, S)` every patch's crop, channel-stacked (all patch models in one job)

Every target offers
    render(batch)          adds anchors (B,V,3), frames (B,V,3,3), offsets (B,V,3) and, for image kinds,
                           image and mask (and a patch's vertex ids) on the batch's device
    values(pred)           prediction -> offsets of the vertices it covers (B, Vk, 3)
    positions(pred, t)     prediction -> garment positions (B, V, 3); outside a patch, ground truth
    truth(t)               (target tensor, mask or None): what the value loss compares the prediction to
    image_size             served (H, W), or None for per-vertex targets
    identity(dataset)      what a checkpoint must match to be loaded by a run of this target

Operators are built by :func:`image_operators` only: cached under `<dataset>/operators/` with the
config's `exact_sample` and `method`. The "all patches in one job" target (`PatchesTarget`) holds the
shared `patch_resolution` ImageOperators and its list of crops: render once, cut every window.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from pbc.pixels.frames import SPACES, from_offsets, to_offsets
from pbc.pixels.operators import ImageOperators, PatchCrop, image_sizes
from pbc.pixels.reconstruct import Skinner, mesh_edges

KINDS = ("whole", "patch", "fc", "patches")


def image_operators(dataset, image_cfg, which: str, cache_dir: str | Path | None = None) -> ImageOperators:
    """The render/sample operators of `dataset`'s garment at image.`which`_resolution ("whole" | "patch"),
    cached under `<dataset>/operators/` (or `cache_dir`), with the config's exact_sample and method."""
    if which not in ("whole", "patch"):
        raise ValueError(f"image operators exist for 'whole' or 'patch' images, not {which!r}")
    sizes = image_sizes(image_cfg)
    return ImageOperators.for_garment(
        dataset.garment,
        sizes[f"{which}_resolution"],
        sizes[f"{which}_pad"],
        exact=bool(image_cfg.get("exact_sample", True)),
        cache_dir=Path(cache_dir) if cache_dir is not None else Path(dataset.dir) / "operators",
        method=str(image_cfg.get("method", "gather")),
    )


def patch_crops(dataset, image_cfg, ops: ImageOperators | None = None) -> list[PatchCrop]:
    """Every cage patch's crop operator, cut from the patch-resolution operators `ops` (built when None)."""
    sizes = image_sizes(image_cfg)
    ops = ops if ops is not None else image_operators(dataset, image_cfg, "patch")
    return [ops.crop(p, sizes["crop_size"], sizes["margin"]) for p in dataset.cage.patches]


class VertexTarget:
    """Per-vertex values (B, V, 3) in `space`; the base of the image targets.

    skinner: rotations (B, J, 3, 3) -> anchors (B, V, 3), frames (B, V, 3, 3); faces (F, 3) long.
    """

    kind = "fc"
    ops = None

    def __init__(self, skinner, faces: Tensor, space: str = "local", num_vertices: int | None = None):
        if space not in SPACES:
            raise ValueError(f"offset space must be one of {SPACES}, got {space!r}")
        self.skinner, self.space = skinner, space
        self.faces = torch.as_tensor(faces).long()
        self.edges = mesh_edges(self.faces)
        self.num_vertices = int(num_vertices) if num_vertices is not None else int(self.faces.max()) + 1
        self._on: dict[str, tuple[Tensor, Tensor]] = {}

    # ------------------------------------------------------------------ what is served
    @property
    def vertices(self) -> Tensor | None:
        """(Vk,) garment vertex ids the prediction covers (None = all)."""
        return None

    @property
    def image_size(self) -> tuple[int, int] | None:
        return None

    @property
    def resolution(self) -> int | None:
        return None

    @property
    def patch_id(self) -> int | None:
        return None

    def identity(self, dataset) -> dict:
        """What a checkpoint must match to be loaded by a run of this target."""
        size = self.image_size
        return {
            "garment_hash": str(dataset.manifest.get("garment_hash", "")),
            "num_vertices": int(dataset.verts.shape[1]),
            "kind": self.kind,
            "resolution": self.resolution,
            "patch_id": self.patch_id,
            "space": self.space,
            "crop_size": size[0] if self.patch_id is not None else None,
        }

    def topology(self, device) -> tuple[Tensor, Tensor]:
        """(faces (F, 3), edges (E, 2)) on `device`, copied there once."""
        key = str(device)
        if key not in self._on:
            self._on[key] = (self.faces.to(device), self.edges.to(device))
        return self._on[key]

    # ------------------------------------------------------------------ vertices -> target
    @torch.no_grad()
    def render(self, batch: dict) -> dict:
        """batch {pose (B, 90) or (B, J, 3, 3), verts (B, V, 3), ...} -> the batch plus anchors, frames,
        offsets (and, for image kinds, image and mask), on the batch's device."""
        pose, verts = batch["pose"], batch["verts"]
        anchors, frames = self.skinner(pose.reshape(pose.shape[0], -1, 3, 3))
        offsets = to_offsets(verts, anchors, frames, self.space)
        return dict(batch, anchors=anchors, frames=frames, offsets=offsets)

    def rendered(self, batch: dict) -> bool:
        return all(k in batch for k in ("anchors", "frames", "offsets"))

    def ensure(self, batch: dict) -> dict:
        """The batch, rendered unless the DataModule already did (batches from a bare DataLoader)."""
        return batch if self.rendered(batch) else self.render(batch)

    def truth(self, t: dict) -> tuple[Tensor, Tensor | None]:
        """(ground truth the value loss compares the prediction to, its mask or None)."""
        return t["offsets"], None

    # ------------------------------------------------------------------ target -> vertices
    def values(self, pred: Tensor) -> Tensor:
        """Prediction -> offsets of the covered vertices (B, Vk, 3)."""
        return pred

    def positions(self, pred: Tensor, t: dict) -> Tensor:
        """Prediction -> positions (B, V, 3) given the batch's anchors and frames."""
        return from_offsets(self.values(pred), t["anchors"], t["frames"], self.space)


class WholeTarget(VertexTarget):
    """The whole garment as a (B, 6, H, W) cloth image (front then back)."""

    kind = "whole"

    def __init__(self, skinner, faces: Tensor, ops: ImageOperators, space: str = "local"):
        super().__init__(skinner, faces, space, ops.V if hasattr(ops, "V") else None)
        self.ops = ops

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.ops.res, self.ops.res)

    @property
    def resolution(self) -> int:
        return int(self.ops.res)

    @torch.no_grad()
    def render(self, batch: dict) -> dict:
        out = super().render(batch)
        out["image"] = self.ops.render(out["offsets"])
        out["mask"] = self.ops.image_mask(out["verts"].device, out["verts"].dtype)
        return out

    def rendered(self, batch: dict) -> bool:
        return super().rendered(batch) and "image" in batch

    def truth(self, t: dict) -> tuple[Tensor, Tensor | None]:
        return t["image"], t["mask"]

    def values(self, pred: Tensor) -> Tensor:
        return self.ops.sample(pred)


class PatchTarget(WholeTarget):
    """One patch's (B, 3, S, S) crop of the patch-resolution image; positions outside it are ground truth.

    resolution: the full image's resolution the crop is cut from (checkpoint identity).
    """

    kind = "patch"

    def __init__(self, skinner, faces: Tensor, crop: PatchCrop, resolution: int, space: str = "local"):
        super().__init__(skinner, faces, crop, space)
        self._resolution = int(resolution)
        self.num_vertices = max(self.num_vertices, int(crop.vertices.max()) + 1)
        ids = crop.vertices
        inside = torch.zeros(max(int(self.faces.max()), int(ids.max())) + 1, dtype=torch.bool)
        inside[ids] = True
        # the edge loss runs over the patch's own edges only
        self.edges = self.edges[inside[self.edges].all(1)]

    @property
    def vertices(self) -> Tensor:
        return self.ops.vertices

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.ops.window[2], self.ops.window[2])

    @property
    def resolution(self) -> int:
        return self._resolution

    @property
    def patch_id(self) -> int:
        return int(self.ops.patch_id)

    @torch.no_grad()
    def render(self, batch: dict) -> dict:
        out = super().render(batch)
        out["vertices"] = self.ops.vertices.to(out["verts"].device)
        return out

    def positions(self, pred: Tensor, t: dict) -> Tensor:
        ids = self.vertices.to(pred.device)
        inner = from_offsets(self.values(pred), t["anchors"][:, ids], t["frames"][:, ids], self.space)
        return t["verts"].index_copy(1, ids, inner.to(t["verts"].dtype))


class PatchesTarget(WholeTarget):
    """Every cage patch's crop in one target: the patch-resolution image is rendered ONCE per batch and
    each patch's window cut from it, channel-stacked as `(B, P*3, S, S)` (channels [3p, 3p+3) = patch p),
    which is the layout of a stacked (grouped-convolution) network's output.

    patches: one `PatchTarget` per crop sharing the skinner, for per-patch losses, positions and the
    identity an exported single-patch checkpoint carries (`patch_identity`).
    """

    kind = "patches"

    def __init__(self, skinner, faces: Tensor, ops: ImageOperators, crops: list[PatchCrop], space: str = "local"):
        super().__init__(skinner, faces, ops, space)
        sizes = {c.window[2] for c in crops}
        if len(sizes) != 1:
            raise ValueError(f"all patch crops must have one size to be stacked, got sizes {sorted(sizes)}")
        self.crops = list(crops)
        self.patches = [PatchTarget(skinner, faces, c, ops.res, space) for c in crops]
        self.num_vertices = max([self.num_vertices] + [p.num_vertices for p in self.patches])
        self._masks: dict[str, Tensor] = {}

    @property
    def num_patches(self) -> int:
        return len(self.crops)

    @property
    def image_size(self) -> tuple[int, int]:
        s = self.crops[0].window[2]
        return (s, s)

    def identity(self, dataset) -> dict:
        return dict(super().identity(dataset), crop_size=self.image_size[0], num_patches=self.num_patches)

    def patch_identity(self, dataset, p: int) -> dict:
        """The identity of patch p's single-patch run (what an exported checkpoint must carry)."""
        return self.patches[p].identity(dataset)

    def image_mask(self, device, dtype=torch.float32) -> Tensor:
        """(1, P*3, S, S) the crops' masks, channel-stacked, made once per device."""
        key = f"{device}/{dtype}"
        if key not in self._masks:
            self._masks[key] = torch.cat([c.image_mask(device, dtype) for c in self.crops], 1).contiguous()
        return self._masks[key]

    @torch.no_grad()
    def render(self, batch: dict) -> dict:
        out = VertexTarget.render(self, batch)
        full = self.ops.render(out["offsets"])  # (B, 6, R, R): one render shared by every crop
        out["image"] = torch.cat([full[:, 3 * c.side:3 * c.side + 3, c.window[0]:c.window[0] + c.window[2],
                                       c.window[1]:c.window[1] + c.window[2]] for c in self.crops], 1)
        out["mask"] = self.image_mask(out["verts"].device, out["verts"].dtype)
        return out

    def values(self, pred: Tensor) -> Tensor:
        raise NotImplementedError("a stacked prediction covers overlapping vertex sets: use "
                                  "target.patches[p].values(pred[:, 3p:3p+3]) per patch")

    def positions(self, pred: Tensor, t: dict) -> Tensor:
        """(B, P*3, S, S) -> (B, V, 3): ground truth with each patch's vertices set by its crop (a later
        patch overwrites an earlier one on the vertices they share: a preview, not a stitch)."""
        pos = t["verts"]
        for p, sub in enumerate(self.patches):
            pos = sub.positions(pred[:, 3 * p:3 * p + 3], dict(t, verts=pos))
        return pos


def make_target(dataset, image_cfg, kind: str, patch_id: int | None = None, space: str = "local",
                skinner=None) -> VertexTarget:
    """The one factory: the cloth target of `kind` ("whole" | "patch" | "fc" | "patches") for `dataset` (a loaded
    pbc dataset: garment, body, embedding, cage, dir) under the `image` config node.

    skinner: reuse one (its per-device tensors) instead of building it from the dataset.
    Raises ValueError naming the bad kind, space or patch id.
    """
    if kind not in KINDS:
        raise ValueError(f"model.kind must be one of {KINDS}, got {kind!r}")
    skinner = skinner if skinner is not None else Skinner(dataset.body, dataset.garment, dataset.embedding)
    faces = dataset.garment.faces
    if kind == "fc":
        return VertexTarget(skinner, faces, space, len(dataset.garment.vertices))
    if kind == "whole":
        return WholeTarget(skinner, faces, image_operators(dataset, image_cfg, "whole"), space)
    if kind == "patches":
        ops = image_operators(dataset, image_cfg, "patch")
        return PatchesTarget(skinner, faces, ops, patch_crops(dataset, image_cfg, ops), space)
    n = len(dataset.cage.patches)
    if patch_id is None or not 0 <= int(patch_id) < n:
        raise ValueError(f"unknown patch_id {patch_id}: dataset {dataset.dir} has patches 0..{n - 1}")
    ops = image_operators(dataset, image_cfg, "patch")
    sizes = image_sizes(image_cfg)
    crop = ops.crop(dataset.cage.patches[int(patch_id)], sizes["crop_size"], sizes["margin"])
    return PatchTarget(skinner, faces, crop, ops.res, space)
