"""`pbc view RUN [options]` (or `--pretrained NAME`): a local web viewer of a trained garment model, the body
and the predicted garment live under joint sliders, in the browser (pbc.jobs.view does the work)."""

from __future__ import annotations

import argparse

import torch

from pbc.cli.errors import entry_point
from pbc.inference.predictor import ClothPredictor, pretrained_run, stitch_config
from pbc.jobs.predict import GUARDS, clip_summary, guard_frames
from pbc.jobs.view import check_port, load_sequence, start_viewer, stop_within, url, view_config, wait_forever
from pbc.stitch.pca import dataset_hash, load_pca
from pbc.stitch.seams import METHODS

EXAMPLES = """examples:
  pbc view runs/main/latest/whole                                    # the whole-shirt model
  pbc view runs/main/latest/whole --patches runs/patches --method pca  # + the stitched patch models
  pbc view runs/main/latest/whole --sequence walk.npy                # a timeline of (N, 10, 3, 3) rotations
  pbc view --pretrained tshirt
Then open the printed address in a browser; Ctrl-C stops the viewer.
"""


def port_number(text: str) -> int:
    try:
        return check_port(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a TCP port number from 1 to 65535 (0: any free one)") \
            from None


def parser() -> argparse.ArgumentParser:
    cfg = view_config()
    ap = argparse.ArgumentParser(
        prog="pbc view", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="A local web viewer (viser) of trained pbc models: the body and the predicted garment, a "
                    "slider per joint axis within the body's limits, the dataset's poses with the simulated "
                    "garment and the per-vertex error as colour, whole vs stitched and the seam method as "
                    "toggles, and play/pause over a loaded sequence. Settings: conf/view.yaml.")
    ap.add_argument("whole_run", nargs="?", help="a whole-shirt training run dir (e.g. runs/main/latest/whole)")
    ap.add_argument("--pretrained", metavar="NAME", help="a pretrained model: yours, else the one shipped with "
                    "pbc (pbc pretrained list; e.g. tshirt) instead of RUN")
    ap.add_argument("--patches", nargs="+", metavar="RUN", help="the patch run dirs (one per cage patch), a sweep "
                    "dir holding them, or a stacked +experiment=patches run dir")
    ap.add_argument("--method", choices=METHODS, default=str(cfg.method),
                    help=f"the seam method shown first (default {cfg.method}; a toggle in the viewer)")
    ap.add_argument("--pca", metavar="FILE", help="PCA basis for --method pca (pbc evaluate's pca.pt); default: "
                                                   "fitted on the training split when first shown")
    ap.add_argument("--sequence", metavar="FILE", help="a pose sequence for the timeline: .npy of (N, 10, 3, 3) "
                                                       "or (N, 90) rotations, or a .bvh clip (joints mapped "
                                                       "automatically, as pbc predict --poses clip.bvh)")
    ap.add_argument("--allow-rest", action="store_true", help="a .bvh sequence: go on when the body's arms, legs or "
                    "spine match no joint of the clip (they stay at rest; refused otherwise)")
    ap.add_argument("--rest-frame", type=int, metavar="K", help="a .bvh sequence: the clip frame whose posture is its "
                    "rest (default: found, as pbc predict)")
    ap.add_argument("--trust-clip", action="store_true", help="a .bvh sequence: go on when the retargeted clip fails "
                    "the sanity check (refused otherwise)")
    ap.add_argument("--guard", choices=GUARDS, help="a .bvh sequence: frames past the model's data, as pbc predict "
                    "--guard (default: conf/motion/sequence.yaml guard)")
    ap.add_argument("--no-mend", action="store_true", help="the models' output as is, as pbc predict --no-mend "
                    "(default: edges past conf/mend.yaml's stretch_cap shortened)")
    ap.add_argument("--data", metavar="DIR", help="the runs' dataset, when it moved from where they recorded it")
    ap.add_argument("--host", default=str(cfg.host), help=f"address to serve on (default {cfg.host}: this "
                                                          "machine only)")
    ap.add_argument("--port", type=port_number, default=int(cfg.port),
                    help=f"port (default {cfg.port}; a port in use: the next free one, said so)")
    return ap


def run(argv: list[str]) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if args.pretrained and args.whole_run:
        ap.error("give a run dir or --pretrained NAME, not both")
    whole = pretrained_run(args.pretrained) if args.pretrained else args.whole_run
    if not whole and not args.patches:
        ap.error("give a whole-shirt run dir (or --pretrained NAME), or --patches with the patch runs")
    cfg = view_config()
    cfg.method = args.method
    stitch = stitch_config(args.method) if args.patches else None
    predictor = ClothPredictor.from_runs(whole, args.patches, stitch, data_dir=args.data)
    if args.no_mend:
        predictor.mend = None
    if predictor.stitcher is not None and args.pca:
        predictor.stitcher.pca = load_pca(args.pca, dataset_hash(predictor.dataset.dir))
    sequence, fps, motion = (load_sequence(args.sequence, predictor.dataset, args.allow_rest, args.rest_frame,
                                           args.trust_clip) if args.sequence else (None, None, None))
    if motion is not None:  # the clip as pbc predict reads it: its summary, its flags, the guard taken
        guarded, report = guard_frames(predictor, motion.poses, args.guard)
        sequence = torch.as_tensor(guarded, dtype=torch.float32)
        print(clip_summary(motion, report), flush=True)
    viewer = start_viewer(predictor, args.host, args.port, sequence, cfg, sequence_fps=fps)
    print(f"pbc view: {url(viewer)}  (Ctrl-C stops it)", flush=True)
    stop_within(float(cfg.stop_grace_s))
    try:
        wait_forever(viewer)
    except KeyboardInterrupt:  # Ctrl-C is how a viewer ends, not a failure
        print("pbc view: stopped", flush=True)
    return 0


main = entry_point("view", run)
