"""The linear maps between cloth pixels (per-vertex values) and cloth images, built once per garment.

One job: precompute the sparse render operator R (vertices -> pixels) and sample operator S
(pixels -> vertices) of a garment at one resolution, cache them on disk, and apply them batched.

Image layout: `(B, 6, H, W)`, channels (du, dv, dn) of the front chart (side 0) then of the back
(side 1); pixel (r, c) has its centre at uv = ((c + 0.5) / W, (r + 0.5) / H) (u -> column, v -> row).

R is built in three linear steps (so it stays one sparse matrix):
  1. rasterise: every pixel centre inside a UV triangle gets the barycentric blend of its 3 vertices;
  2. pad: pixels within `pad` px outside a chart copy the row of their nearest chart pixel, so the
     CNN's filters see a smooth edge (paper Fig. 2);
  3. make the round trip exact (`exact=True`): bilinear sampling of a piecewise-linear image is not
     exact at the vertices, where the field has kinks (error ~ pixel size x slope jump, ~0.01-0.1 cm
     at 512). The residual I - S R is pushed back into the <= 4 pixels each vertex samples, in
     proportion to its bilinear weights (minimum-norm correction), iterated until S R = I to float
     precision. Only the 2x2 pixel blocks around vertices change, by O(pixel size x slope jump).
S is bilinear interpolation at each vertex's `vertex_uv` in its `vertex_side` chart.
A patch crop is a row subset of R (one side, a window of the `patch_resolution` image).
"""

from __future__ import annotations

import hashlib
import math
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch
from scipy import ndimage
from torch import Tensor

from pbc.core.io import atomic_path, is_writable_dir, out_of_space, user_cache_dir
from pbc.core.validate import FULL_IMAGE_WINDOW

OPERATOR_VERSION = 1
BOX_RESOLUTION = 512  # Patch.box_512 is a pixel box in a 512 image: the cage's contract (docs/interfaces.md)


def scaled_pixels(n: int, resolution: int, reference: int) -> int:
    """A pixel length given at the reference resolution, at `resolution` (at least 1)."""
    return max(1, int(round(n * resolution / reference)))


def image_sizes(image_cfg) -> dict:
    """Pixel sizes from the `image` config: crop_size, margin and pad are given at
    `reference_resolution` (512) and scale with the resolution they are used at.

    -> {whole_resolution, patch_resolution, whole_pad, patch_pad, crop_size, margin} (crop/margin at
    the patch resolution), whole_sides (chart sides a whole-garment model predicts, in channel order) and
    whole_rows (first, stop) (the band of rows of the whole image it predicts).
    """
    ref = int(image_cfg["reference_resolution"])
    whole, patch = int(image_cfg["whole_resolution"]), int(image_cfg["patch_resolution"])
    pad = int(image_cfg["pad"])
    rows = image_cfg.get("whole_rows", None) or FULL_IMAGE_WINDOW["whole_rows"]
    return {
        "whole_sides": tuple(int(s) for s in (image_cfg.get("whole_sides", None) or FULL_IMAGE_WINDOW["whole_sides"])),
        "whole_rows": (int(round(float(rows[0]) * whole)), int(round(float(rows[1]) * whole))),
        "whole_resolution": whole,
        "patch_resolution": patch,
        "whole_pad": scaled_pixels(pad, whole, ref),
        "patch_pad": scaled_pixels(pad, patch, ref),
        "crop_size": scaled_pixels(int(image_cfg["crop_size"]), patch, ref),
        "margin": scaled_pixels(int(image_cfg["margin"]), patch, ref),
    }


