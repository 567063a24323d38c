"""How much of a patch is its cage, and the seam methods on known disagreement (appendix C, Figs. 4-7).

One job: the study of the cage Poisson blendshapes (`pbc.stitch.cage_basis`) on a dataset: the error of
filling each patch's interior from its true cage offsets (isotropic and anisotropic basis), Fig. 4, and
optionally a controlled comparison of the seam methods of `pbc.stitch.seams` on ground-truth crops offset
per patch. It sits above both modules (it builds a full stitcher), so the basis and the seams stay free of
each other. Operators and crops come from `pbc.pixels.target` (`image_operators` / `patch_crops`), the
offsets from a target's skinner, as in training.

    python -m pbc.stitch.cage_study <dataset dir> [--split test] [--seam-study 0.5] [--out outputs/cage_basis]
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch import Tensor  # noqa: E402

from pbc.core.io import save_figure  # noqa: E402
from pbc.pixels.reconstruct import mesh_edges  # noqa: E402
from pbc.pixels.target import image_operators, make_target, patch_crops  # noqa: E402
from pbc.stitch.cage_basis import PatchBasis  # noqa: E402
from pbc.stitch.pca import fit_pca  # noqa: E402
from pbc.stitch.seams import build_stitcher, edge_jump, seam_edges  # noqa: E402


def dataset_offsets(ds, indices: np.ndarray, space: str = "local", batch: int = 32, target=None) -> Tensor:
    """The offsets (B, V, 3) of dataset samples in `space` (draped cloth vs. its skinned cloth pixels).

    target: a cloth target of `ds` (`pbc.pixels.target.make_target`) whose skinner and space are used;
    None: the per-vertex ("fc") target, which builds no operators.
    """
    target = target if target is not None else make_target(ds, None, "fc", space=space)
    out = []
    with torch.inference_mode():
        for i in range(0, len(indices), batch):
            j = np.asarray(indices[i:i + batch])
            b = {"pose": torch.from_numpy(np.array(ds.poses[j], np.float32)),
                 "verts": torch.from_numpy(np.array(ds.verts[j], np.float32))}
            out.append(target.render(b)["offsets"])
    return torch.cat(out)


def figure4(path, basis_iso: PatchBasis, basis_aniso: PatchBasis, label: str) -> None:
    """Appendix Figs. 4-6: boundary perturbations (two bumps; a sine wave) carried into one patch by the
    isotropic and the anisotropic basis, drawn as height fields over the patch's flat pattern."""
    pts, faces, c = basis_iso.points, basis_iso.faces, len(basis_iso.cage)
    cage = pts[:c]
    centre, span = cage.mean(0), np.ptp(cage, 0).max()
    ang = np.arctan2(cage[:, 1] - centre[1], cage[:, 0] - centre[0])
    top = cage[:, 1].min()  # v grows downwards: the patch's top edge has the smallest v
    bumps = sum(np.exp(-((cage[:, 0] - x) ** 2 + (cage[:, 1] - top) ** 2) / (2 * (0.07 * span) ** 2))
                for x in cage[:, 0].min() + np.array([0.35, 0.65]) * np.ptp(cage[:, 0]))
    sine = np.sin(6 * ang)
    rows = [("two bumps on the boundary (Fig. 5)", 0.02 * bumps), ("sine wave on the boundary (Fig. 6)", 0.01 * sine)]
    fig = plt.figure(figsize=(11, 7.2))
    # one subfigure per row, its perturbation named once above it: the row name no longer sits in a
    # two-line axes title that ran into the tick labels of the row above
    subs = fig.subfigures(2, 1, hspace=0.04)
    for r, (name, vals) in enumerate(rows):
        subs[r].suptitle(name, fontsize=9, fontweight="bold")
        v = torch.from_numpy(vals)[:, None]
        fills = [np.r_[vals, np.zeros(len(pts) - c)],
                 np.r_[vals, basis_iso.fill(v)[:, 0].numpy()],
                 np.r_[vals, basis_aniso.fill(v)[:, 0].numpy()]]
        titles = ["(a) boundary perturbation", "(b) isotropic basis", f"(c) anisotropic basis\n({label})"]
        for k, (h, t) in enumerate(zip(fills, titles, strict=True)):
            ax = subs[r].add_subplot(1, 3, k + 1, projection="3d")
            ax.plot_trisurf(pts[:, 0], -pts[:, 1], h * 100, triangles=faces, cmap="viridis", linewidth=0.1,
                            edgecolor=(0, 0, 0, 0.15), vmin=float(vals.min()) * 100, vmax=float(vals.max()) * 100)
            if k == 0:
                ax.scatter(cage[:, 0], -cage[:, 1], vals * 100, c="r", s=4)
            ax.set_title(t, fontsize=8)
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
    ops = image_operators(ds, image_cfg, "patch")
    crops = patch_crops(ds, image_cfg, ops)
    target = make_target(ds, image_cfg, "fc")
    train = dataset_offsets(ds, ds.split("train"), target=target).float()
    st = build_stitcher(ops, crops, ds.garment, ds.cage, stitch_cfg,
                        pca=fit_pca(train, int(stitch_cfg.pca_components)))
    idx = np.concatenate([ds.split("val"), ds.split("test")])[:max_samples]
    gt = dataset_offsets(ds, idx, target=target).float()
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
