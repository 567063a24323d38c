"""`pbc predict RUN --poses POSES [options]` (also `python -m pbc.predict`): garment meshes for body poses
from trained runs, the whole model alone or the patch models stitched (pbc.predict does the work)."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.predict import (
    ClothPredictor,
    check_max_poses,
    first_poses,
    fit_training_pca,
    predict_to_dir,
    read_poses,
    stitch_config,
)
from pbc.stitch.pca import dataset_hash, load_pca
from pbc.stitch.seams import METHODS

EXAMPLES = """examples:
  pbc predict runs/main/latest/whole --poses test                  # the dataset's test poses
  pbc predict runs/main/latest/whole --poses my_poses.npy --body   # (N, 10, 3, 3) or (N, 90) rotations
  pbc predict runs/main/latest/whole --patches runs/patches --method pca --poses test --format ply
"""


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="pbc predict", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="Garment meshes for body poses, from trained pbc models: the whole-shirt model alone, or "
                    "the patch models (one per patch of the garment's cage) stitched by a seam method. Writes "
                    "meshes/ (OBJ with the garment's UVs and normals, or PLY), vertices.npy, poses.npy, "
                    "contact_sheet.png and predict.json.")
    ap.add_argument("whole_run", nargs="?", help="a whole-shirt training run dir (e.g. runs/main/latest/whole)")
    ap.add_argument("--patches", nargs="+", metavar="RUN", help="the patch run dirs (one per cage patch), a sweep "
                    "dir holding them, or a stacked +experiment=patches run dir")
    ap.add_argument("--method", default="pca", choices=METHODS, help="seam method for --patches (default pca)")
    ap.add_argument("--pca", metavar="FILE", help="PCA basis for --method pca (pbc evaluate's pca.pt); "
                                                   "default: fitted on the training split")
    ap.add_argument("--model", choices=("patches", "whole"), help="default: patches when given, else whole")
    ap.add_argument("--poses", required=True, help="an .npy of rotations, (N, 10, 3, 3) or (N, 90), or a split "
                                                   "of the run's dataset: train, val or test")
    ap.add_argument("--max", type=int, metavar="N", help="the first N poses only (N >= 1)")
    ap.add_argument("--out", help="output dir (default $PBC_ROOT/runs/predict/<date>_<time>)")
    ap.add_argument("--format", choices=("obj", "ply"), default="obj", help="mesh format (default obj)")
    ap.add_argument("--body", action="store_true", help="also write each posed body mesh")
    ap.add_argument("--sheet", type=int, default=12, metavar="N", help="poses on contact_sheet.png (0: none)")
    ap.add_argument("--batch-size", type=int, default=16)
    return ap


def run(argv: list[str]) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if not args.whole_run and not args.patches:
        ap.error("give a whole-shirt run dir, or --patches with the patch runs")
    check_max_poses(args.max)  # before any model is loaded: --max 0 is a mistake, not "all"
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    out = Path(args.out or Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "predict" / stamp)
    stitch = stitch_config(args.method) if args.patches else None
    predictor = ClothPredictor.from_runs(args.whole_run, args.patches, stitch)
    if predictor.stitcher is not None and args.method == "pca":
        predictor.stitcher.pca = (load_pca(args.pca, dataset_hash(predictor.dataset.dir)) if args.pca else
                                  fit_training_pca(predictor, int(stitch.pca_components), 4096))
    poses, names, truth = first_poses(*read_poses(args.poses, predictor.dataset), args.max)
    info = {"whole_run": args.whole_run, "patch_runs": args.patches, "poses": str(args.poses)}
    res = predict_to_dir(predictor, poses, names, out, args.format, args.body, args.sheet, args.batch_size,
                         args.model, truth, info)
    err = f"; vertex error vs simulation {res['vertex_error_cm']:.3f} cm" if "vertex_error_cm" in res else ""
    print(f"{res['num_poses']} poses -> {out}/meshes/*.{args.format} ({res['model']} model{err}), "
          f"vertices.npy, contact_sheet.png, predict.json ({res['seconds']:.1f} s)")
    return 0


main = entry_point("predict", run)

if __name__ == "__main__":
    main()