# ----------------------------------------------------------------------------------------- build
def rasterize(tri_uv: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel centres covered by UV triangles, vectorised over all triangles.

    tri_uv (F, 3, 2) in [0, 1]^2 -> pixel (M,) flat r * res + c, face (M,), bary (M, 3); a pixel on a
    shared edge is kept once, by the triangle it lies most inside.
    """
    xy = tri_uv.astype(np.float64) * res - 0.5  # pixel-index coordinates: centre of (r, c) at (c, r)
    lo = np.clip(np.ceil(xy.min(1) - 1e-9), 0, res - 1).astype(np.int64)
    hi = np.clip(np.floor(xy.max(1) + 1e-9), 0, res - 1).astype(np.int64)
    nx, ny = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nx * ny
    face = np.repeat(np.arange(len(xy)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    col = lo[face, 0] + k % nx[face]
    row = lo[face, 1] + k // nx[face]
    a, b, c = xy[face, 0], xy[face, 1], xy[face, 2]
    v0, v1 = b - a, c - a
    q = np.stack([col, row], 1) - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-15, np.nan, den)  # degenerate triangles cover nothing
    l1 = (q[:, 0] * v1[:, 1] - v1[:, 0] * q[:, 1]) / den
    l2 = (v0[:, 0] * q[:, 1] - q[:, 0] * v0[:, 1]) / den
    bary = np.stack([1 - l1 - l2, l1, l2], 1)
    inside = bary.min(1) >= -1e-7
    pix, face, bary = row[inside] * res + col[inside], face[inside], bary[inside]
    order = np.lexsort((-bary.min(1), pix))  # per pixel, most-inside triangle first
    pix, face, bary = pix[order], face[order], bary[order]
    first = np.r_[True, pix[1:] != pix[:-1]]
    return pix[first], face[first], np.clip(bary[first], 0.0, 1.0)


def bilinear_taps(uv: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation taps at uv (N, 2): pixel (N, 4) flat index, weight (N, 4)."""
    x, y = uv[:, 0] * res - 0.5, uv[:, 1] * res - 0.5
    x0 = np.clip(np.floor(x), 0, res - 2).astype(np.int64)
    y0 = np.clip(np.floor(y), 0, res - 2).astype(np.int64)
    fx, fy = np.clip(x - x0, 0, 1), np.clip(y - y0, 0, 1)
    pix = np.stack([y0 * res + x0, y0 * res + x0 + 1, (y0 + 1) * res + x0, (y0 + 1) * res + x0 + 1], 1)
    w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return pix, w


def _garment_arrays(garment) -> dict[str, np.ndarray]:
    def a(x, dtype):
        return np.ascontiguousarray(np.asarray(x.detach().cpu() if torch.is_tensor(x) else x, dtype=dtype))

    return {
        "faces": a(garment.faces, np.int64),
        "uv": a(garment.uv, np.float64),
        "face_uv": a(garment.face_uv, np.int64),
        "face_side": a(garment.face_side, np.int64),
        "vertex_uv": a(garment.vertex_uv, np.float64),
        "vertex_side": a(garment.vertex_side, np.int64),
    }


def operator_key(garment, resolution: int, pad: int, exact: bool) -> str:
    """Hash of everything R and S depend on: the garment's charts, resolution, pad, exactness, version."""
    h = hashlib.sha256(f"v{OPERATOR_VERSION}-{resolution}-{pad}-{int(exact)}".encode())
    for name, arr in _garment_arrays(garment).items():
        h.update(name.encode())
        h.update(np.round(arr, 9).tobytes() if arr.dtype == np.float64 else arr.tobytes())
    return h.hexdigest()[:16]


READBACK_TOL = 1e-3  # |S R - I| past this: a vertex's value does not survive rendering and sampling back


def build_operators(
    garment, resolution: int, pad: int, exact: bool = True, tol: float = 1e-7, max_iter: int = 50
) -> dict[str, np.ndarray]:
    """R (2*H*W x V) and S (V x 2*H*W) of `garment` as CSR arrays plus masks; pure numpy/scipy.

    Returns a dict of arrays (the on-disk cache format): R_indptr/R_indices/R_data, S_pix/S_w (V, 4)
    flat pixel index over (2, H, W) and weights, chart (2, H, W) and mask (2, H, W) bool (mask = the
    padded chart: every pixel R writes), label (2, H, W) int the dominant vertex of each chart pixel
    (-1 elsewhere), residual the final max |S R - I|.
    """
    g = _garment_arrays(garment)
    res, V = int(resolution), int(g["vertex_uv"].shape[0])
    hw = res * res
    rows, cols, vals = [], [], []
    chart = np.zeros((2, hw), bool)
    label = np.full((2, hw), -1, np.int64)
    for side in (0, 1):
        fs = np.nonzero(g["face_side"] == side)[0]
        if len(fs) == 0:  # a one-chart garment (the necktie): its back image stays empty
            continue
        pix, f, bary = rasterize(g["uv"][g["face_uv"][fs]], res)
        verts = g["faces"][fs][f]  # (M, 3)
        chart[side, pix] = True
        label[side, pix] = verts[np.arange(len(pix)), bary.argmax(1)]
        # Padding: each pixel within `pad` px outside the chart copies the row of its nearest chart
        # pixel (a nearest-neighbour extension, linear in the vertex values).
        src = np.full(hw, -1, np.int64)
        src[pix] = np.arange(len(pix))
        dist, (ri, ci) = ndimage.distance_transform_edt(~chart[side].reshape(res, res), return_indices=True)
        band = ((dist > 0) & (dist <= pad)).reshape(-1)
        band_pix = np.nonzero(band)[0]
        near = src[(ri.reshape(-1) * res + ci.reshape(-1))[band_pix]]
        all_pix = np.r_[pix, band_pix]
        all_src = np.r_[np.arange(len(pix)), near]
        rows.append(np.repeat(side * hw + all_pix, 3))
        cols.append(verts[all_src].reshape(-1))
        vals.append(bary[all_src].reshape(-1))
    R = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * hw, V))
    R.sum_duplicates()

    s_pix, s_w = bilinear_taps(g["vertex_uv"], res)
    s_pix = s_pix + g["vertex_side"][:, None] * hw
    S = sp.csr_matrix((s_w.reshape(-1), (np.repeat(np.arange(V), 4), s_pix.reshape(-1))), shape=(V, 2 * hw))
    eye = sp.identity(V, format="csr")
    residual = abs(eye - S @ R).max()
    if exact:
        # Kaczmarz-style minimum-norm correction of the sampled rows: R += S^T D (I - S R), D = 1/|S_v|^2.
        # One step is exact where vertices read disjoint pixels; a few more settle shared pixels.
        # Where vertices crowd a few pixels (a small chart at a low resolution) the steps can overshoot and
        # grow without bound: the correction keeps the best R it met and stops once the residual runs away.
        D = sp.diags(1.0 / np.square(s_w).sum(1))
        best, best_residual = R, residual
        for _ in range(max_iter):
            if residual < tol or not residual < 100.0 * best_residual:
                break
            E = eye - S @ R
            E.data[np.abs(E.data) < 1e-12] = 0.0
            E.eliminate_zeros()
            R = (R + S.T @ D @ E).tocsr()
            R.data[np.abs(R.data) < 1e-12] = 0.0
            R.eliminate_zeros()
            residual = abs(eye - S @ R).max()
            if residual < best_residual:
                best, best_residual = R, residual
        R, residual = best, best_residual
        if residual > READBACK_TOL:
            err = np.asarray(abs(eye - S @ R).max(axis=1).todense()).ravel()
            warnings.warn(f"at {res} x {res} px, {int((err > READBACK_TOL).sum())} of {V} garment vertices cannot be "
                          f"read back from the cloth images (largest error {residual:.2g}): their charts are too "
                          "small at this resolution; raise image.whole_resolution / image.patch_resolution",
                          stacklevel=2)
    R.sort_indices()
    mask = np.diff(R.indptr) > 0
    return {
        "R_indptr": R.indptr.astype(np.int64),
        "R_indices": R.indices.astype(np.int64),
        "R_data": R.data.astype(np.float64),
        "S_pix": s_pix.astype(np.int64),
        "S_w": s_w.astype(np.float64),
        "chart": chart.reshape(2, res, res),
        "mask": mask.reshape(2, res, res),
        "label": label.reshape(2, res, res),
        "residual": np.float64(residual),
        "resolution": np.int64(res),
        "pad": np.int64(pad),
        "num_vertices": np.int64(V),
    }


