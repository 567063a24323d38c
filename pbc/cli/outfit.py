"""`pbc outfit predict`: several garments on one body, each predicted by its own model, composed as layers inner to
outer, each pushed out of the layers under it (PBNS; pbc.inference.outfit, conf/outfit.yaml).

    pbc outfit predict --pretrained tshirt trousers --poses walk.bvh --out runs/outfit/walk
    pbc outfit predict --pretrained tshirt trousers --poses test --max 8    # each piece's own test poses
    pbc outfit predict --pretrained tshirt trousers --poses walk.bvh --order trousers,tshirt

The layer order is inferred (where two pieces overlap, the one farther from the body is outer) unless --order
names every piece once, innermost first. Writes motion.mp4 (the body and every piece, each in its layer's colour),
garment_<piece>.glb, vertices_<piece>.npy (composed), predicted_<piece>.npy (each model's own output),
contact_sheet.png and outfit.json (the order and how it was found, each layer's % of vertices inside the layers
under it and inside the body before and after the push-out, the time per frame), and prints one line per layer.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.inference.outfit import OutfitPredictor, check_order
from pbc.inference.poses import check_max_poses
from pbc.inference.predictor import ClothPredictor
from pbc.jobs.outfit import clip_poses, layer_lines, predict_outfit, read_outfit_clip, split_poses
from pbc.jobs.predict import GUARDS


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="pbc outfit", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    pr = sub.add_parser("predict", help="every piece predicted and composed as layers over a clip or test poses")
    pr.add_argument("--pretrained", nargs="+", required=True, metavar="NAME",
                    help="a pretrained model per piece (pbc pretrained list), e.g. tshirt trousers")
    pr.add_argument("--poses", required=True, help="a .bvh motion clip, or a split of the pieces' datasets (test: "
                    "each piece's own test poses, one after the other, every piece predicted on all of them)")
    pr.add_argument("--order", help="the layers, innermost first, comma-separated: trousers,tshirt (default: "
                    "inferred)")
    pr.add_argument("--max", type=int, metavar="N", help="the first N frames of a clip, or of each piece's split")
    pr.add_argument("--out", help="output dir (default $PBC_ROOT/runs/outfit/<date>_<time>)")
    pr.add_argument("--sheet", type=int, default=12, metavar="N", help="frames on contact_sheet.png (0: none)")
    pr.add_argument("--video", choices=("mp4", "gif", "none"), default="mp4", help="body + pieces video")
    pr.add_argument("--no-glb", action="store_true", help="no animated garment_<piece>.glb")
    pr.add_argument("--guard", choices=GUARDS, help="a clip's frames past a model's data, each model's own copy "
                    "(as pbc predict --guard; default: conf/motion/sequence.yaml's)")
    pr.add_argument("--bvh-map", default="auto", metavar="TABLE", help="a clip's joint map (as pbc predict)")
    pr.add_argument("--frames", metavar="START:STOP:STEP", help="the clip's frames (a Python slice)")
    return ap


def pieces_of(names: list[str], order: str | None) -> list[str] | None:
    """The pieces' names checked (two or more, each once) and the --order they are given in (None: inferred)."""
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"--pretrained {' '.join(names)}: {twice[0]} given twice; give each piece's model once")
    if len(names) < 2:
        raise ValueError(f"--pretrained {' '.join(names)}: an outfit needs two pieces or more; give a model per "
                         "piece, e.g. --pretrained tshirt trousers (one garment: pbc predict)")
    return None if order is None else check_order(order.split(","), names)


def run(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    check_max_poses(args.max)
    order = pieces_of(list(args.pretrained), args.order)  # before any model is loaded
    is_bvh = Path(args.poses).suffix.lower() == ".bvh"
    if not is_bvh and (args.frames or args.guard or args.bvh_map != "auto"):
        raise ValueError("--frames, --guard and --bvh-map are for a BVH clip (--poses clip.bvh)")
    out = Path(args.out or Path(os.environ.get("PBC_ROOT", ".")) / "runs" / "outfit" /
               time.strftime("%Y-%m-%d_%H-%M-%S"))
    outfit = OutfitPredictor({n: ClothPredictor.from_pretrained(n) for n in args.pretrained}, order)
    if is_bvh:
        motion = read_outfit_clip(outfit, args.poses, args.max, joint_map=args.bvh_map, frames=args.frames)
        poses = clip_poses(outfit, motion, args.guard)
    else:
        poses = split_poses(outfit, args.poses, args.max)
    report = predict_outfit(outfit, poses, out, None if args.video == "none" else args.video, not args.no_glb,
                            args.sheet, info={"pretrained": list(args.pretrained), "poses_given": str(args.poses)})
    print(f"order ({report['order_source']}), innermost first: {', '.join(report['order'])}")
    print("\n".join(layer_lines(report)))
    print(f"{report['num_frames']} frames -> {out}/: {', '.join(sorted(_files(report['files'])))} "
          f"({report['seconds_per_frame']:.2f} s a frame)")
    return 0


def _files(files: dict) -> list[str]:
    """The file names of outfit.json's `files`."""
    names = []
    for v in files.values():
        names += list(v.values()) if isinstance(v, dict) and all(isinstance(x, str) for x in v.values()) else \
            [v] if isinstance(v, str) else []
    return names + ["outfit.json"]


main = entry_point("outfit", run)

if __name__ == "__main__":
    main()
