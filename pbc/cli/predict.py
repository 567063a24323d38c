"""`pbc predict RUN --poses POSES [options]` (also `python -m pbc.predict`): garment meshes for body poses
from trained runs, the whole model alone or the patch models stitched (pbc.predict does the work)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from pbc.cli.errors import entry_point
from pbc.inference.poses import check_max_poses, read_motion, read_poses
from pbc.inference.predictor import ClothPredictor, fit_training_pca, pretrained_run, stitch_config
from pbc.jobs.predict import GUARDS, clip_summary, mend_summary, predict_sequence, predict_to_dir
from pbc.motion.retarget import shipped_joint_maps
from pbc.stitch.pca import dataset_hash, load_pca
from pbc.stitch.seams import METHODS

EXAMPLES = """examples:
  pbc predict runs/main/latest/whole --poses test                  # the dataset's test poses
  pbc predict --pretrained tshirt --poses test                     # the model shipped with pbc, no training
  pbc predict runs/main/latest/whole --poses my_poses.npy --body   # (N, 10, 3, 3) or (N, 90) rotations
  pbc predict runs/main/latest/whole --patches runs/patches --method pca --poses test --format ply
  pbc predict runs/main/latest/whole --poses walk.bvh --frames 0:300:4   # a BVH clip: video, GLB, contact sheet
  pbc predict runs/main/latest/whole --poses walk.bvh --obj               # ... and an OBJ per frame
  pbc predict runs/main/latest/whole --poses walk.bvh --fps 30 --guard range --bvh-map my_rig.yaml
  pbc predict --pretrained tshirt --poses dance.bvh --rest-frame 40     # a clip whose rest is its frame 40
  pbc predict runs/shapes/whole --poses walk.bvh --person 3            # a data.body_shape run: on person 3