CACHE_KEYS = ("R_indptr", "R_indices", "R_data", "S_pix", "S_w", "chart", "mask", "label", "residual",
              "resolution", "pad", "num_vertices")


def _read_cache(path: Path, resolution: int) -> dict[str, np.ndarray] | None:
    """The cached operators at `path`, or None when absent, unreadable, truncated or incomplete."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None  # numpy raises a bare BadZipFile for a truncated file: it is only a cache
    if any(k not in arrays for k in CACHE_KEYS) or int(arrays["resolution"]) != resolution:
        return None
    return arrays


def cache_dirs(cache_dir: str | Path | None) -> list[Path]:
    """Where operators are looked for, in order: `cache_dir` (e.g. `<dataset>/operators`), then the user
    cache dir (pbc.core.io.user_cache_dir("operators"): $PBC_CACHE_DIR/operators, else ~/.cache/pbc/operators),
    which also takes them when `cache_dir` cannot (read-only, or a full disk that still looks writable)."""
    if cache_dir is None:
        return []
    user = user_cache_dir("operators")
    return [Path(cache_dir)] if Path(cache_dir).absolute() == user.absolute() else [Path(cache_dir), user]


_CACHE_WARNED: set[str] = set()  # cache targets already warned about in this process: one warning each


def load_or_build(
    garment, resolution: int, pad: int, exact: bool = True, cache_dir: str | Path | None = None
):
    """`build_operators`, cached as `operators_<hash>.npz` in `cache_dir` (atomic write).

    A corrupt or incomplete cache file is rebuilt and overwritten. When `cache_dir` cannot take the file
    (a dataset on read-only shared storage, or a full disk) the operators are cached in the user cache dir
    instead (`$PBC_CACHE_DIR/operators`, else ~/.cache/pbc/operators) and found there by later runs; when
    neither can, they are built in memory, with one warning per process.
    """
    dirs = cache_dirs(cache_dir)
    name = f"operators_{operator_key(garment, resolution, pad, exact)}.npz"
    for d in dirs:
        arrays = _read_cache(d / name, resolution)
        if arrays is not None:
            return arrays
        if (d / name).is_file() and is_writable_dir(d):
            break  # a corrupt file where it belongs: rebuilt and overwritten there, not shadowed by another copy
    arrays = build_operators(garment, resolution, pad, exact)
    failed = []
    for d in dirs:  # the dataset's dir first, then the user cache
        if not is_writable_dir(d):
            failed.append(f"{d} is not writable")
            continue
        try:
            with atomic_path(d / name, suffix=".npz") as tmp:
                np.savez(tmp, **arrays)
            return arrays
        except Exception as err:  # a full disk passes the writable test and fails here, maybe chained
            if not (isinstance(err, OSError) or out_of_space(err)):
                raise
            failed.append(f"{d}: {getattr(err, 'strerror', None) or err}")
    if failed and str(dirs[-1]) not in _CACHE_WARNED:
        _CACHE_WARNED.add(str(dirs[-1]))
        warnings.warn(f"cannot cache operators ({'; '.join(failed)}); they are rebuilt on every run: free space "
                      "there or set PBC_CACHE_DIR to a writable directory with room", stacklevel=2)
    return arrays


# ----------------------------------------------------------------------------------------- apply
@dataclass
class _Ell:
    """A sparse matrix as row buckets of padded rows (ELL): out[row] = sum_k w[:, k] * x[col[:, k]].

    Rows are bucketed by their entry count (3 for plain rasterised pixels, more for the few corrected
    ones) so the common rows do not pay for the widest one.
    """

    row: Tensor  # (P,) long, output index of every row, buckets concatenated
    cols: list[Tensor]  # per bucket (Pb, Kb) long
    ws: list[Tensor]  # per bucket (Pb, Kb) float

    def to(self, device) -> _Ell:
        return _Ell(self.row.to(device), [c.to(device) for c in self.cols], [w.to(device) for w in self.ws])

    def apply(self, xt: Tensor) -> Tensor:
        """xt (B, C, V) -> (B, C, P) row values, in `row` order."""
        return torch.cat(
            [(xt[:, :, c] * w.to(xt.dtype)).sum(-1) for c, w in zip(self.cols, self.ws, strict=True)], -1
        )


def _csr_to_ell(
    indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, rows: np.ndarray | None = None
) -> _Ell:
    counts = np.diff(indptr)
    nz = np.nonzero(counts)[0] if rows is None else rows[counts[rows] > 0]
    out_rows, cols, ws = [], [], []
    for sel in (counts[nz] <= 3, counts[nz] > 3):
        r = nz[sel]
        if not len(r) and out_rows:
            continue
        K = max(int(counts[r].max()) if len(r) else 1, 1)
        col = np.zeros((len(r), K), np.int64)
        w = np.zeros((len(r), K), np.float32)
        for k in range(K):
            has = counts[r] > k
            pos = indptr[r[has]] + k
            col[has, k], w[has, k] = indices[pos], data[pos]
        out_rows.append(r)
        cols.append(torch.from_numpy(col))
        ws.append(torch.from_numpy(w))
    return _Ell(torch.from_numpy(np.concatenate(out_rows).astype(np.int64)), cols, ws)


class ImageOperators:
    """R, S, masks and patch crops of one garment at one resolution, applied batched on any device.

    render(x (B, V, 3)) -> (B, 6, H, W);  sample(img (B, 6, H, W)) -> (B, V, 3);
    mask (2, H, W) bool padded chart (eq. 1's W); image_mask(device) (1, 6, H, W) float;
    crop_window(box, size) (r0, c0, size); crop(patch, crop_size, margin) -> PatchCrop.
    `method` picks the kernel: "gather" (index/weight gathers) or "sparse" (torch sparse CSR matmul).
    """

    def __init__(self, arrays: dict[str, np.ndarray], method: str = "gather"):
        self.arrays = arrays
        self.res = int(arrays["resolution"])
        self.V = int(arrays["num_vertices"])
        self.pad = int(arrays["pad"])
        self.residual = float(arrays["residual"])
        self.mask = torch.from_numpy(np.asarray(arrays["mask"], bool))
        self.chart = torch.from_numpy(np.asarray(arrays["chart"], bool))
        self.label = np.asarray(arrays["label"])
        if method not in ("gather", "sparse"):
            raise ValueError(f"unknown render method {method!r}; choose 'gather' or 'sparse'")
        self.method = method
        self._ell = _csr_to_ell(arrays["R_indptr"], arrays["R_indices"], arrays["R_data"])
        self._s_pix = torch.from_numpy(np.asarray(arrays["S_pix"], np.int64))
        self._s_w = torch.from_numpy(np.asarray(arrays["S_w"], np.float32))
        self._dev: dict = {}

    @classmethod
    def for_garment(
        cls, garment, resolution: int, pad: int, exact: bool = True, cache_dir=None, method="gather"
    ):
        """Build (or load from `cache_dir`) the operators of `garment` at `resolution`."""
        return cls(load_or_build(garment, resolution, pad, exact, cache_dir), method)

    def scipy_R(self) -> sp.csr_matrix:
        a = self.arrays
        return sp.csr_matrix((a["R_data"], a["R_indices"], a["R_indptr"]), shape=(2 * self.res**2, self.V))

    def scipy_S(self) -> sp.csr_matrix:
        V = self.V
        return sp.csr_matrix(
            (self.arrays["S_w"].reshape(-1), (np.repeat(np.arange(V), 4), self.arrays["S_pix"].reshape(-1))),
            shape=(V, 2 * self.res**2),
        )

    # per-device tensors, made on first use
    def _on(self, device) -> dict:
        key = str(device)
        if key not in self._dev:
            hw = self.res**2
            ell = self._ell.to(device)
            side, pix = ell.row // hw, ell.row % hw
            # flat index into (6 * H * W) for channel c of side s: (3 s + c) * HW + pix
            out_idx = ((3 * side)[None, :] + torch.arange(3, device=device)[:, None]) * hw + pix[None, :]
            side_v, pix_v = self._s_pix.to(device) // hw, self._s_pix.to(device) % hw  # (V, 4)
            in_idx = ((3 * side_v)[:, :, None] + torch.arange(3, device=device)) * hw + pix_v[:, :, None]
            d = {"ell": ell, "out_idx": out_idx.reshape(-1), "s_idx": in_idx, "s_w": self._s_w.to(device)}
            if self.method == "sparse":
                R = self.scipy_R().tocoo()
                # block-diagonal over the 3 channels so one matmul renders all 6 image channels; rows are
                # ordered (side, channel, pixel), i.e. already the (6, H, W) image layout
                side, pix = R.row // hw, R.row % hw
                rows = np.concatenate([(3 * side + c) * hw + pix for c in range(3)])
                cols = np.concatenate([c * self.V + R.col for c in range(3)])
                r6 = sp.csr_matrix((np.tile(R.data, 3), (rows, cols)), shape=(6 * hw, 3 * self.V))
                with warnings.catch_warnings():  # torch flags sparse CSR as beta on every construction
                    warnings.simplefilter("ignore", UserWarning)
                    d["R6"] = torch.sparse_csr_tensor(
                        torch.from_numpy(r6.indptr.astype(np.int64)),
                        torch.from_numpy(r6.indices.astype(np.int64)),
                        torch.from_numpy(r6.data.astype(np.float32)),
                        size=r6.shape,
                        check_invariants=False,
                    ).to(device)
            self._dev[key] = d
        return self._dev[key]

    def render(self, x: Tensor) -> Tensor:
        """Per-vertex values (B, V, 3) -> cloth images (B, 6, H, W); zero outside the padded charts."""
        B, res = x.shape[0], self.res
        d = self._on(x.device)
        if self.method == "sparse":
            y = torch.sparse.mm(d["R6"], x.permute(2, 1, 0).reshape(3 * self.V, B).to(d["R6"].dtype))
            # y is (6HW, B): its transpose is the batch as a view with the batch innermost in memory.
            # Not made contiguous on purpose: that copy cost 2x the matmul at 512 (bench/render.py), and
            # every consumer (masks, losses, crops, convolutions) accepts strided tensors.
            return y.t().reshape(B, 6, res, res)
        vals = d["ell"].apply(x.transpose(1, 2))  # (B, 3, P)
        out = x.new_zeros(B, 6 * res * res)
        out = out.index_copy(1, d["out_idx"], vals.reshape(B, -1))
        return out.view(B, 6, res, res)

    def sample(self, img: Tensor) -> Tensor:
        """Cloth images (B, 6, H, W) -> per-vertex values (B, V, 3), bilinear at the vertex UVs."""
        d = self._on(img.device)
        flat = img.reshape(img.shape[0], -1)
        taps = flat[:, d["s_idx"]]  # (B, V, 4, 3)
        return (taps * d["s_w"].to(img.dtype)[None, :, :, None]).sum(2)

    def image_mask(self, device=None, dtype=torch.float32) -> Tensor:
        """The padded chart mask as (1, 6, H, W): eq. 1's W, broadcast over the batch."""
        m = self.mask.to(device=device, dtype=dtype)
        return m[:, None].expand(2, 3, self.res, self.res).reshape(1, 6, self.res, self.res)

    # ------------------------------------------------------------------------------------ crops
    def crop_window(self, box_512: tuple[int, int, int, int], crop_size: int) -> tuple[int, int, int]:
        """(row0, col0, size): `crop_size` square (at this resolution) centred on the box, clamped inside."""
        s = self.res / BOX_RESOLUTION
        r0, c0, r1, c1 = (v * s for v in box_512)
        size = min(int(crop_size), self.res)
        top = int(math.floor((r0 + r1) / 2 - size / 2 + 0.5))
        left = int(math.floor((c0 + c1) / 2 - size / 2 + 0.5))
        return (min(max(top, 0), self.res - size), min(max(left, 0), self.res - size), size)

    def patch_pixels(self, patch) -> np.ndarray:
        """(H, W) bool: chart pixels of `patch`'s side whose dominant vertex belongs to the patch."""
        lab = self.label[patch.side]
        ids = np.zeros(self.V + 1, bool)
        ids[np.asarray(patch.vertices, np.int64)] = True
        return ids[np.where(lab < 0, self.V, lab)]

    def crop(self, patch, crop_size: int, margin: int) -> PatchCrop:
        """The crop operator of `patch`: a row subset of R plus its mask (patch pixels dilated by
        `margin` px, inside the padded chart), and the restriction of S to the patch's vertices."""
        r0, c0, size = self.crop_window(patch.box_512, crop_size)
        hw, side = self.res**2, int(patch.side)
        win = np.zeros((self.res, self.res), bool)
        win[r0 : r0 + size, c0 : c0 + size] = True
        rows = side * hw + np.nonzero(win.reshape(-1))[0]
        a = self.arrays
        ell = _csr_to_ell(a["R_indptr"], a["R_indices"], a["R_data"], rows)
        g = ell.row - side * hw
        local = (g // self.res - r0) * size + (g % self.res - c0)
        near = ndimage.distance_transform_edt(~self.patch_pixels(patch)) <= margin
        m = (near & self.mask[side].numpy())[r0 : r0 + size, c0 : c0 + size]
        verts = np.asarray(patch.vertices, np.int64)
        sp_ = np.asarray(a["S_pix"])[verts] - side * hw
        lr, lc = sp_ // self.res - r0, sp_ % self.res - c0
        if (lr < 0).any() or (lc < 0).any() or (lr >= size).any() or (lc >= size).any():
            raise ValueError(f"patch {patch.id}: its vertices fall outside its {size}px crop window")
        return PatchCrop(
            patch_id=int(patch.id),
            side=side,
            window=(r0, c0, size),
            ell=_Ell(local, ell.cols, ell.ws),
            mask=torch.from_numpy(m),
            vertices=torch.from_numpy(verts),
            s_pix=torch.from_numpy(lr * size + lc),
            s_w=torch.from_numpy(np.asarray(a["S_w"], np.float32)[verts]),
        )


@dataclass
class PatchCrop:
    """Render/sample operators of one patch crop (a `size` x `size` window of one side's image)."""

    patch_id: int
    side: int
    window: tuple[int, int, int]  # (row0, col0, size) in the patch-resolution image
    ell: _Ell  # rows index the flat (size * size) crop
    mask: Tensor  # (size, size) bool
    vertices: Tensor  # (Vk,) garment vertex ids of the patch
    s_pix: Tensor  # (Vk, 4) flat crop pixel
    s_w: Tensor  # (Vk, 4)

    def render(self, x: Tensor) -> Tensor:
        """Per-vertex values (B, V, 3) of the whole garment -> crop (B, 3, size, size)."""
        ell, size = self.ell.to(x.device), self.window[2]
        vals = ell.apply(x.transpose(1, 2))  # (B, 3, P)
        out = x.new_zeros(x.shape[0], 3, size * size)
        out[:, :, ell.row] = vals
        return out.view(x.shape[0], 3, size, size)

    def sample(self, crop: Tensor) -> Tensor:
        """Crop (B, 3, size, size) -> values at the patch's vertices (B, Vk, 3)."""
        flat = crop.reshape(crop.shape[0], 3, -1)
        taps = flat[:, :, self.s_pix.to(crop.device)]  # (B, 3, Vk, 4)
        return (taps * self.s_w.to(crop.device, crop.dtype)).sum(-1).transpose(1, 2)

    def image_mask(self, device=None, dtype=torch.float32) -> Tensor:
        """(1, 3, size, size) float crop mask, broadcast over the batch."""
        return self.mask.to(device=device, dtype=dtype)[None, None].expand(1, 3, *self.mask.shape)
