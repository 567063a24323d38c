"""`pbc cage-study DATASET_DIR [--seam-study BIAS_CM]`: how much of each patch its cage explains (the
isotropic and an anisotropic cage basis against the training mean), and Fig. 4 of the paper."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from pbc.cli.errors import entry_point
from pbc.core.io import write_json, write_text
from pbc.core.paths import CONF_DIR
from pbc.data.dataset import load_dataset
from pbc.pixels.target import make_target
from pbc.stitch.cage_basis import build_cage_basis, reconstruction_error, tensor_from_config
from pbc.stitch.cage_study import dataset_offsets, figure4, seam_study


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc cage-study", description=__doc__)
    ap.add_argument("dataset", help="dataset directory (pbc generate)")
    ap.add_argument("--stitch", default=str(CONF_DIR / "stitch" / "cage.yaml"),
                    help="stitch config holding cage_anisotropy / cage_angle_deg (the anisotropic tensor)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--out", default="outputs/cage_basis")
    ap.add_argument("--figure-patch", type=int, default=None, help="patch drawn in Fig. 4 (default: most interior)")
    ap.add_argument("--seam-study", type=float, default=None, metavar="BIAS_CM",
                    help="also compare the seam methods on ground-truth crops offset per patch by BIAS_CM")
    ap.add_argument("--image", default=str(CONF_DIR / "image" / "default.yaml"),
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


main = entry_point("cage-study", run)

if __name__ == "__main__":
    main()
