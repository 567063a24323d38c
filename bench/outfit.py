"""The outfit bench: the two starters (the shirt over the trousers, on Anny) composed as layers
(pbc.inference.outfit) over held-out poses and corpus clips.

    python bench/outfit.py [--every 4] [--clip-frames 30] [--out docs/results/outfit]

- **held-out poses**: each starter's own test split (the shirt's 60, the trousers' 23, one after the other; every
  piece predicted on all of them), composed as conf/outfit.yaml says: per layer the % of its vertices inside the
  layers under it and inside the body before and after the push-out (PBNS/HOOD), and each piece's vertex error
  against its own drapes on its own poses, alone (its model's output) and composed;
- **body push-out**: the same on every `--every`-th test pose with each `body` setting (none, parts, whole), the
  figures the setting is chosen by;
- **corpus clips**: CMU clips and a Bandai Namco walk (../shared/corpus/motion), every `--every`-th frame, at most
  `--clip-frames` frames a clip, each model's guard on its own copy: the penetration before and after.

The drapes are each piece's own, simulated without the other piece: a composed piece that moves off the part of the
other it lies in moves off its drape there. Prints the tables and, as its last line, one JSON object of the figures
with the device.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.inference.outfit import OutfitPredictor, outfit_settings  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402
from pbc.jobs.outfit import clip_poses, read_outfit_clip, split_poses, vertex_errors  # noqa: E402

CORPUS = ROOT.parent / "shared" / "corpus"
CLIPS = ("cmu/cmu_02_01_f0110-0229.bvh", "cmu/cmu_09_01_f0060-0148.bvh", "cmu/cmu_16_02_f0140-0259.bvh",
         "bandai_dataset-2_walk_feminine_001.bvh")
BODIES = ("none", "parts", "whole")


def layer_rows(result) -> list[dict]:
    return [{"piece": r["piece"], "under": result.order[:i], "under_before_pct": r["inside_under_before_pct"],
             "under_after_pct": r["inside_under_after_pct"], "under_after_frames": r["inside_under_after_frames"],
             "body_before_pct": r["inside_body_before_pct"], "body_after_pct": r["inside_body_after_pct"],
             "moved_mm_max": r["moved_mm_max"]} for i, r in enumerate(result.layers)]


def table(title: str, rows: list[dict], frames: int, seconds: float) -> str:
    head = (f"{title}: {frames} frames, {seconds:.2f} s a frame (prediction + composition)\n"
            f"| layer | piece | inside the layers under it, before -> after | inside the body, before -> after | "
            f"moved max |\n|---|---|---|---|---|")
    lines = [f"| {i + 1} | {r['piece']} | {r['under_before_pct']:.2f}% -> {r['under_after_pct']:.2f}% | "
             f"{r['body_before_pct']:.2f}% -> {r['body_after_pct']:.2f}% | {r['moved_mm_max']:.0f} mm |"
             for i, r in enumerate(rows)]
    return "\n".join([head, *lines])


def per_frame_seconds(result, frames: int) -> float:
    return (result.seconds["predict"] + result.seconds["compose"]) / max(1, frames)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=4, help="every k-th test pose for the body settings, every k-th "
                    "clip frame (default 4)")
    ap.add_argument("--clip-frames", type=int, default=30, help="at most this many frames a clip (default 30)")
    ap.add_argument("--out", type=Path, help="write results.json here")
    args = ap.parse_args(argv)
    from bench.drape import device_name  # noqa: PLC0415 - the sibling benchmark's device line, after sys.path

    device = device_name(None)
    t0 = time.time()
    outfit = OutfitPredictor({n: ClothPredictor.from_pretrained(n) for n in ("tshirt", "trousers")})
    default = outfit.settings.body
    print(f"# device: {device}; order {outfit.order_source}: {', '.join(outfit.order)} (innermost first); "
          f"body push-out: {default} (conf/outfit.yaml)")
    figures = {"device": device, "order": outfit.order, "order_source": outfit.order_source,
               "order_pairs": outfit.pairs, "body": default}

    poses = split_poses(outfit, "test", None)
    result = outfit(poses.body, poses.pieces)
    errors = vertex_errors(result, poses.truth)
    frames = len(poses.names)
    print("\n" + table("held-out poses (each starter's test split)", layer_rows(result), frames,
                       per_frame_seconds(result, frames)))
    print("\n| piece | its own test poses | vertex error alone | composed | composed no worse |\n|---|---|---|---|---|")
    for name, e in errors.items():
        print(f"| {name} | {e['poses']} | {e['alone_cm']:.3f} cm | {e['composed_cm']:.3f} cm | "
              f"{'yes' if e['composed_cm'] <= e['alone_cm'] else 'no'} |")
    figures["held_out"] = {"frames": frames, "layers": layer_rows(result), "vertex_error": errors,
                           "seconds_per_frame": round(per_frame_seconds(result, frames), 3)}

    rows = np.arange(0, frames, args.every)
    sub_truth = {n: (np.flatnonzero(np.isin(rows, r)), d[np.isin(r, rows)]) for n, (r, d) in poses.truth.items()}
    variants = {}
    print(f"\nbody push-out on every {args.every}th held-out pose ({len(rows)} frames)\n"
          "| body | layer | inside the layers under it after | inside the body, before -> after | "
          "vertex error alone -> composed |\n|---|---|---|---|---|")
    for body in BODIES:
        outfit.settings = outfit_settings(body=body)
        res = outfit(poses.body[rows], {n: p[rows] for n, p in poses.pieces.items()})
        err = vertex_errors(res, sub_truth)
        variants[body] = {"layers": layer_rows(res), "vertex_error": err,
                          "seconds_per_frame": round(per_frame_seconds(res, len(rows)), 3)}
        for r in layer_rows(res):
            e = err[r["piece"]]
            print(f"| {body} | {r['piece']} | {r['under_after_pct']:.2f}% | {r['body_before_pct']:.2f}% -> "
                  f"{r['body_after_pct']:.2f}% | {e['alone_cm']:.3f} -> {e['composed_cm']:.3f} cm |")
    outfit.settings = outfit_settings()
    figures["body_push_out"] = {"every": args.every, "frames": len(rows), "variants": variants}

    clips = {}
    for clip in CLIPS:
        motion = read_outfit_clip(outfit, CORPUS / "motion" / clip, args.clip_frames,
                                  frames=f"::{args.every}")
        cp = clip_poses(outfit, motion)
        res = outfit(cp.body, cp.pieces)
        n = len(cp.names)
        clips[clip] = {"frames": n, "layers": layer_rows(res), "guards": cp.guards,
                       "seconds_per_frame": round(per_frame_seconds(res, n), 3)}
        print("\n" + table(f"corpus clip {clip} (every {args.every}th frame)", layer_rows(res), n,
                           per_frame_seconds(res, n)))
    figures["clips"] = clips
    worst_after = max([r["under_after_pct"] for r in figures["held_out"]["layers"]]
                      + [r["under_after_pct"] for c in clips.values() for r in c["layers"]])
    worst_before = max([r["under_before_pct"] for r in figures["held_out"]["layers"]]
                       + [r["under_before_pct"] for c in clips.values() for r in c["layers"]])
    no_worse = {n: e["composed_cm"] <= e["alone_cm"] for n, e in errors.items()}
    figures["targets"] = {"before_at_most_1pct": worst_before <= 1.0, "after_0pct": worst_after == 0.0,
                          "no_piece_worse": no_worse}
    print(f"\ntarget: at most 1% of a layer inside the layers under it before the push-out: "
          f"{'holds' if worst_before <= 1.0 else 'fails'} (worst {worst_before:.2f}%)")
    print(f"target: 0% after: {'holds' if worst_after == 0.0 else 'fails'} (worst {worst_after:.2f}%)")
    for name, ok in no_worse.items():
        e = errors[name]
        print(f"target: {name} composed no worse than alone on its own test poses: {'holds' if ok else 'fails'} "
              f"({e['alone_cm']:.3f} -> {e['composed_cm']:.3f} cm)")
    figures["seconds"] = round(time.time() - t0, 1)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps(figures, indent=1) + "\n")
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
