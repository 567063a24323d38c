"""Cage Poisson blendshapes (appendix C, Figs. 4-7): fill a patch's interior from its cage.

One job: per patch, the basis function of every cage vertex, the solution of a Laplace equation
div(D grad phi) = 0 on the patch's flat sewing pattern with phi = 1 at that cage vertex and 0 at the
others; then any perturbation of the cage (offsets in texture and normal coordinates) is carried into
the interior as `interior = W @ cage_values`.

- The operator is linear finite elements on the patch's triangles in its UV chart (metres: uv * uv_scale):
  K_ij = sum_T area_T grad(phi_i)^T D grad(phi_j). D = I is the isotropic (cotangent) Laplacian; a
  constant anisotropic D = R(angle) diag(1, ratio) R(angle)^T spreads a boundary perturbation along the
  angle (u axis at 0 deg) and damps it across (ratio < 1): appendix Fig. 4c.
- The cage of a patch is its vertices on a seam edge (an edge to another patch) plus any vertex in none
  of its own triangles. Vertices on an opening (hem, neck, cuff) that is not a seam keep the natural
  (zero-flux) boundary condition.
- Properties (tests/test_cage_basis.py): the basis sums to 1 at every interior vertex (partition of unity:
  K annihilates constants); with D constant and the whole boundary in the cage, it reproduces linear
  functions exactly on a flat patch; cage values are reproduced exactly (they are the Dirichlet data).

Two uses: `reconstruction_error` (how much of a patch is its cage, on a dataset) and `CageSeams`, the
`stitch.method=cage` seam method: every cage vertex gets one agreed value (the mean of what each patch
that can see it predicts there), and each patch's own prediction is corrected by the basis fill of the
difference between the agreed and its own cage values, so the patches meet without a seam.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from torch import Tensor


def anisotropic_tensor(ratio: float = 1.0, angle_deg: float = 0.0) -> np.ndarray:
    """D = R diag(1, ratio) R^T (2, 2): conductivity 1 along `angle_deg` from the u axis, `ratio` across."""
    if ratio <= 0:
        raise ValueError(f"the anisotropy ratio must be > 0 (1 = isotropic), got {ratio}")
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return R @ np.diag([1.0, float(ratio)]) @ R.T


def fem_stiffness(points: np.ndarray, faces: np.ndarray, tensor: np.ndarray | None = None) -> sp.csr_matrix:
    """Linear-FEM stiffness of div(D grad u) on a flat triangle mesh.

    points (n, 2), faces (f, 3), tensor (2, 2) symmetric positive definite (None = identity) -> (n, n) CSR,
    symmetric, rows summing to 0. Degenerate triangles contribute nothing.
    """
    D = np.eye(2) if tensor is None else np.asarray(tensor, np.float64)
    p = np.asarray(points, np.float64)[faces]  # (f, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-18
    area = 0.5 * np.abs(det)
    # gradients of the 3 hat functions: rows of inv([e1 e2]^T) applied to (-1,-1), (1,0), (0,1)
    inv = np.zeros((len(faces), 2, 2))
    inv[ok] = np.linalg.inv(np.stack([e1, e2], 1)[ok])  # (f, 2, 2): inv of rows e1, e2
    ref = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # d(phi)/d(bary coords)
    grads = np.einsum("kc,fdc->fkd", ref, inv)  # (f, 3, 2)
    local = np.einsum("fid,de,fje->fij", grads, D, grads) * area[:, None, None]
    local[~ok] = 0.0
    rows = np.repeat(faces, 3, axis=1).reshape(-1)
    cols = np.tile(faces, (1, 3)).reshape(-1)
    n = len(points)
    return sp.csr_matrix((local.reshape(-1), (rows, cols)), shape=(n, n))


def harmonic_basis(points: np.ndarray, faces: np.ndarray, cage: np.ndarray,
                   tensor: np.ndarray | None = None) -> np.ndarray:
    """Basis functions of the cage vertices at the other vertices of a flat mesh.

    points (n, 2), faces (f, 3), cage (c,) local vertex ids -> W (n - c, c) over the non-cage vertices in
    increasing id order: column k solves K phi = 0 off the cage with phi = 1 at cage[k], 0 at the rest.
    """
    n = len(points)
    cage = np.asarray(cage, np.int64)
    free = np.setdiff1d(np.arange(n), cage)
    if len(free) == 0:
        return np.zeros((0, len(cage)))
    if len(cage) == 0:
        raise ValueError("a patch without cage vertices has no boundary condition: its basis is undefined")
    K = fem_stiffness(points, faces, tensor).tocsr()
    K_ff = K[free][:, free].tocsc()
    K_fc = K[free][:, cage]
    try:
        lu = spla.splu(K_ff)
    except RuntimeError as err:  # a free vertex whose component touches no cage vertex
        raise ValueError("the patch has interior vertices not connected to its cage (singular Laplacian); "
                         "add a cage vertex to every connected piece of the patch") from err
    return lu.solve(-K_fc.toarray())


@dataclass
class PatchBasis:
    """The cage basis of one patch. Vertex ids are garment ids."""

    patch_id: int
    cage: np.ndarray  # (c,) cage vertex ids
    interior: np.ndarray  # (m,) the patch's other vertices
    weights: np.ndarray  # (m, c) basis values: interior = weights @ cage values
    points: np.ndarray  # (n, 2) flat pattern positions (metres) of cage then interior vertices
    faces: np.ndarray  # (f, 3) the patch's own triangles, indices into `points`

    def fill(self, cage_values: Tensor) -> Tensor:
        """cage_values (..., c, C) -> interior values (..., m, C)."""
        W = torch.as_tensor(self.weights, dtype=cage_values.dtype, device=cage_values.device)
        return torch.einsum("mc,...cd->...md", W, cage_values)


def chart_positions(garment) -> np.ndarray:
    """(V, 2, 2) uv of every vertex in each chart (NaN where the vertex is not in that chart)."""
    faces = np.asarray(garment.faces, np.int64)
    fuv = np.asarray(garment.face_uv, np.int64)
    side = np.asarray(garment.face_side, np.int64)
    uv = np.asarray(garment.uv, np.float64)
    out = np.full((garment.vertices.shape[0], 2, 2), np.nan)
    for c in range(3):
        out[faces[:, c], side] = uv[fuv[:, c]]
    return out


def patch_cages(garment, cage) -> list[np.ndarray]:
    """Per patch: its vertices on an edge to another patch, or in none of its own triangles (sorted ids)."""
    V = garment.vertices.shape[0]
    vp = cage.vertex_patch(V)
    faces = np.asarray(garment.faces, np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    cross = vp[e[:, 0]] != vp[e[:, 1]]
    on_seam = np.zeros(V, bool)
    on_seam[e[cross].reshape(-1)] = True
    fside = np.asarray(garment.face_side, np.int64)
    out = []
    for p in cage.patches:
        own = np.all(vp[faces] == p.id, axis=1) & (fside == p.side)
        in_face = np.zeros(V, bool)
        in_face[faces[own].reshape(-1)] = True
        v = np.asarray(p.vertices, np.int64)
        out.append(np.sort(v[on_seam[v] | ~in_face[v]]))
    return out


def build_cage_basis(garment, cage, tensor: np.ndarray | None = None) -> list[PatchBasis]:
    """The cage basis of every patch of a garment (flat pattern in metres, `tensor` as in `fem_stiffness`)."""
    V = garment.vertices.shape[0]
    vp = cage.vertex_patch(V)
    faces = np.asarray(garment.faces, np.int64)
    fside = np.asarray(garment.face_side, np.int64)
    chart = chart_positions(garment) * float(garment.uv_scale)
    cages = patch_cages(garment, cage)
    out = []
    for p, cg in zip(cage.patches, cages, strict=True):
        verts = np.asarray(p.vertices, np.int64)
        interior = np.sort(np.setdiff1d(verts, cg))
        order = np.concatenate([cg, interior])
        local = -np.ones(V, np.int64)
        local[order] = np.arange(len(order))
        own = np.all(vp[faces] == p.id, axis=1) & (fside == p.side)
        f = local[faces[own]]
        pts = chart[order, p.side]
        pts = np.where(np.isnan(pts), 0.0, pts)  # only cage vertices (in no own face) can lack a uv here
        W = harmonic_basis(pts, f, np.arange(len(cg)), tensor)
        out.append(PatchBasis(int(p.id), cg, interior, W, pts, f))
    return out


def fill_from_cage(bases: list[PatchBasis], values: Tensor) -> Tensor:
    """Replace every patch's interior by the basis fill of its cage values: (B, V, C) -> (B, V, C)."""
    out = values.clone()
    for b in bases:
        if len(b.interior):
            out[:, torch.as_tensor(b.interior)] = b.fill(values[:, torch.as_tensor(b.cage)])
    return out


