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

Two uses: `reconstruction_error` (how much of a patch is its cage, on a dataset: the tool
`python -m pbc.stitch.cage_study`) and `CageSeams`, the
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

from pbc.stitch.crops import uv_to_pixel


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
