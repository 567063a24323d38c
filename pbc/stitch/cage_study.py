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

import numpy as np
import torch
from torch import Tensor

from pbc.stitch.cage_basis import PatchBasis, build_cage_basis, reconstruction_error, tensor_from_config


def dataset_offsets(ds, indices: np.ndarray, space: str = "local", batch: int = 32, target=None) -> Tensor:
    """The offsets (B, V, 3) of dataset samples in `space` (draped cloth vs. its skinned cloth pixels).

    target: a cloth target of `ds` (`pbc.pixels.target.make_target`) whose skinner and space are used;
    None: the per-vertex ("fc") target, which builds no operators.
    """
    from pbc.pixels.target import make_target

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
    from pbc.pixels.reconstruct import mesh_edges
    from pbc.pixels.target import image_operators, make_target, patch_crops
    from pbc.stitch.pca import fit_pca
    from pbc.stitch.seams import build_stitcher, edge_jump, seam_edges

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


def main(argv=None) -> int:
    """python -m pbc.stitch.cage_study <dataset dir>: how much of each patch its cage explains, + Fig. 4."""
    import argparse
    import json
    from pathlib import Path

    from omegaconf import OmegaConf

    from pbc.data.dataset import load_dataset
    from pbc.io import write_json, write_text
    from pbc.pixels.target import make_target

    ap = argparse.ArgumentParser(prog="python -m pbc.stitch.cage_study", description=main.__doc__)
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
    target = make_target(ds, None, "fc")  # per-vertex offsets: the skinner, no operators
    offs = dataset_offsets(ds, idx, target=target).double()
    mean = dataset_offsets(ds, ds.split("train"), target=target).double().mean(0)
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
             f"({len(iso)} patches); mean error over interior vertices, cm.", "",
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