def reconstruction_error(bases: list[PatchBasis], offsets: Tensor, mean: Tensor | None = None) -> dict:
    """How much of a patch is its cage: the error of filling each interior from the true cage offsets.

    offsets (B, V, 3) local (du, dv, dn) offsets; mean (V, 3): if given, the fill is mean + basis fill of
    (offsets - mean) (the cage carries the pose-dependent part only). Distances are in the offsets' units
    (frames are orthonormal, so they equal 3D vertex distances). Returns per-patch and overall means over
    interior vertices: error, the offsets' own size there, and the error of the constant-mean-of-cage fill.
    """
    x = offsets if mean is None else offsets - mean.to(offsets)[None]
    filled = fill_from_cage(bases, x)
    per_patch, err_all, base_all, size_all = [], [], [], []
    for b in bases:
        if not len(b.interior):
            continue
        i = torch.as_tensor(b.interior)
        e = (filled[:, i] - x[:, i]).norm(dim=-1)
        const = x[:, torch.as_tensor(b.cage)].mean(1, keepdim=True)
        e0 = (const - x[:, i]).norm(dim=-1)
        s = x[:, i].norm(dim=-1)
        per_patch.append({"patch": b.patch_id, "interior": len(b.interior), "cage": len(b.cage),
                          "error": float(e.mean()), "const_error": float(e0.mean()), "size": float(s.mean())})
        err_all.append(e.reshape(-1))
        base_all.append(e0.reshape(-1))
        size_all.append(s.reshape(-1))
    e, e0, s = torch.cat(err_all), torch.cat(base_all), torch.cat(size_all)
    return {"error": float(e.mean()), "error_p95": float(e.quantile(0.95)), "const_error": float(e0.mean()),
            "size": float(s.mean()), "per_patch": per_patch}


