"""The cloth target: what a model predicts, and the one way to go pose/vertices <-> target <-> 3D.

One job: own, for one (dataset, image config, kind, patch id, offset space), the operators and the
skinner that every caller needs, so the DataModule, the LightningModule, the predictor, `pbc.evaluate`,
the previews and the benchmarks cannot build them differently (docs/architecture.md, "The cloth target").

Kinds (the only place that switches on them is :func:`make_target`):
    whole  `(B, 6, H, W)` front (du,dv,dn) then back, H = W = image.whole_resolution; or, for a garment whose
           charts fill a band of the image (image.whole_sides / whole_rows: the necktie), that window of it,
           `(B, 3 * sides, rows, W)` (`WindowTarget`)
    patch  `(B, 3, S, S)` one patch's crop of the image.patch_resolution image (S = scaled crop_size)
    fc     `(B, V, 3)`    per-vertex values (the fully connected baselines of appendix E.3)
    patches `(B, P*3, S, S)` every patch's crop, channel-stacked (all patch models in one job)

Every target offers
    render(batch)          adds anchors (B,V,3), frames (B,V,3,3), offsets (B,V,3) and, for image kinds,
                           image and mask (and a patch's vertex ids) on the batch's device
    values(pred)           prediction -> offsets of the vertices it covers (B, Vk, 3)
    positions(pred, t)     prediction -> garment positions (B, V, 3); outside a patch, ground truth
    truth(t)               (target tensor, mask or None): what the value loss compares the prediction to
    image_size             served (H, W), or None for per-vertex targets; channels: of one served image
    identity(dataset)      what a checkpoint must match to be loaded by a run of this target

Operators are built by :func:`image_operators` only: cached under `<dataset>/operators/` with the
config's `exact_sample` and `method`. The "all patches in one job" target (`PatchesTarget`) holds the
shared `patch_resolution` ImageOperators and its list of crops: render once, cut every window.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from pbc.core.validate import KINDS
from pbc.geometry.meshops import vertex_normals
from pbc.pixels.frames import SPACES, from_offsets, to_offsets
from pbc.pixels.operators import ImageOperators, PatchCrop, image_sizes
from pbc.pixels.reconstruct import Skinner, mesh_edges


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
        offsets (and, for image kinds, image and mask), on the batch's device. A batch of a dataset of
        several people (`data.body_shape`) carries `person` (B,): each sample is skinned on its person."""
        pose, verts = batch["pose"], batch["verts"]
        person = {"person": batch["person"]} if batch.get("person") is not None else {}
        anchors, frames = self.skinner(pose.reshape(pose.shape[0], -1, 3, 3), **person)
        offsets = to_offsets(verts, anchors, frames, self.space)
        return dict(batch, anchors=anchors, frames=frames, offsets=offsets)

    def rendered(self, batch: dict) -> bool:
        return all(k in batch for k in ("anchors", "frames", "offsets"))

    def ensure(self, batch: dict) -> dict:
        """The batch, rendered unless the DataModule already did (batches from a bare DataLoader)."""
        return batch if self.rendered(batch) else self.fetch(batch)

    def normal_faces(self, device) -> Tensor:
        """(Fk, 3) faces whose normals reach the covered vertices (all faces, or those touching a patch):
        the normal loss's vertex normals at those vertices need no other face. Copied to `device` once."""
        key = f"normal_faces:{device}"
        if key not in self._on:
            faces = self.faces
            ids = self.vertices
            if ids is not None:
                inside = torch.zeros(max(int(faces.max()), int(ids.max())) + 1, dtype=torch.bool)
                inside[ids] = True
                faces = faces[inside[faces].any(1)]
            self._on[key] = faces.to(device)
        return self._on[key]

    # ------------------------------------------------------------------ the target cache
    # What render adds that is the same for every sample (not stacked per sample in a TargetCache).
    constant_keys = ("mask", "vertices")
    cache: TargetCache | None = None

    def fetch(self, batch: dict) -> dict:
        """The batch with its targets: looked up in `self.cache` (a :class:`TargetCache` the DataModule
        attaches) when it holds every sample of the batch on the batch's device, else rendered."""
        cache = self.cache
        if cache is not None and cache.covers(batch):
            return cache.lookup(batch)
        return self.render(batch)

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

    def encode(self, offsets: Tensor) -> Tensor:
        """Offsets (B, V, 3) -> the image this target serves (what a perfect model would predict)."""
        return self.ops.render(offsets)

    def values(self, pred: Tensor) -> Tensor:
        return self.ops.sample(pred)

    @property
    def channels(self) -> int:
        """Channels of one predicted image: (du, dv, dn) per chart side."""
        return 6