"""
# the options that only a BVH clip takes, and their defaults
MOTION_OPTIONS = {"bvh_map": "auto", "frames": None, "fps": None, "clamp_to_range": False, "guard": None,
                  "video": "mp4", "no_glb": False, "allow_rest": False, "max_frames": None, "rest_frame": None,
                  "trust_clip": False}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="pbc predict", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="Garment meshes for body poses, from trained pbc models: the whole-shirt model alone, or "
                    "the patch models (one per patch of the garment's cage) stitched by a seam method. Writes "
                    "meshes/ (OBJ with the garment's UVs and normals, or PLY), vertices.npy, poses.npy, "
                    "contact_sheet.png and predict.json.")
    ap.add_argument("whole_run", nargs="?", help="a whole-shirt training run dir (e.g. runs/main/latest/whole)")
    ap.add_argument("--pretrained", metavar="NAME", help="a pretrained model: yours, else the one shipped with "
                    "pbc (pbc pretrained list; e.g. tshirt) instead of a run dir")
    ap.add_argument("--patches", nargs="+", metavar="RUN", help="the patch run dirs (one per cage patch), a sweep "
                    "dir holding them, or a stacked +experiment=patches run dir")
    ap.add_argument("--method", default="pca", choices=METHODS, help="seam method for --patches (default pca)")
    ap.add_argument("--pca", metavar="FILE", help="PCA basis for --method pca (pbc evaluate's pca.pt); "
                                                   "default: fitted on the training split")
    ap.add_argument("--model", choices=("patches", "whole"), help="default: patches when given, else whole")
    ap.add_argument("--poses", required=True, help="an .npy of rotations, (N, 10, 3, 3) or (N, 90), a .bvh motion "
                                                   "clip, or a split of the run's dataset: train, val or test")
    ap.add_argument("--max", type=int, metavar="N", help="the first N poses only (N >= 1)")
    ap.add_argument("--out", help="output dir (default $PBC_ROOT/runs/predict/<date>_<time>)")
    ap.add_argument("--format", choices=("obj", "ply"), help="mesh format (default obj; for a clip: a mesh per "
                    "frame in it)")
    ap.add_argument("--obj", action="store_true", help="for a clip: also a mesh per frame (meshes/, OBJ unless "
                    "--format ply; without it a clip writes its video, garment.glb and contact sheet)")
    ap.add_argument("--body", action="store_true", help="also write each posed body mesh")
    ap.add_argument("--person", type=int, metavar="K", help="in a dataset of several people (data.body_shape): "
                    "the garment on person K (0..K-1, shapes.npz) for every pose; default: a split's poses each on "
                    "its own person, other poses on the base person (body.npz)")
    ap.add_argument("--sheet", type=int, default=12, metavar="N", help="poses on contact_sheet.png, for a clip "
                    "frames spread over it (0: none)")
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--no-mend", action="store_true", help="the models' output as is: no edge stretched past "
                    "stretch_cap of conf/mend.yaml (2x its usual length) shortened")
    motion = ap.add_argument_group("a BVH clip (--poses clip.bvh): motion.mp4, garment.glb, contact_sheet.png "
                                   "(a mesh per frame with --obj)")
    motion.add_argument("--bvh-map", default="auto", metavar="TABLE",
                        help="the joint map: a table of conf/motion (" + ", ".join(shipped_joint_maps())
                        + ") or a YAML file of that layout; auto (default): a shipped table knowing every joint, "
                        "else matched by name and structure (Mixamo, Bandai Namco, LAFAN1, Blender, ...; "
                        "`pbc motion inspect CLIP` shows the match)")
    motion.add_argument("--frames", metavar="START:STOP:STEP", help="the clip's frames (a Python slice), e.g. 0:300:4")
    motion.add_argument("--fps", type=float, help="resample the selected frames at this rate (slerp)")
    motion.add_argument("--allow-rest", action="store_true", help="go on when the body's arms, legs or spine "
                        "match no joint of the clip (they stay at rest; refused otherwise)")
    motion.add_argument("--max-frames", type=int, metavar="N", help="the most frames a request may make "
                        "(default: max_frames of conf/motion/sequence.yaml, 100000)")
    motion.add_argument("--guard", choices=GUARDS, help="frames past the model's data (flagged either way): "
                        "nearest turns each towards its nearest training pose to the limit and clamps its joint "
                        "angles into the training poses' range, range clamps only, none predicts them as they are "
                        "(default: guard of conf/motion/sequence.yaml, nearest)")
    motion.add_argument("--clamp-to-range", action="store_true", help="the same as --guard range")
    motion.add_argument("--rest-frame", type=int, metavar="K", help="the clip frame whose posture is its rest "
                        "(default: its OFFSETs' layout, or for a skeleton lying flat a frame standing as a rest; "
                        "`pbc motion inspect CLIP` shows which)")
    motion.add_argument("--trust-clip", action="store_true", help="go on when the retargeted clip fails the sanity "
                        "check (trunk upright, feet under the hips, a person's height; refused otherwise)")
    motion.add_argument("--video", choices=("mp4", "gif", "none"), default="mp4", help="body + garment video "
                        "(default mp4)")
    motion.add_argument("--no-glb", action="store_true", help="no animated garment.glb")
    return ap


def run(argv: list[str]) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if args.pretrained and args.whole_run:
        ap.error("give a run dir or --pretrained NAME, not both")
    if args.pretrained:
        args.whole_run = str(pretrained_run(args.pretrained))  # an unknown name: the models there are listed
    if not args.whole_run and not args.patches:
        ap.error("give a whole-shirt run dir (or --pretrained NAME), or --patches with the patch runs")
    check_max_poses(args.max)  # before any model is loaded: --max 0 is a mistake, not "all"
    is_bvh = Path(args.poses).suffix.lower() == ".bvh"
    given = [k for k, v in MOTION_OPTIONS.items() if getattr(args, k) != v]
    if given and not is_bvh:
        raise ValueError(f"{', '.join('--' + k.replace('_', '-') for k in given)}: only for a BVH clip "
                         "(--poses clip.bvh)")
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
    out = Path(args.out or Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "predict" / stamp)
    stitch = stitch_config(args.method) if args.patches else None
    predictor = ClothPredictor.from_runs(args.whole_run, args.patches, stitch)
    if args.no_mend:
        predictor.mend = None
    if predictor.stitcher is not None and args.method == "pca":
        predictor.stitcher.pca = (load_pca(args.pca, dataset_hash(predictor.dataset.dir)) if args.pca else
                                  fit_training_pca(predictor, int(stitch.pca_components), 4096))
    info = {"whole_run": args.whole_run, "pretrained": args.pretrained, "patch_runs": args.patches,
            "poses": str(args.poses)}
    if is_bvh:
        return run_motion(args, predictor, out, info)
    chosen = read_poses(args.poses, predictor.dataset).first(args.max)
    truth, person = chosen.truth, chosen.people
    if args.person is not None:
        person = args.person
        if chosen.people is not None and np.any(chosen.people != args.person):
            truth = None  # simulated on other people: no error to report against them
            print(f"--person {args.person}: the split's poses were simulated on their own people, so no vertex "
                  "error is reported")
    res = predict_to_dir(predictor, chosen.poses, chosen.names, out, args.format or "obj", args.body, args.sheet,
                         args.batch_size, args.model, truth, info, person)
    err = f"; vertex error vs simulation {res['vertex_error_cm']:.3f} cm" if "vertex_error_cm" in res else ""
    print(mend_summary(res["mend"], res["num_poses"]))
    print(f"{res['num_poses']} poses -> {out}/meshes/*.{args.format or 'obj'} ({res['model']} model{err}), "
          f"vertices.npy, contact_sheet.png, predict.json ({res['seconds']:.1f} s)")
    return 0


def run_motion(args, predictor: ClothPredictor, out: Path, info: dict) -> int:
    """--poses clip.bvh: the clip read and checked whole before anything is written."""
    if args.clamp_to_range and args.guard not in (None, "range"):
        raise ValueError(f"--clamp-to-range is --guard range: give one of them, not --guard {args.guard} too")
    motion = read_motion(args.poses, predictor.dataset, args.bvh_map, args.frames, args.fps, args.allow_rest,
                         args.max_frames, args.rest_frame, args.trust_clip)
    if args.max is not None:
        motion = dataclasses.replace(motion, poses=motion.poses[:args.max], times=motion.times[:args.max],
                                     source_frames=motion.source_frames[:args.max])
    meshes = args.obj or args.format is not None or args.body  # asked for: a clip's meshes are its largest output
    res = predict_sequence(predictor, motion, out, args.format or "obj", None if args.video == "none" else args.video,
                           not args.no_glb, args.body, "range" if args.clamp_to_range else args.guard,
                           args.batch_size, args.model,
                           dict(info, frames=args.frames, fps=args.fps), person=args.person, meshes=meshes,
                           sheet=args.sheet)
    for note in res["notes"][len(motion.notes):]:  # where the training range came from when not the run
        print(note)
    print(clip_summary(motion, res["pose_range"]))
    print(mend_summary(res["mend"], res["num_poses"]))
    written = [res["files"][k] for k in ("meshes", "video", "glb", "contact_sheet") if k in res["files"]]
    print(f"{res['num_poses']} frames ({motion.table.name} joint map, {motion.units}, {motion.fps:g} fps) -> "
          f"{out}/: {', '.join([*written, 'vertices.npy', 'predict.json'])} ({res['model']} model, "
          f"{res['seconds']:.1f} s)" + ("" if meshes else "; a mesh per frame with --obj"))
    return 0


main = entry_point("predict", run)

if __name__ == "__main__":
    main()