# ----------------------------------------------------------------------------- the seam method
class CageSeams:
    """`stitch.method=cage`: agreed cage values carried into each patch as a harmonic correction.

    Built once per garment from its patch crops (`PatchCrop`s of the patch-resolution operators).
    Every cage vertex v of patch p is read by p and by each patch q across a seam edge from v whose crop
    sees v in q's chart, inside q's trusted mask; the agreed value is the mean of those readings. Patch p's
    result is its own reading plus the basis fill of (agreed - own) on its cage: cage vertices get the
    agreed value, interior vertices a smooth correction that vanishes where the patches already agree.
    """

    def __init__(self, garment, cage, crops, resolution: int, tensor: np.ndarray | None = None):
        from pbc.stitch.seams import uv_to_pixel

        self.bases = build_cage_basis(garment, cage, tensor)
        V = garment.vertices.shape[0]
        vp = cage.vertex_patch(V)
        chart = chart_positions(garment)
        faces = np.asarray(garment.faces, np.int64)
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = np.concatenate([e, e[:, ::-1]])
        origins = np.array([c.window[:2] for c in crops])
        size = crops[0].window[2]
        reads_v, reads_p, reads_pix = [], [], []

        def can_read(q: int, v: int) -> np.ndarray | None:
            uv = chart[v, crops[q].side]
            if np.isnan(uv).any():
                return None
            pix = uv_to_pixel(torch.from_numpy(uv), (resolution, resolution)).numpy()
            r, c = np.rint(pix - origins[q]).astype(int)
            if not (0 <= r < size and 0 <= c < size) or not bool(crops[q].mask[r, c]):
                return None
            return pix

        # own reading of every vertex: its patch's crop at its position in that patch's chart
        sides = np.array([c.side for c in crops])
        own_uv = chart[np.arange(V), sides[vp]]
        reads_v += list(range(V))
        reads_p += vp.tolist()
        reads_pix += list(uv_to_pixel(torch.from_numpy(own_uv), (resolution, resolution)).numpy())
        self.num_own = V
        cage_ids = np.concatenate([b.cage for b in self.bases])
        nbrs: dict[int, set] = {}
        for a, b in e:
            if vp[a] != vp[b]:
                nbrs.setdefault(int(a), set()).add(int(vp[b]))
        for v in cage_ids:
            for q in sorted(nbrs.get(int(v), ())):
                pix = can_read(q, int(v))
                if pix is not None:
                    reads_v.append(int(v))
                    reads_p.append(q)
                    reads_pix.append(pix)
        self.read_vertex = torch.as_tensor(np.asarray(reads_v, np.int64))
        self.read_patch = torch.as_tensor(np.asarray(reads_p, np.int64))
        # bilinear taps of every reading as flat indices into the (P * size * size) crops, precomputed so a
        # batch costs one gather (pixel centres at integer (row, col); taps outside the crop weigh 0)
        local = np.stack(reads_pix) - origins[np.asarray(reads_p)]
        r0, c0 = np.floor(local[:, 0]), np.floor(local[:, 1])
        fr, fc = local[:, 0] - r0, local[:, 1] - c0
        rows = np.stack([r0, r0, r0 + 1, r0 + 1], 1).astype(np.int64)
        cols = np.stack([c0, c0 + 1, c0, c0 + 1], 1).astype(np.int64)
        w = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], 1)
        inside = (rows >= 0) & (rows < size) & (cols >= 0) & (cols < size)
        flat = (np.asarray(reads_p)[:, None] * size * size + np.clip(rows, 0, size - 1) * size
                + np.clip(cols, 0, size - 1))
        self.tap_index = torch.as_tensor(flat)
        self.tap_weight = torch.as_tensor(np.where(inside, w, 0.0)).float()
        counts = torch.zeros(V).index_add_(0, self.read_vertex, torch.ones(len(reads_v)))
        self.readers = counts  # (V,) how many patches read each vertex (1 = its own patch only)
        # a front/back seam vertex read in its other chart: exact sampling (S R = I) holds only in the
        # chart it is sampled from, so that reading carries the representation floor (~0.05 cm at 256)
        rs = np.array([c.side for c in crops])[np.asarray(reads_p)]
        other = rs != np.asarray(garment.vertex_side)[np.asarray(reads_v)]
        self.cross_chart = torch.zeros(V, dtype=torch.bool)
        self.cross_chart[torch.as_tensor(np.asarray(reads_v)[other], dtype=torch.long)] = True
        self.num_vertices = V

    def agreed(self, crops: Tensor) -> tuple[Tensor, Tensor]:
        """crops (B, P, 3, h, w) -> own readings (B, V, 3) and agreed values (B, V, 3) (mean of readers)."""
        B, P, C, h, w = crops.shape
        flat = crops.permute(0, 2, 1, 3, 4).reshape(B, C, P * h * w)
        taps = flat[:, :, self.tap_index.to(crops.device)]  # (B, C, R, 4)
        vals = (taps * self.tap_weight.to(crops)).sum(-1).transpose(1, 2)  # (B, R, C)
        own = vals[:, : self.num_own]
        total = crops.new_zeros(crops.shape[0], self.num_vertices, vals.shape[-1])
        total = total.index_add(1, self.read_vertex.to(crops.device), vals)
        return own, total / self.readers.to(crops)[None, :, None]

    def __call__(self, crops: Tensor) -> Tensor:
        """crops (B, P, 3, h, w) -> (B, V, 3) offsets."""
        own, agreed = self.agreed(crops)
        out = own.clone()
        for b in self.bases:
            cg = torch.as_tensor(b.cage, device=crops.device)
            delta = agreed[:, cg] - own[:, cg]
            out[:, cg] = agreed[:, cg]
            if len(b.interior):
                it = torch.as_tensor(b.interior, device=crops.device)
                out[:, it] = own[:, it] + b.fill(delta)
        return out


