"""`python -m pbc.evaluate whole_run=... patch_runs=...`: whole-shirt model vs. stitched patch models.

One job: score, on a split of the dataset (test by default), the whole-garment model, the P patch
models of the dataset's cage (28 on the T-shirt) stitched under every seam method, the same stitcher fed
ground-truth crops, and the representation floor S(R(x)) at both resolutions; then write into the Hydra run dir:

    metrics.json    per entry: vertex error (cm), normal distance (1 - cos), seam jump (cm), interior jump;
                    plus the patches' disagreement across seams before blending
    metrics.md      the same as a markdown table
    error_maps.png  per-vertex error rendered on the front/back cloth images, one row per entry
    preview_*.png   gt / whole / stitched meshes side by side for a few poses
    meshes/*.obj    those meshes (garment OBJ with UVs and normals, pbc.geometry.meshio)
    pca.pt          the PCA basis fitted on the training split (with the dataset hash)

Seam jump: mean over cage-seam edges of |(p_a - p_b) - (g_a - g_b)| (what the edge carries that the
ground truth does not); "interior jump" is the same over all other edges, for scale.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import torch
from matplotlib.collections import PolyCollection
from omegaconf import DictConfig, OmegaConf

from pbc.core.io import require_writable_dir, save_figure, write_text
from pbc.core.runs import INTERIOR_JUMP, NORMAL_DISTANCE, SEAM_JUMP, VERTEX_ERROR, RunRecord
from pbc.data.dataset import person_kw, run_data_record
from pbc.data.trimmed import recorded_mean_offsets
from pbc.geometry.meshio import write_garment_mesh
from pbc.geometry.meshops import vertex_normals
from pbc.inference.predictor import ClothPredictor, fit_training_pca
from pbc.pixels.frames import from_offsets
from pbc.pixels.reconstruct import mesh_edges
from pbc.stitch.pca import dataset_hash, load_pca, save_pca
from pbc.stitch.seams import METHODS, NEEDS_WHOLE, edge_jump, patch_disagreement, seam_edges, uv_to_pixel

log = logging.getLogger(__name__)


CM = 100.0


def _scores(pos, gt, faces, seam, interior) -> dict[str, torch.Tensor]:
    """Per-sample scores (B,) of positions pos against gt (B, V, 3)."""
    n_p, n_g = vertex_normals(pos, faces), vertex_normals(gt, faces)
    return {
        VERTEX_ERROR: (pos - gt).norm(dim=-1).mean(1) * CM,
        NORMAL_DISTANCE: (1 - (n_p * n_g).sum(-1)).mean(1),
        SEAM_JUMP: edge_jump(pos, gt, seam) * CM,
        INTERIOR_JUMP: edge_jump(pos, gt, interior) * CM,
    }


def evaluate(cfg: DictConfig, out: Path) -> dict:
    t0 = time.time()
    require_writable_dir(out, "evaluation dir", "set hydra.run.dir (or PBC_ROOT) to a writable place")
    unknown = [m for m in cfg.methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown seam methods {unknown}; choose from {METHODS}")
    patch_runs = OmegaConf.to_container(cfg.patch_runs) if OmegaConf.is_list(cfg.patch_runs) else cfg.patch_runs
    if patch_runs in ("", []):
        patch_runs = None
    if patch_runs is None and not cfg.whole_run:
        raise ValueError("nothing to evaluate: give whole_run=<run dir> and/or patch_runs=<run dirs>")
    # the dataset the runs recorded (resolved dir + fingerprint); data_dir only to point at a moved copy
    pred = ClothPredictor.from_runs(cfg.whole_run, patch_runs, cfg.stitch, data_dir=cfg.get("data_dir"))
    pred.mend = None  # the models' own output is scored, as training measures it (pbc predict mends)
    ds = pred.dataset
    patches = pred.stitcher is not None  # else the whole model alone: no stitch, no patch floor
    # a shipped model's data (whole_run=pretrained:NAME) has no training split, only its mean offsets
    shipped_mean = recorded_mean_offsets(ds)
    if cfg.pca_path:
        basis = load_pca(cfg.pca_path, dataset_hash(ds.dir))
    elif shipped_mean is not None and not patches:
        basis = None
    else:  # its mean is the no-model baseline even without patches
        basis = fit_training_pca(pred, int(cfg.stitch.pca_components), int(cfg.pca_fit_max))
        save_pca(basis, out / "pca.pt")
    if patches:
        pred.use_pca(basis)
    train_mean = basis.mean if basis is not None else shipped_mean[0]

    faces = pred.faces
    # the cage's seams: where a stitch would show; scored for the whole model too, for comparison
    vp = pred.stitcher.vertex_patch if patches else torch.from_numpy(ds.cage.vertex_patch(len(ds.garment.vertices)))
    seam = seam_edges(faces, vp)
    all_e = mesh_edges(faces)
    is_seam = (vp[all_e[:, 0]] != vp[all_e[:, 1]])
    interior = all_e[~is_seam]
    if patches:
        sides = torch.tensor([p.side for p in ds.cage.patches])
        same_side = sides[vp[seam[:, 0]]] == sides[vp[seam[:, 1]]]
        vpix = uv_to_pixel(torch.as_tensor(ds.garment.vertex_uv).float(), (pred.ops_patch.res,) * 2)
        origins = torch.tensor([c.window[:2] for c in pred.crops]).float()

    idx = ds.split(cfg.split)
    if cfg.max_samples:
        idx = idx[: int(cfg.max_samples)]
    if len(idx) == 0:
        raise ValueError(f"split {cfg.split!r} of {ds.dir} is empty")
    acc: dict[str, dict[str, list]] = {}
    disagreement = []
    keep = {}  # the first batch's positions, for the figures

    def add(name, pos, gt):
        for k, v in _scores(pos, gt, faces, seam, interior).items():
            acc.setdefault(name, {}).setdefault(k, []).append(v)

    with torch.inference_mode():
        for i in range(0, len(idx), int(cfg.batch_size)):
            j = idx[i:i + int(cfg.batch_size)]
            poses = torch.from_numpy(ds.poses[j]).float()
            gt = torch.from_numpy(ds.verts[j]).float()
            gt_off, anchors, frames = pred.offsets_of(poses, gt, **person_kw(ds, j))

            def pos_of(off, anchors=anchors, frames=frames):
                return from_offsets(off, anchors, frames, pred.space)

            batch = {"gt": gt}
            gt_whole = pred.image_target.values(pred.image_target.encode(gt_off))
            # the representation floors of the whole (floor_256) and patch (floor_512) images, by their default
            # resolutions' names whatever the run's image sizes
            batch["floor_256"] = pos_of(gt_whole)
            if patches:
                batch["floor_512"] = pos_of(pred.ops_patch.sample(pred.ops_patch.render(gt_off)))
            # the no-model baseline: every pose gets the training split's mean offsets
            batch["train_mean"] = pos_of(train_mean.view(1, -1, 3).expand(len(j), -1, -1).to(gt_off))
            whole_off = pred.whole_offsets(poses) if pred.whole_net is not None else None
            if whole_off is not None:
                batch["whole"] = pos_of(whole_off)
            if patches:
                crops = pred.patch_crops(poses)
                gt_crops = torch.stack([c.render(gt_off) for c in pred.crops], 1)
                for m in cfg.methods:
                    if m in NEEDS_WHOLE and whole_off is None:
                        continue
                    batch[f"patches_{m}"] = pos_of(pred.stitcher(crops, m, whole_off))
                    batch[f"gt_crops_{m}"] = pos_of(pred.stitcher(gt_crops, m, gt_whole))
                disagreement.append(patch_disagreement(crops, origins, vpix, seam[same_side], vp) * CM)
            for name, pos in batch.items():
                if name != "gt":
                    add(name, pos, gt)
            if not keep:
                keep = {k: v[: int(cfg.num_previews)] for k, v in batch.items()}

    entries = {name: {k: float(torch.cat(v).mean()) for k, v in d.items()} for name, d in acc.items()}
    metrics = {
        "split": cfg.split, "num_samples": len(idx), "dataset": str(ds.dir), "data": run_data_record(ds),
        "whole_run": str(cfg.whole_run), "patch_runs": patch_runs if isinstance(patch_runs, list) or patch_runs is None
        else str(patch_runs),
        "stitch": OmegaConf.to_container(cfg.stitch), "pca": None if basis is None else {
            "components": basis.num_components, "dataset_hash": basis.dataset_hash},
        "seam_edges": int(seam.shape[0]),
        "patch_disagreement_before_blend_cm": float(torch.cat(disagreement).mean()) if disagreement else None,
        "entries": entries, "seconds": round(time.time() - t0, 2),
    }
    # the run's record: what it measured (the entries, at the top level) and what it was configured with
    RunRecord(config=OmegaConf.to_container(cfg, resolve=False), data=metrics["data"], seconds=metrics["seconds"],
              extra={k: v for k, v in metrics.items() if k not in ("data", "seconds")}).write(out)
    write_text(out / "metrics.md", markdown_table(metrics))
    write_figures(out, pred, keep, faces, cfg.stitch.method)
    return metrics


def markdown_table(metrics: dict) -> str:
    cols = [VERTEX_ERROR, NORMAL_DISTANCE, SEAM_JUMP, INTERIOR_JUMP]
    what = "Whole vs. stitched patches" if metrics["patch_runs"] is not None else "The whole model"
    lines = [f"# {what} ({metrics['split']}, {metrics['num_samples']} samples)", "",
             "| entry | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, d in metrics["entries"].items():
        lines.append(f"| {name} | " + " | ".join(f"{d[c]:.4f}" for c in cols) + " |")
    if metrics["patch_disagreement_before_blend_cm"] is not None:
        lines += ["", f"Patch disagreement across seams before blending: "
                  f"{metrics['patch_disagreement_before_blend_cm']:.4f} cm over {metrics['seam_edges']} seam edges."]
    lines.append("")
    return "\n".join(lines)


def write_figures(out: Path, pred, keep: dict, faces: torch.Tensor, method: str) -> None:
    """error_maps.png, preview_<i>.png and meshes/*.obj from the first batch's positions."""
    import matplotlib  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting


    gt = keep["gt"]
    names = [n for n in keep if n != "gt" and not n.startswith("gt_crops")]
    ops = pred.ops_patch if pred.ops_patch is not None else pred.image_target.ops
    mask = ops.mask.numpy()
    # the sides with charts, cut to the charts' bounding box (a necktie fills a thin band of one side)
    sides = [s for s in range(2) if mask[s].any()]
    rows, cols = np.nonzero(mask[sides].any(0))
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    aspect = (rows.max() - rows.min() + 1) / (cols.max() - cols.min() + 1)
    fig, axes = plt.subplots(len(names), len(sides), figsize=(3 * len(sides), max(0.6, 3 * aspect) * len(names) + 0.8),
                             squeeze=False)
    vmax = max(float((keep[n][0] - gt[0]).norm(dim=-1).max()) * CM for n in names) or 1.0
    for r, n in enumerate(names):
        err = (keep[n][:1] - gt[:1]).norm(dim=-1, keepdim=True).expand(-1, -1, 3) * CM
        img = ops.render(err)[0]
        for k, s in enumerate(sides):
            ax = axes[r, k]
            im = ax.imshow(np.ma.masked_where(~mask[s][box], img[3 * s].numpy()[box]), cmap="magma",
                           vmin=0, vmax=vmax)
            ax.set_title(f"{n} {'front' if s == 0 else 'back'}", fontsize=7)
            ax.axis("off")
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.6, label="cm")
    save_figure(fig, out / "error_maps.png", dpi=80)

    shown = [n for n in ("gt", "whole", f"patches_{method}") if n in keep]
    f = faces.numpy()
    for i in range(gt.shape[0]):
        fig, axes = plt.subplots(1, len(shown), figsize=(3.2 * len(shown), 3.6), squeeze=False)
        for a, n in zip(axes[0], shown, strict=True):
            v = keep[n][i].numpy()
            tri = v[f]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True) + 1e-12
            order = np.argsort(tri[:, :, 2].mean(1))  # painter's algorithm, front view along +z
            shade = 0.25 + 0.75 * np.abs(nrm[order, 2])
            a.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=plt.cm.gray(shade), linewidths=0))
            a.set_xlim(v[:, 0].min(), v[:, 0].max())
            a.set_ylim(v[:, 1].min(), v[:, 1].max())
            a.set_aspect("equal")
            a.set_title(n, fontsize=8)
            a.axis("off")
            write_garment_mesh(out / "meshes" / f"pose{i}_{n}.obj", pred.dataset.garment, keep[n][i],
                               header=[f"{n}, pose {i} of the evaluated split (pbc.evaluate)"])
        save_figure(fig, out / f"preview_{i}.png", dpi=80)
