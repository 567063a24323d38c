"""`pbc motion inspect CLIP.bvh [body overrides]`: what pbc makes of a motion clip, before predicting with it;
`pbc motion limits CLIP_OR_FOLDER...`: per-joint limits measured from clips, for the pose sampler.

    pbc motion inspect walk.bvh                        # on Anny (the starters' body); the figure at the middle frame
    pbc motion inspect walk.bvh body=mannequin --frame 40 --out walk.png
    pbc motion inspect walk.bvh --bvh-map my_rig.yaml  # a joint map of your own (conf/motion/cmu_mb.yaml's layout)

Prints the clip's dialect, units, skeleton height and rest pose (or the frame standing in for it), the match
(body joint <- clip joint, and why), the clip joints that drive nothing, the sanity of the retargeted clip
(trunk upright, feet under the hips, a person's height) and whether `pbc predict`, `pbc view` and
`data.poses` would refuse it, with the setting that goes on; writes a PNG of the clip's skeleton at a frame
beside the body posed by it (--out; default <clip name>.inspect.png in the current folder).

    pbc motion limits ../shared/corpus/motion/cmu --exclude 'cmu_07_*' --out limits.yaml
    pbc motion limits held_out/*.bvh --against limits.yaml   # frames outside measured limits; nothing written
    python -m pbc.generate data=tshirt +body.limits_file=limits.yaml   # the sampler draws within them

`limits` reads every clip as predict does, measures each joint axis's robust range (conf/motion/sequence.yaml
`limits`: percentiles, a floor on the width; pbc.motion.limits), prints the hand-set limits beside the measured
ones with the % of frames outside each, and writes the measured limits (--out, conf/body's joints layout). A clip
the reader refuses stops it, naming the clip, unless --skip-refused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.core.config import load_config
from pbc.core.io import require_out_dir
from pbc.geometry.body import body_from_config
from pbc.jobs.motion_limits import measure_limits
from pbc.motion.bvh import check_skeleton, read_bvh
from pbc.motion.inspect import clip_figure, describe
from pbc.motion.retarget import bvh_to_poses, check_motion_files, choose_joint_map

STARTERS_BODY = "anny"  # conf/body: the body of the shipped models (pbc/pretrained)


def limits(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc motion limits", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("clips", nargs="+", metavar="CLIP_OR_FOLDER", help=".bvh clips, or folders of them")
    ap.add_argument("--out", metavar="FILE.yaml", help="write the measured limits there (default: nothing written)")
    ap.add_argument("--body", default=STARTERS_BODY, help=f"the body of conf/body (default {STARTERS_BODY})")
    ap.add_argument("--skip-refused", action="store_true", help="leave out a clip the reader refuses (named in one "
                    "line) instead of stopping")
    ap.add_argument("--exclude", action="append", default=[], metavar="GLOB", help="leave out clips whose name (in "
                    "its folder) matches, e.g. 'cmu_07_*' (repeatable)")
    ap.add_argument("--against", metavar="LIMITS.yaml", help="also report the % of frames outside this limits file's "
                    "limits (e.g. measured on other clips)")
    ap.add_argument("--percentiles", nargs=2, type=float, metavar=("LOW", "HIGH"), help="percent of the frames "
                    "below the low and the high limit (default: conf/motion/sequence.yaml limits.percentiles)")
    ap.add_argument("--note", action="append", default=[], metavar="TEXT", help="a line for the file's header (the "
                    "clips' source and licence; repeatable)")
    args = ap.parse_args(argv)
    measure_limits(args.clips, args.body, args.out, args.skip_refused, args.exclude, args.against, args.percentiles,
                   args.note, command=argv)
    return 0


def run(argv: list[str]) -> int:
    if argv and argv[0] == "limits":
        return limits(argv[1:])
    ap = argparse.ArgumentParser(prog="pbc motion", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=("inspect", "limits"))
    ap.add_argument("clip", help="a .bvh motion clip")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the body, e.g. body=anny")
    ap.add_argument("--bvh-map", default="auto", metavar="TABLE", help="a table of conf/motion or a YAML file of "
                    "that layout; auto (default): a shipped table knowing every joint, else by name and structure")
    ap.add_argument("--frame", type=int, metavar="K", help="the clip frame of the figure (default: the middle one)")
    ap.add_argument("--out", help="the PNG to write (default: <clip name>.inspect.png here)")
    ap.add_argument("--rest-frame", type=int, metavar="K", help="the clip frame whose posture is its rest (default: "
                    "its OFFSETs' layout, or for a skeleton lying flat frame 0 when it stands as a rest, else the "
                    "clip's most neutral standing frame)")
    ap.add_argument("--no-figure", action="store_true", help="the report only")
    args = ap.parse_args(argv)
    check_motion_files()  # conf/motion's numbers, before the clip is read
    clip = Path(args.clip)
    if clip.suffix.lower() != ".bvh":
        raise ValueError(f"{clip}: give a .bvh motion clip")
    out = Path(args.out or f"{clip.stem}.inspect.png")
    if not args.no_figure and out.suffix.lower() != ".png":
        raise ValueError(f"--out {out}: give a .png file name")
    if not args.no_figure:
        require_out_dir(out.parent, holds_file=True)  # before the clip is read: the figure is the last thing written
    bvh = read_bvh(clip)
    check_skeleton(bvh)
    frame = bvh.num_frames // 2 if args.frame is None else args.frame
    if not -bvh.num_frames <= frame < bvh.num_frames:
        raise ValueError(f"--frame {frame}: {clip} has frames 0 to {bvh.num_frames - 1}")
    frame %= bvh.num_frames
    overrides = list(args.overrides)
    if not any(o.lstrip("+~").startswith("body") for o in overrides):
        overrides.insert(0, f"body={STARTERS_BODY}")  # the body the shipped models, so predict and view, use
    body = body_from_config(load_config(overrides).body)
    # the whole report, even when predict would refuse the clip: that is what a user inspects it for
    motion = bvh_to_poses(bvh, body.skeleton, choose_joint_map(bvh, args.bvh_map), allow_rest=True,
                          rest_frame=args.rest_frame, trust=True)
    print(f"body: {overrides[0] if overrides[0].startswith('body=') else 'as overridden'}")
    print("\n".join(describe(bvh, motion, body.skeleton)))
    if not args.no_figure:
        print(f"figure: {clip_figure(out, bvh, motion, body, frame)} (frame {frame})")
    return 0


main = entry_point("motion", run)

if __name__ == "__main__":
    main()