def tensor_from_config(cfg) -> np.ndarray:
    """D of a stitch config: `cage_anisotropy` (ratio across / along, 1 = isotropic) and `cage_angle_deg`."""
    return anisotropic_tensor(float(cfg.get("cage_anisotropy", 1.0)), float(cfg.get("cage_angle_deg", 0.0)))


# ----------------------------------------------------------------------------- tool: how much is the cage
def dataset_offsets(ds, indices: np.ndarray, space: str = "local", batch: int = 32) -> Tensor:
    """The local offsets (B, V, 3) of dataset samples (draped cloth vs. its skinned cloth pixels)."""
    from pbc.pixels.frames import to_offsets
    from pbc.pixels.reconstruct import Skinner

    skin = Skinner(ds.body, ds.garment, ds.embedding)
    out = []
    with torch.inference_mode():
        for i in range(0, len(indices), batch):
            j = np.asarray(indices[i:i + batch])
            anchors, frames = skin(torch.from_numpy(np.array(ds.poses[j], np.float32)))
            out.append(to_offsets(torch.from_numpy(np.array(ds.verts[j], np.float32)), anchors, frames, space))
    return torch.cat(out)


def figure4(path, basis_iso: PatchBasis, basis_aniso: PatchBasis, label: str) -> None:
    """Appendix Figs. 4-6: boundary perturbations (two bumps; a sine wave) carried into one patch by the
    isotropic and the anisotropic basis, drawn as height fields over the patch's flat pattern."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pbc.io import save_figure

    pts, faces, c = basis_iso.points, basis_iso.faces, len(basis_iso.cage)
    cage = pts[:c]
    centre, span = cage.mean(0), np.ptp(cage, 0).max()
    ang = np.arctan2(cage[:, 1] - centre[1], cage[:, 0] - centre[0])
    top = cage[:, 1].min()  # v grows downwards: the patch's top edge has the smallest v
    bumps = sum(np.exp(-((cage[:, 0] - x) ** 2 + (cage[:, 1] - top) ** 2) / (2 * (0.07 * span) ** 2))
                for x in cage[:, 0].min() + np.array([0.35, 0.65]) * np.ptp(cage[:, 0]))
    sine = np.sin(6 * ang)
    rows = [("two bumps on the boundary (Fig. 5)", 0.02 * bumps), ("sine wave on the boundary (Fig. 6)", 0.01 * sine)]
    fig = plt.figure(figsize=(11, 6.6))
    for r, (name, vals) in enumerate(rows):
        v = torch.from_numpy(vals)[:, None]
        fills = [np.r_[vals, np.zeros(len(pts) - c)],
                 np.r_[vals, basis_iso.fill(v)[:, 0].numpy()],
                 np.r_[vals, basis_aniso.fill(v)[:, 0].numpy()]]
        titles = ["(a) boundary perturbation", "(b) isotropic basis", f"(c) anisotropic basis ({label})"]
        for k, (h, t) in enumerate(zip(fills, titles, strict=True)):
            ax = fig.add_subplot(2, 3, 3 * r + k + 1, projection="3d")
            ax.plot_trisurf(pts[:, 0], -pts[:, 1], h * 100, triangles=faces, cmap="viridis", linewidth=0.1,
                            edgecolor=(0, 0, 0, 0.15), vmin=float(vals.min()) * 100, vmax=float(vals.max()) * 100)
            if k == 0:
                ax.scatter(cage[:, 0], -cage[:, 1], vals * 100, c="r", s=4)
            ax.set_title(f"{t}\n{name}" if k == 0 else t, fontsize=8)
            ax.set_zlabel("dn (cm)", fontsize=7)
            ax.tick_params(labelsize=5)
            ax.view_init(elev=35, azim=-60)
    save_figure(fig, path, dpi=90)


def seam_study(ds, image_cfg, stitch_cfg, bias_cm: float = 0.5, seed: int = 0, max_samples: int = 8) -> dict:
    """A controlled comparison of the seam methods: ground-truth crops, each patch's crop offset by its own
    random constant (std `bias_cm` per channel), stitched by average / pca / inpaint / cage.

    Known disagreement, no model: what each method does with crops that disagree at the seams.
    -> {method: {vertex_error_cm, seam_jump_cm, interior_jump_cm}} over the val + test samples.
    """
    from pbc.pixels.operators import ImageOperators, image_sizes
    from pbc.pixels.reconstruct import mesh_edges
    from pbc.stitch.pca import fit_pca
    from pbc.stitch.seams import build_stitcher, edge_jump, seam_edges

    sizes = image_sizes(image_cfg)
    ops = ImageOperators.for_garment(ds.garment, sizes["patch_resolution"], sizes["patch_pad"])
    crops = [ops.crop(p, sizes["crop_size"], sizes["margin"]) for p in ds.cage.patches]
    train = dataset_offsets(ds, ds.split("train")).float()
    st = build_stitcher(ops, crops, ds.garment, ds.cage, stitch_cfg,
                        pca=fit_pca(train, int(stitch_cfg.pca_components)))
    idx = np.concatenate([ds.split("val"), ds.split("test")])[:max_samples]
    gt = dataset_offsets(ds, idx).float()
    vp = st.vertex_patch
    seam = seam_edges(ds.garment.faces, vp)
    alle = mesh_edges(ds.garment.faces)
    interior = alle[vp[alle[:, 0]] == vp[alle[:, 1]]]
    g = torch.Generator().manual_seed(seed)
    bias = bias_cm / 100.0 * torch.randn(len(idx), len(crops), 3, generator=g)
    gt_crops = torch.stack([c.render(gt) for c in crops], 1)
    noisy = gt_crops + bias[..., None, None]
    out = {"samples": int(len(idx)), "bias_cm": bias_cm, "resolution": ops.res, "methods": {}}
    for m in ("average", "pca", "inpaint", "cage"):
        for name, c in (("biased", noisy), ("exact", gt_crops)):
            x = st(c, m)
            out["methods"].setdefault(m, {})[name] = {
                "vertex_error_cm": float((x - gt).norm(dim=-1).mean()) * 100,
                "seam_jump_cm": float(edge_jump(x, gt, seam).mean()) * 100,
                "interior_jump_cm": float(edge_jump(x, gt, interior).mean()) * 100}
    return out


def main(argv=None) -> int:
    """python -m pbc.stitch.cage_basis <dataset dir>: how much of each patch its cage explains, + Fig. 4."""
    import argparse
    import json
    from pathlib import Path

    from omegaconf import OmegaConf

    from pbc.data.dataset import load_dataset
    from pbc.io import write_json, write_text

    ap = argparse.ArgumentParser(prog="python -m pbc.stitch.cage_basis", description=main.__doc__)
    ap.add_argument("dataset", help="dataset directory (python -m pbc.generate)")
    ap.add_argument("--stitch", default=str(Path(__file__).resolve().parents[2] / "conf/stitch/cage.yaml"),
                    help="stitch config holding cage_anisotropy / cage_angle_deg (the anisotropic tensor)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--out", default="outputs/cage_basis")
    ap.add_argument("--figure-patch", type=int, default=None, help="patch drawn in Fig. 4 (default: most interior)")
    ap.add_argument("--seam-study", type=float, default=None, metavar="BIAS_CM",
                    help="also compare the seam methods on ground-truth crops offset per patch by BIAS_CM")
    ap.add_argument("--image", default=str(Path(__file__).resolve().parents[2] / "conf/image/default.yaml"),
                    help="image config of the seam study (resolutions, crop, margin, pad)")
    args = ap.parse_args(argv)
    ds = load_dataset(args.dataset)
    scfg = OmegaConf.load(args.stitch)
    if float(scfg.get("cage_anisotropy", 1.0)) == 1.0:
        # the config is isotropic: compare with a stated anisotropic tensor, 20x stronger along v (down the
        # patch) than along u, so a perturbation of the top edge runs down as folds (appendix Fig. 5)
        scfg = OmegaConf.merge(scfg, {"cage_anisotropy": 0.05, "cage_angle_deg": 90.0})
    tensors = {"isotropic": None, "anisotropic": tensor_from_config(scfg)}
    label = f"ratio {float(scfg.cage_anisotropy):g} at {float(scfg.cage_angle_deg):g} deg"
    idx = ds.split(args.split)
    if len(idx) == 0:
        raise ValueError(f"split {args.split!r} of {ds.dir} is empty")
    offs = dataset_offsets(ds, idx).double()
    mean = dataset_offsets(ds, ds.split("train")).double().mean(0)
    out = Path(args.out)
    res = {"dataset": str(ds.dir), "split": args.split, "samples": int(len(idx)),
           "vertices": int(ds.garment.vertices.shape[0]), "tensor_anisotropic": label, "results": {}}
    bases = {}
    for name, D in tensors.items():
        bases[name] = build_cage_basis(ds.garment, ds.cage, D)
        res["results"][name] = {"raw": reconstruction_error(bases[name], offs),
                                "train_mean_plus_fill": reconstruction_error(bases[name], offs, mean)}
    iso = bases["isotropic"]
    res["cage_vertices"] = int(sum(len(b.cage) for b in iso))
    res["interior_vertices"] = int(sum(len(b.interior) for b in iso))
    # the no-cage baseline: every interior vertex at the training mean
    interior = torch.as_tensor(np.concatenate([b.interior for b in iso]))
    res["train_mean_error"] = float((offs[:, interior] - mean[None, interior]).norm(dim=-1).mean())
    if args.seam_study is not None:
        st_cfg = OmegaConf.merge(OmegaConf.load(Path(args.stitch).parent / "average.yaml"), scfg, {"method": "cage"})
        res["seam_study"] = seam_study(ds, OmegaConf.load(args.image), st_cfg, args.seam_study)
    write_json(out / "cage_basis.json", res)
    lines = [f"# How much of a patch is its cage ({ds.dir.name}, {args.split}: {len(idx)} samples)", "",
             f"{res['interior_vertices']} interior vertices filled from {res['cage_vertices']} cage vertices "
             f"(28 patches); mean error over interior vertices, cm.", "",
             "| basis | fill of the offsets | mean + fill of (offsets - mean) | cage-mean constant "
             "| interior offset size |",
             "|---|---|---|---|---|"]
    for name, r in res["results"].items():
        a, b = r["raw"], r["train_mean_plus_fill"]
        lines.append(f"| {name} | {100 * a['error']:.3f} (p95 {100 * a['error_p95']:.3f}) | "
                     f"{100 * b['error']:.3f} (p95 {100 * b['error_p95']:.3f}) | {100 * a['const_error']:.3f} | "
                     f"{100 * a['size']:.3f} |")
    lines += ["", f"Training-mean offsets alone (no cage): {100 * res['train_mean_error']:.3f} cm.", ""]
    if "seam_study" in res:
        ss = res["seam_study"]
        lines += [f"## Seam methods on ground-truth crops offset per patch ({ss['bias_cm']} cm std per channel, "
                  f"{ss['samples']} val+test samples, {ss['resolution']} px)", "",
                  "| method | vertex error cm | seam jump cm | interior jump cm "
                  "| same, exact crops: vertex / seam cm |",
                  "|---|---|---|---|---|"]
        for m, r in ss["methods"].items():
            b, e = r["biased"], r["exact"]
            lines.append(f"| {m} | {b['vertex_error_cm']:.4f} | {b['seam_jump_cm']:.4f} | "
                         f"{b['interior_jump_cm']:.4f} | {e['vertex_error_cm']:.4f} / {e['seam_jump_cm']:.4f} |")
        lines.append("")
    write_text(out / "cage_basis.md", "\n".join(lines))
    k = args.figure_patch if args.figure_patch is not None else int(np.argmax([len(b.interior) for b in iso]))
    figure4(out / "fig4_cage_basis.png", iso[k], bases["anisotropic"][k], label)
    print("\n".join(lines))
    print(json.dumps({"out": str(out)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
