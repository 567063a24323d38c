"""Seam handling: the band around the cage seams, the four seam methods, and the seam-jump metric.

One job: make the stitched garment smooth and consistent across patch boundaries (paper section 4.1).
- `average`: the feathered blend of `assemble` alone (baseline);
- `pca`: project the stitched per-vertex offsets onto a PCA basis of whole garments, used either
  everywhere or only in a soft band around the seams;
- `inpaint`: refill the seam band of the assembled images with `skimage.restoration.inpaint_biharmonic`;
- `hierarchy`: fill the seam band with the whole-shirt model's prediction (beyond the paper);
- `cage`: agreed cage values carried into each patch by its Poisson blendshape basis (appendix C,
  `pbc.stitch.cage_basis.CageSeams`);
- `hierarchy_detail`: the whole-shirt model's prediction as the low-frequency base and the patches'
  high-frequency detail on top, split by a masked Gaussian low-pass of the 512 images (beyond the paper).
The seam band is the seam curves rasterised in each chart and dilated by a width, with a weight that
falls linearly from 1 on the seam to 0 at the width. The metric is the mean jump across seam edges.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage
from skimage.draw import line
from skimage.restoration import inpaint_biharmonic
from torch import Tensor

from pbc.stitch.assemble import Assembler, feather_weights
from pbc.stitch.cage_basis import CageSeams, tensor_from_config
from pbc.stitch.crops import sample_crops, uv_to_pixel
from pbc.stitch.pca import PCABasis, project

METHODS = ("average", "pca", "inpaint", "hierarchy", "hierarchy_detail", "cage")
NEEDS_WHOLE = ("hierarchy", "hierarchy_detail")


# ----------------------------------------------------------------------------- band


def rasterise_segments(segments: np.ndarray, sides: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Draw line segments into a two-sided mask.

    segments: (K, 2, 2) float (row, col) end points; sides: (K,) 0/1 -> (2, H, W) bool.
    """
    H, W = size
    out = np.zeros((2, H, W), bool)
    seg = np.rint(np.asarray(segments, float)).astype(int)
    for (r0, c0), (r1, c1), s in zip(seg[:, 0], seg[:, 1], np.asarray(sides), strict=True):
        rr, cc = line(r0, c0, r1, c1)
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        out[s, rr[ok], cc[ok]] = True
    return out


def vertex_patch_ids(patch_vertices: list, num_vertices: int) -> Tensor:
    """Patch id per vertex from each patch's vertex list -> (V,) long (-1 if no patch owns it)."""
    vp = torch.full((num_vertices,), -1, dtype=torch.long)
    for k, vs in enumerate(patch_vertices):
        vp[torch.as_tensor(np.asarray(vs), dtype=torch.long)] = k
    return vp


def seam_edges(faces: Tensor, vertex_patch: Tensor) -> Tensor:
    """Unique mesh edges whose two end vertices belong to different patches: (E, 2) long, sorted pairs."""
    f = faces.long()
    e = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).sort(1).values
    e = torch.unique(e, dim=0)
    return e[vertex_patch[e[:, 0]] != vertex_patch[e[:, 1]]]


def seam_curve_mask(faces: Tensor, face_uv: Tensor, face_side: Tensor, uv: Tensor, vertex_patch: Tensor,
                    size: tuple[int, int]) -> np.ndarray:
    """Pixel mask of the cage seams in both charts: (2, H, W) bool.

    Every face edge joining two patches is drawn in its face's chart; every vertex on such an edge is
    also marked at each chart position it has, so a seam that is a chart boundary (front/back side
    seams) shows up in both charts.
    """
    f, fu = faces.long(), face_uv.long()
    vp = vertex_patch
    segs, sides = [], []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        cross = vp[f[:, a]] != vp[f[:, b]]
        pa = uv_to_pixel(uv[fu[cross, a]].double(), size)
        pb = uv_to_pixel(uv[fu[cross, b]].double(), size)
        segs.append(torch.stack([pa, pb], 1))
        sides.append(face_side[cross])
    on_seam = torch.zeros(vp.shape[0], dtype=torch.bool)
    e = seam_edges(faces, vp)
    on_seam[e.reshape(-1)] = True
    for c in range(3):
        sel = on_seam[f[:, c]]  # every chart position of a seam vertex, as a point
        p = uv_to_pixel(uv[fu[sel, c]].double(), size)
        segs.append(torch.stack([p, p], 1))
        sides.append(face_side[sel])
    return rasterise_segments(torch.cat(segs).numpy(), torch.cat(sides).numpy(), size)