class WindowTarget(WholeTarget):
    """A whole garment whose charts fill only part of the square image: the model predicts the band of rows
    `rows` of the chart sides `sides`, (B, 3 * len(sides), rows[1] - rows[0], R). The necktie (appendix F):
    side 0, rows 96..160 of 256 -> (B, 3, 64, 256). Rendering renders the full image and keeps the window;
    sampling puts the prediction back into a zero image, so every vertex must sample inside the window
    (checked here: an image window that cuts a chart is refused, naming the rows the vertices need).

    sides: chart sides kept, in channel order; rows: (first, stop) image rows kept.
    """

    def __init__(self, skinner, faces: Tensor, ops: ImageOperators, sides, rows, space: str = "local"):
        super().__init__(skinner, faces, ops, space)
        self.sides = tuple(int(s) for s in sides)
        self.rows = (int(rows[0]), int(rows[1]))
        self._channels = torch.tensor([3 * s + c for s in self.sides for c in range(3)])
        res = ops.res
        if not 0 <= self.rows[0] < self.rows[1] <= res:
            raise ValueError(f"image window rows {self.rows} are not inside the {res}px image: check image.whole_rows")
        pix, w = np.asarray(ops.arrays["S_pix"]), np.asarray(ops.arrays["S_w"])
        side, row = pix // res**2, pix % res**2 // res
        outside = (w > 0) & (~np.isin(side, self.sides) | (row < self.rows[0]) | (row >= self.rows[1]))
        if outside.any():
            need = row[w > 0]
            raise ValueError(
                f"the image window (sides {list(self.sides)}, rows {self.rows[0]}..{self.rows[1]} of {res}) cuts the "
                f"garment's charts: {int(outside.any(1).sum())} vertices sample outside it (the charts use sides "
                f"{sorted(set(side[w > 0].tolist()))}, rows {int(need.min())}..{int(need.max()) + 1}); widen "
                "image.whole_rows or add the side to image.whole_sides")

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.rows[1] - self.rows[0], self.ops.res)

    @property
    def channels(self) -> int:
        return 3 * len(self.sides)

    def identity(self, dataset) -> dict:
        return dict(super().identity(dataset), window=[list(self.sides), *self.rows])

    def _cut(self, full: Tensor) -> Tensor:
        """(B, 6, R, R) -> (B, 3 * len(sides), rows[1] - rows[0], R): the window."""
        return full.index_select(1, self._channels.to(full.device))[:, :, self.rows[0]:self.rows[1]]

    def encode(self, offsets: Tensor) -> Tensor:
        return self._cut(self.ops.render(offsets))

    @torch.no_grad()
    def render(self, batch: dict) -> dict:
        out = VertexTarget.render(self, batch)
        out["image"] = self.encode(out["offsets"]).contiguous()
        out["mask"] = self._cut(self.ops.image_mask(out["verts"].device, out["verts"].dtype)).contiguous()
        return out

    def values(self, pred: Tensor) -> Tensor:
        b, res = pred.shape[0], self.ops.res
        full = pred.new_zeros(b, 6, *pred.shape[2:]).index_copy(1, self._channels.to(pred.device), pred)
        return self.ops.sample(F.pad(full, (0, 0, self.rows[0], res - self.rows[1])))


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
    def channels(self) -> int:
        return 3

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
    def channels(self) -> int:
        """Channels of one patch's crop (the stacked net's per-patch output)."""
        return 3

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


def dataset_skinner(dataset) -> Skinner:
    """The skinner of a loaded dataset: its base body, and its people when it spans several
    (`ClothDataset.shapes`, `data.body_shape`)."""
    return Skinner(dataset.body, dataset.garment, dataset.embedding, shapes=getattr(dataset, "shapes", None))


def make_target(dataset, image_cfg, kind: str, patch_id: int | None = None, space: str = "local",
                skinner=None, cache_dir: str | Path | None = None) -> VertexTarget:
    """The one factory: the cloth target of `kind` ("whole" | "patch" | "fc" | "patches") for `dataset` (a loaded
    pbc dataset: garment, body, embedding, cage, dir) under the `image` config node.

    skinner: reuse one (its per-device tensors) instead of building it from the dataset; cache_dir: where
    operators are cached (default `<dataset>/operators/`).
    Raises ValueError naming the bad kind, space or patch id.
    """
    if kind not in KINDS:
        raise ValueError(f"model.kind must be one of {KINDS}, got {kind!r}")
    skinner = skinner if skinner is not None else dataset_skinner(dataset)
    faces = dataset.garment.faces
    if kind == "fc":
        return VertexTarget(skinner, faces, space, len(dataset.garment.vertices))
    if kind == "whole":
        ops, sizes = image_operators(dataset, image_cfg, "whole", cache_dir), image_sizes(image_cfg)
        if sizes["whole_sides"] == (0, 1) and sizes["whole_rows"] == (0, ops.res):
            return WholeTarget(skinner, faces, ops, space)
        return WindowTarget(skinner, faces, ops, sizes["whole_sides"], sizes["whole_rows"], space)
    if kind == "patches":
        ops = image_operators(dataset, image_cfg, "patch", cache_dir)
        return PatchesTarget(skinner, faces, ops, patch_crops(dataset, image_cfg, ops), space)
    n = len(dataset.cage.patches)
    if patch_id is None or not 0 <= int(patch_id) < n:
        raise ValueError(f"unknown patch_id {patch_id}: dataset {dataset.dir} has patches 0..{n - 1}")
    ops = image_operators(dataset, image_cfg, "patch", cache_dir)
    sizes = image_sizes(image_cfg)
    crop = ops.crop(dataset.cage.patches[int(patch_id)], sizes["crop_size"], sizes["margin"])
    return PatchTarget(skinner, faces, crop, ops.res, space)


