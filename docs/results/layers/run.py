"""A long-sleeved shirt with a folded collar and turned-back cuffs lying on it, fitted on Anny (A-pose), with the
layers wrapped on top of the cloth under them (garment.shrinkwrap.layer_*) and without (every vertex wrapped onto
the skin, the behaviour before): drapes kept, and how much of the collar and cuffs ends up inside the shirt.

    python docs/results/layers/run.py [WORK_DIR] [--samples 16]

The garment is made as tests/helpers/long_sleeves.py makes it (pbc's coarse shirt sized to Anny, sleeves to the
wrists, a collar and cuffs as pieces of their own 6 mm over the shirt, MakeClothes' .obj + .mhclo). Writes
results.json and drapes.png (the first four kept drapes of each) here.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
sys.path.insert(0, str(REPO / "tests"))

from helpers.long_sleeves import long_sleeve_mhclo  # noqa: E402

from pbc.core.config import load_config  # noqa: E402
from pbc.data.dataset import load_dataset  # noqa: E402
from pbc.geometry.body import body_from_config  # noqa: E402
from pbc.geometry.body.anny import base_mesh_vertices  # noqa: E402
from pbc.geometry.body.base import pose_body  # noqa: E402
from pbc.geometry.meshops import boundary_loops, mesh_pieces, surface_distance  # noqa: E402
from pbc.jobs.writers import camera, render_frames  # noqa: E402

SETTINGS = {"layers": [], "no layers (all on the skin)": ["garment.shrinkwrap.layer_min_area=100"]}


def pieces(ds) -> np.ndarray:
    """(V,) bool: the collar's and cuffs' vertices (every mesh piece but the shirt, the largest)."""
    comp = mesh_pieces(ds.garment.faces.numpy(), len(ds.garment.vertices))
    return comp != np.bincount(comp).argmax()


def inside_shirt(ds, verts: np.ndarray, poses: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per drape, the fraction of the pieces' vertices more than 2 mm nearer the body than the shirt is under them
    (the shirt's nearest point's distance to the posed body): collar or cuff cloth pushed in under the shirt. Only
    vertices over the shirt's inside count: where the nearest shirt point is within 1 cm of the shirt's edge (a
    cuff past the sleeve's hem, the collar at the neckline) the shirt flares and the comparison says nothing."""
    f = ds.garment.faces.numpy()
    shirt = f[~mask[f].any(1)]
    edge = np.unique(np.concatenate(boundary_loops(shirt)))
    bf = ds.body.faces.numpy()
    out = []
    for v, pose in zip(verts, poses, strict=True):
        bv = pose_body(ds.body, torch.from_numpy(np.array(pose, np.float32))[None])[0].double().numpy()
        d_piece = surface_distance(v[mask], bv, bf)[0]
        _, on_shirt, _ = surface_distance(v[mask], v, shirt)
        d_shirt = surface_distance(on_shirt, bv, bf)[0]
        over = cKDTree(v[edge]).query(on_shirt)[0] > 0.01
        out.append(float((d_piece < d_shirt - 0.002)[over].mean()))
    return np.array(out)


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("work", nargs="?", default="/tmp/pbc_layers", type=Path)
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args(argv)
    cfg = load_config(["body=anny"])
    path = long_sleeve_mhclo(args.work / "mh", body_from_config(cfg.body), base_mesh_vertices(cfg.body).numpy(),
                             layers=True)
    env = dict(os.environ, PBC_ROOT=str(args.work))
    results = {}
    for k, (name, extra) in enumerate(SETTINGS.items()):
        out = args.work / f"fit{k}"
        if not (out / "whole" / "metrics.json").is_file():
            subprocess.run([sys.executable, "-m", "pbc", "garment", "fit", str(path), "body=anny", *extra,
                            "--samples", str(args.samples), "--epochs", "1", "--out", str(out)], check=True, env=env)
        ds = load_dataset(out / "data")
        mask = pieces(ds)
        inside = inside_shirt(ds, np.asarray(ds.verts), np.asarray(ds.poses), mask)
        counts = ds.manifest["counts"]
        results[name] = {"requested": counts["requested"], "kept": counts["kept"],
                         "discarded": counts.get("discarded"), "piece_vertices": int(mask.sum()),
                         "pieces_inside_shirt_mean": round(float(inside.mean()), 4),
                         "pieces_inside_shirt_max": round(float(inside.max()), 4),
                         "wrap": {k2: ds.manifest.get("shrinkwrap", {}).get(k2) for k2 in
                                  ("layer_vertices", "layer_lift_max", "patch_stretch_max")}}
        print(name, json.dumps(results[name]), flush=True)
    (HERE / "results.json").write_text(json.dumps({"machine": "2-core CPU, no GPU", "samples": args.samples,
                                                   "settings": results}, indent=1) + "\n")
    # the drapes themselves, upper body, the collar and cuffs in orange over the blue shirt: where a piece is
    # under the shirt it does not show
    frames = []
    for k in range(len(SETTINGS)):
        ds = load_dataset(args.work / f"fit{k}" / "data")
        mask = pieces(ds)
        f = ds.garment.faces.numpy()
        piece_f, shirt_f = torch.from_numpy(f[mask[f].all(1)]), torch.from_numpy(f[~mask[f].any(1)])
        idx = list(range(min(4, len(ds))))
        v = torch.from_numpy(np.array(ds.verts[idx], np.float32))
        bv = pose_body(ds.body, torch.from_numpy(np.array(ds.poses[idx], np.float32)))
        upper = v[:, :, 1] > 0.05
        cam = camera(torch.cat([v[i][upper[i]] for i in range(len(idx))]), 480, 0.03)
        frames.append(render_frames([(bv, ds.body.faces, [0.8, 0.7, 0.6], 0.0, True),
                                     (v, shirt_f, [0.3, 0.45, 0.85], 0.002, False),
                                     (v, piece_f, [0.95, 0.55, 0.15], 0.002, False)],
                                    cam, [0.3, 0.5, 1.0], [1.0, 1.0, 1.0]))
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(len(frames), 4, figsize=(18, 3.4 * len(frames)), squeeze=False)
    for row, (name, imgs) in enumerate(zip(SETTINGS, frames, strict=True)):
        r = results[name]
        for c, ax in enumerate(axes[row]):
            ax.axis("off")
            if c < len(imgs):
                ax.imshow(imgs[c])
        axes[row, 0].set_title(f"{name}: {r['kept']}/{r['requested']} drapes kept, "
                               f"{100 * r['pieces_inside_shirt_mean']:.0f}% of collar/cuff vertices under the shirt",
                               loc="left", fontsize=10)
    fig.tight_layout()
    fig.savefig(HERE / "drapes.png", dpi=90)
    plt.close(fig)

if __name__ == "__main__":
    main(sys.argv[1:])