def band_weight(curve_mask: np.ndarray, width: float) -> Tensor:
    """Soft seam band: 1 on the seam pixels, falling linearly to 0 at `width` pixels away.

    curve_mask: (2, H, W) bool -> (2, H, W) float32; the band is `band_weight(...) > 0`.
    """
    out = np.zeros(curve_mask.shape, np.float32)
    for s in range(curve_mask.shape[0]):
        if curve_mask[s].any():
            d = ndimage.distance_transform_edt(~curve_mask[s])
            out[s] = np.clip(1.0 - d / float(width), 0.0, 1.0)
    return torch.from_numpy(out)


def sample_pixels(images: Tensor, pix: Tensor, side: Tensor) -> Tensor:
    """Bilinear samples of two-sided images at (row, col) pixel positions.

    images: (B, 2*C, H, W) or (2, H, W) (one channel per side); pix: (V, 2); side: (V,) -> (B, V, C)
    (or (V,) for the single-channel form).
    """
    single = images.ndim == 3
    img = images[None] if single else images
    B, C2, H, W = img.shape
    C = C2 // 2
    grid = torch.stack([(pix[:, 1] + 0.5) / W * 2 - 1, (pix[:, 0] + 0.5) / H * 2 - 1], -1).to(img)
    per_side = img.view(B * 2, C, H, W)
    g = grid[None, :, None, :].expand(B * 2, -1, -1, -1)
    vals = F.grid_sample(per_side, g, mode="bilinear", align_corners=False)  # (2B, C, V, 1)
    vals = vals[..., 0].view(B, 2, C, -1)
    out = torch.gather(vals, 1, side.to(img.device).view(1, 1, 1, -1).expand(B, 1, C, -1))[:, 0]
    out = out.transpose(1, 2)
    return out[0, :, 0] if single else out


# ----------------------------------------------------------------------------- methods


def blend_in_band(raw: Tensor, fill: Tensor, weight: Tensor) -> Tensor:
    """raw, fill: (B, V, 3); weight: (V,) in [0, 1] -> raw + weight * (fill - raw)."""
    return raw + weight[None, :, None] * (fill - raw)


def nearest_fill_index(known: np.ndarray) -> np.ndarray:
    """For each side, the flat index of the nearest known pixel: (2, H, W) bool -> (2, H, W) long.

    Used to extend the assembled images past the covered area before inpainting, so the biharmonic
    fill near a chart edge does not see the zeros outside it.
    """
    S, H, W = known.shape
    out = np.zeros((S, H, W), np.int64)
    for s in range(S):
        if known[s].all() or not known[s].any():
            out[s] = np.arange(H * W).reshape(H, W)
            continue
        r, c = ndimage.distance_transform_edt(~known[s], return_distances=False, return_indices=True)
        out[s] = r * W + c
    return out


def inpaint_band(images: Tensor, band: np.ndarray, fill_index: np.ndarray | None = None) -> Tensor:
    """Refill the band pixels of each side with biharmonic inpainting; other pixels are untouched.

    images: (B, 2*C, H, W); band: (2, H, W) bool; fill_index: (2, H, W) from `nearest_fill_index`
    (optional) to extend known values outside the covered area first. Returns a new tensor.
    """
    B, C2, H, W = images.shape
    C = C2 // 2
    out = images.detach().clone()
    x = images.detach().cpu().double().numpy().reshape(B, 2, C, H, W)
    for s in range(2):
        m = band[s]
        if not m.any():
            continue
        for b in range(B):
            img = x[b, s]
            if fill_index is not None:
                img = img.reshape(C, -1)[:, fill_index[s].reshape(-1)].reshape(C, H, W)
            filled = inpaint_biharmonic(np.moveaxis(img, 0, -1), m, channel_axis=-1)
            vals = torch.from_numpy(np.moveaxis(filled, -1, 0)[:, m]).to(out)
            out[b, s * C:(s + 1) * C][:, torch.from_numpy(m)] = vals
    return out