# ---------------------------------------------------------------------------------- the target cache
class TargetCache:
    """The rendered targets of a fixed set of samples, held on one device (docs/architecture.md).

    A sample's anchors, frames, offsets, cloth image (and mask) depend only on the sample, so they are
    rendered once per dataset instead of once per batch per epoch; `lookup` then costs one gather.

    per_sample: key -> (N, ...) tensors, row i = sample `index[i]`; constants: key -> tensors every batch
    shares (mask (1, C, H, W), a patch's vertex ids); index (N,) int64 dataset sample ids.
    Stored dtypes are kept (an fp16 image costs half the memory); `lookup` serves float32.
    """

    def __init__(self, per_sample: dict[str, Tensor], constants: dict[str, Tensor], index: Tensor):
        self.per_sample, self.constants = per_sample, constants
        index = torch.as_tensor(index).long()
        self.device = index.device if not per_sample else next(iter(per_sample.values())).device
        self.row = torch.full((int(index.max()) + 1 if len(index) else 0,), -1, dtype=torch.long,
                              device=self.device)
        self.row[index.to(self.device)] = torch.arange(len(index), device=self.device)

    def __len__(self) -> int:
        return int((self.row >= 0).sum())

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in self.per_sample.values())

    def covers(self, batch: dict) -> bool:
        """True when the batch (with its `index`) lives on this cache's device and every sample is held."""
        idx = batch.get("index")
        if idx is None or idx.device != self.device:
            return False
        return bool(len(idx) == 0 or (int(idx.max()) < len(self.row) and int(idx.min()) >= 0
                                      and (self.row[idx] >= 0).all()))

    def lookup(self, batch: dict) -> dict:
        """The batch plus its cached targets (float32), as the target's render would give them."""
        rows = self.row[batch["index"]]
        out = dict(batch)
        for k, v in self.per_sample.items():
            v = v[rows]  # advanced indexing: index_select on a 4-D tensor was 6x slower on the CPU
            out[k] = v if v.dtype == torch.float32 or not v.is_floating_point() else v.float()
        out.update(self.constants)
        return out


@torch.no_grad()
def build_cache(target: VertexTarget, pose: Tensor, verts: Tensor, index: Tensor, device=None,
                chunk: int = 64, image_dtype: torch.dtype = torch.float32,
                normals: bool = True, person: Tensor | None = None) -> TargetCache:
    """Render the targets of N samples once, `chunk` at a time, on `device`.

    pose (N, 90) or (N, J, 3, 3), verts (N, V, 3) float32 (any device; copied chunk by chunk), index (N,)
    their dataset sample ids. image_dtype: storage of the cloth images (float16 halves the cache; its
    error is measured by bench/train.py); per-vertex values stay float32. normals: also cache the
    ground-truth vertex normals (N, V, 3) the normal loss and metric compare to. person: (N,) each sample's
    person (a dataset of several people, `data.body_shape`), None for one body.
    """
    device = torch.device(device) if device is not None else verts.device
    n = int(verts.shape[0])
    if n == 0:
        raise ValueError("build_cache needs at least one sample")
    faces = target.topology(device)[0]
    per_sample: dict[str, Tensor] = {}
    constants: dict[str, Tensor] = {}
    for start in range(0, n, int(chunk)):
        stop = min(start + int(chunk), n)
        batch = {"pose": torch.as_tensor(pose[start:stop]).to(device, torch.float32),
                 "verts": torch.as_tensor(verts[start:stop]).to(device, torch.float32)}
        if person is not None:
            batch["person"] = torch.as_tensor(person[start:stop]).long().to(device)
        out = target.render(batch)
        if normals:
            out["normals"] = vertex_normals(batch["verts"], faces)
        for k, v in out.items():
            if k in batch:
                continue
            if k in target.constant_keys:
                constants.setdefault(k, v)
                continue
            if k not in per_sample:
                dtype = image_dtype if k == "image" else v.dtype
                per_sample[k] = torch.empty((n, *v.shape[1:]), dtype=dtype, device=device)
            per_sample[k][start:stop] = v
    return TargetCache(per_sample, constants, torch.as_tensor(index).long().to(device))