def gaussian_kernel1d(sigma: float, truncate: float = 3.0) -> Tensor:
    """Normalised 1-D Gaussian taps: (2 * ceil(truncate * sigma) + 1,) float32."""
    r = max(1, int(np.ceil(truncate * sigma)))
    t = torch.arange(-r, r + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    return k / k.sum()


def masked_blur(images: Tensor, mask: Tensor, sigma: float) -> Tensor:
    """Gaussian low-pass inside each side's mask, normalised so the mask edge does not pull toward 0.

    images: (B, 2*C, H, W); mask: (2, H, W) bool -> (B, 2*C, H, W), blur(img * m) / blur(m) inside
    the mask and 0 outside. A constant inside the mask is returned unchanged. For sigma >= 8 px the
    blur runs on a grid coarsened by sigma // 4 (box-averaged, then bilinearly upsampled): the result
    is still a normalised low-pass of the same kind, at 1/16 or less of the full-resolution cost.
    """
    B, C2, H, W = images.shape
    C = C2 // 2
    m = mask.to(images)[:, None].expand(2, C, H, W).reshape(1, C2, H, W)
    f = max(1, int(sigma // 4))
    if H % f or W % f:
        f = 1
    num, den = images * m, m
    if f > 1:
        num, den = F.avg_pool2d(num, f), F.avg_pool2d(den, f)
    k = gaussian_kernel1d(sigma / f).to(images)
    r = (k.numel() - 1) // 2

    def blur(x: Tensor) -> Tensor:  # separable, depthwise, zero outside the image: (N, C2, h, w) -> same
        n = x.shape[1]
        x = F.conv2d(F.pad(x, (r, r, 0, 0)), k.view(1, 1, 1, -1).expand(n, 1, 1, -1), groups=n)
        x = F.conv2d(F.pad(x, (0, 0, r, r)), k.view(1, 1, -1, 1).expand(n, 1, -1, 1), groups=n)
        return F.interpolate(x, size=(H, W), mode="bilinear", align_corners=False) if f > 1 else x

    num, den = blur(num), blur(den)
    return torch.where(m > 0, num / den.clamp_min(1e-12), torch.zeros_like(num))


# ----------------------------------------------------------------------------- metric


def edge_jump(pred: Tensor, gt: Tensor, edges: Tensor) -> Tensor:
    """Mean over edges of |(p_a - p_b) - (g_a - g_b)|: the discontinuity an edge carries that gt lacks.

    pred, gt: (B, V, 3); edges: (E, 2) -> (B,) in the inputs' units.
    """
    if edges.numel() == 0:
        return pred.new_zeros(pred.shape[0])
    d = (pred[:, edges[:, 0]] - pred[:, edges[:, 1]]) - (gt[:, edges[:, 0]] - gt[:, edges[:, 1]])
    return d.norm(dim=-1).mean(1)


def patch_disagreement(crops: Tensor, origins: Tensor, vertex_pix: Tensor, edges: Tensor,
                       vertex_patch: Tensor) -> Tensor:
    """Jump between neighbouring patches' own predictions before blending.

    For each seam edge (a, b) with patches (p, q), both vertices are read from both crops; the value
    is the mean of |crop_p(a) - crop_q(a)| and |crop_p(b) - crop_q(b)|. Only edges that lie in the
    same chart as both patches make sense; callers pass those. crops (B, P, C, h, w) -> (B,).
    """
    if edges.numel() == 0:
        return crops.new_zeros(crops.shape[0])
    a, b = edges[:, 0], edges[:, 1]
    p, q = vertex_patch[a], vertex_patch[b]
    verts = torch.cat([a, a, b, b])
    ids = torch.cat([p, q, p, q])
    vals = sample_crops(crops, ids, vertex_pix[verts], origins)  # (B, 4E, C)
    E = a.shape[0]
    ja = (vals[:, :E] - vals[:, E:2 * E]).norm(dim=-1)
    jb = (vals[:, 2 * E:3 * E] - vals[:, 3 * E:]).norm(dim=-1)
    return 0.5 * (ja + jb).mean(1)


# ----------------------------------------------------------------------------- stitcher


@dataclass
class Stitcher:
    """Crops -> per-vertex offsets under any seam method (all pure over the batch).

    assembler: crops -> images at the patch resolution; sample: images (B, 6, H, W) -> (B, V, 3)
    offsets; `fold` optionally precomputes sample∘assemble as one sparse matrix for a fast `average`;
    vertex_band: (V,) seam band weight at each vertex's sample position;
    image_band: (2, H, W) bool band for inpainting; fill_index: from `nearest_fill_index`;
    pca: basis of whole-garment offsets; pca_band_only: filter only in the band;
    render: (B, V, 3) offsets -> (B, 6, H, W) images (hierarchy_detail draws the whole model's offsets
    at the patch resolution with it); detail_sigma: px of the low-pass that splits base from detail;
    coverage: (2, H, W) bool pixels any crop covers (where the low-pass is taken).
    """

    assembler: Assembler
    sample: Callable[[Tensor], Tensor]
    vertex_band: Tensor
    image_band: np.ndarray
    fill_index: np.ndarray | None = None
    pca: PCABasis | None = None
    pca_band_only: bool = True
    pca_components: int | None = None
    folded: Tensor | None = None  # sparse CSR (V, P*h*w), the same for every channel
    render: Callable[[Tensor], Tensor] | None = None
    detail_sigma: float = 16.0
    coverage: Tensor | None = None
    cage: Callable[[Tensor], Tensor] | None = None  # CageSeams: crops -> (B, V, 3)
    # builds `cage` on the first `cage` call: the cage basis costs ~1.7 s on the full shirt, and only
    # that method needs it
    cage_builder: Callable[[], Callable[[Tensor], Tensor]] | None = None

    def to(self, device) -> Stitcher:
        """Move this stitcher's tensors to `device`, in place (the `sample`/`render` operators already work
        on any device; inpaint runs its solve on the CPU and comes back). Same device: nothing is copied."""
        self.assembler = self.assembler.to(device)
        for name in ("vertex_band", "folded", "coverage"):
            v = getattr(self, name)
            if v is not None and v.device != torch.device(device):
                setattr(self, name, v.to(device))
        if self.pca is not None and self.pca.mean.device != torch.device(device):
            self.pca = self.pca.to(device)
        return self

    def fold(self, sample_matrix: Tensor) -> None:
        """Precompute sample∘assemble as one sparse (V, P*h*w) matrix (same for every channel).

        sample_matrix: sparse (V, 2*H*W) whose column side*H*W + pixel reads that side's pixel.
        """
        folded = torch.sparse.mm(sample_matrix.coalesce(), self.assembler.matrix())
        self.folded = folded.coalesce().to_sparse_csr()

    def average(self, crops: Tensor) -> Tensor:
        """crops (B, P, 3, h, w) -> (B, V, 3) offsets through the feathered blend."""
        if self.folded is not None:
            B, P, C, h, w = crops.shape
            x = crops.permute(1, 3, 4, 0, 2).reshape(P * h * w, B * C)
            return (self.folded @ x).view(-1, B, C).transpose(0, 1)
        return self.sample(self.assembler.images(crops))

    def base_plus_detail(self, patches: Tensor, base: Tensor) -> Tensor:
        """low-pass(base) + patches - low-pass(patches): (B, 6, H, W) each -> (B, 6, H, W).

        Both low-passes use the same mask (the crops' coverage), so patches equal to the base plus any
        smooth field give back the base plus that field's high frequencies only.
        """
        lo_base = masked_blur(base, self.coverage, self.detail_sigma)
        lo_patch = masked_blur(patches, self.coverage, self.detail_sigma)
        return lo_base + patches - lo_patch

    def __call__(self, crops: Tensor, method: str = "average", whole: Tensor | None = None) -> Tensor:
        """crops (B, P, 3, h, w); whole: (B, V, 3) whole-model offsets (hierarchy) -> (B, V, 3)."""
        if method == "average":
            return self.average(crops)
        if method == "pca":
            if self.pca is None:
                raise ValueError("stitch=pca needs a PCA basis (fit one on the training split)")
            raw = self.average(crops)
            filt = project(self.pca, raw, self.pca_components)
            return blend_in_band(raw, filt, self.vertex_band) if self.pca_band_only else filt
        if method == "inpaint":
            img = inpaint_band(self.assembler.images(crops), self.image_band, self.fill_index)
            return self.sample(img)
        if method == "hierarchy":
            if whole is None:
                raise ValueError("stitch=hierarchy needs the whole-shirt model's prediction")
            return blend_in_band(self.average(crops), whole, self.vertex_band)
        if method == "hierarchy_detail":
            if whole is None or self.render is None or self.coverage is None:
                raise ValueError("stitch=hierarchy_detail needs the whole-shirt model's prediction and a renderer")
            return self.sample(self.base_plus_detail(self.assembler.images(crops), self.render(whole)))
        if method == "cage":
            if self.cage is None and self.cage_builder is not None:
                self.cage = self.cage_builder()
            if self.cage is None:
                raise ValueError("stitch=cage needs the cage basis (build the stitcher with build_stitcher)")
            return self.cage(crops)
        raise ValueError(f"unknown seam method {method!r}; choose one of {METHODS}")


def build_stitcher(ops, crops, garment, cage, cfg, pca: PCABasis | None = None) -> Stitcher:
    """A `Stitcher` for one garment at the patch resolution.

    ops: `ImageOperators` at the patch resolution; crops: its P `PatchCrop`s, one per cage patch (id order);
    cfg: a `conf/stitch/*.yaml` node (feather_ramp, band_width, pca_components, pca_band_only,
    detail_sigma).
    """
    H = W = ops.res
    masks = torch.stack([c.mask for c in crops])
    windows = torch.tensor([c.window[:2] for c in crops])
    sides = torch.tensor([c.side for c in crops])
    asm = Assembler.build(feather_weights(masks, float(cfg.feather_ramp)), windows, sides, (H, W))
    vp = vertex_patch_ids([p.vertices for p in cage.patches], garment.vertices.shape[0])
    curves = seam_curve_mask(garment.faces, garment.face_uv, garment.face_side, garment.uv, vp, (H, W))
    weight = band_weight(curves, float(cfg.band_width))  # (2, H, W)
    image_band = (weight.numpy() > 0) & ops.mask.numpy()
    weight6 = weight[:, None].expand(2, 3, H, W).reshape(1, 6, H, W)
    vertex_band = ops.sample(weight6)[0, :, 0]
    tensor = tensor_from_config(cfg)  # checked now: a bad anisotropy is an error at build, not first use
    st = Stitcher(asm, ops.sample, vertex_band, image_band,
                  fill_index=nearest_fill_index(asm.coverage().numpy()), pca=pca,
                  pca_band_only=bool(cfg.pca_band_only),
                  pca_components=None if cfg.pca_components is None else int(cfg.pca_components),
                  render=ops.render, detail_sigma=float(cfg.detail_sigma), coverage=asm.coverage(),
                  cage_builder=lambda: CageSeams(garment, cage, crops, ops.res, tensor))
    S = ops.scipy_S().tocoo()
    st.fold(torch.sparse_coo_tensor(torch.from_numpy(np.stack([S.row, S.col]).astype(np.int64)),
                                    torch.from_numpy(S.data.astype(np.float32)), S.shape, check_invariants=False))
    st.curves, st.vertex_patch = curves, vp
    return st
