"""Updates a second of `pbc view`: one slider move -> prediction + posed body -> the meshes pushed to the scene.

    .venv/bin/python bench/view.py                                   # paper-size random decoders, stand-in shirt
    .venv/bin/python bench/view.py --data data/tshirt_small_seed0    # the same decoders on a real dataset
    .venv/bin/python bench/view.py --whole RUN --patches SWEEP_DIR   # trained runs

A viser server runs with no browser attached, so the figure is the viewer's own work per update (what a
browser adds is its own drawing). Each row alternates two poses (nothing is cached) and reports the mean
milliseconds of an update, the predictor alone beside it, and updates a second (1000 / mean). The issue's
goal: at least 10 updates a second with the whole model on 2 CPU cores; the stitched model as fast as it
goes. Timings are only comparable on a quiet machine; say when it is shared. Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests"))  # the stand-in shirt: tests/helpers/evaluate_world.py

GOAL_UPDATES_S = 10.0  # the viewer's goal: the whole model on 2 CPU cores


def mean_ms(fn, poses, reps: int) -> float:
    fn(poses[0])  # warm-up: allocations, oneDNN primitive caches, the PCA basis
    fn(poses[1])
    t0 = time.perf_counter()
    for k in range(reps):
        fn(poses[k % len(poses)])
    return 1000 * (time.perf_counter() - t0) / reps


def predictor_from(args):
    from pbc.inference.predictor import ClothPredictor, stitch_config

    if args.whole or args.patches:
        return ClothPredictor.from_runs(args.whole, args.patches, stitch_config("average") if args.patches else None)
    from predict import paper_predictor  # bench/predict.py: random paper-size decoders on the stand-in shirt

    pred = paper_predictor(stitch_config("average"))
    if args.data:  # the same networks on a real dataset's garment and body
        from helpers.evaluate_world import IMAGE

        from pbc.data.dataset import load_dataset

        pred = ClothPredictor(load_dataset(args.data), IMAGE, pred.whole_net, pred.patch_nets,
                              stitch_config("average"))
    return pred


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--whole")
    ap.add_argument("--patches", nargs="*")
    ap.add_argument("--data", help="a dataset dir for the random decoders (default: the stand-in shirt)")
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--threads", type=int, help="torch threads (default torch's: one a core); on a loaded machine "
                                                 "1 can beat 2, whose threads wait on each other")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    from pbc.jobs.view import ClothViewer, start_viewer, view_meshes

    pred = predictor_from(args)
    viewer: ClothViewer = start_viewer(pred, "127.0.0.1", 0, log=lambda *_: None)
    ds = pred.dataset
    poses = [torch.from_numpy(np.array(ds.poses[i], dtype=np.float32)) for i in range(min(4, len(ds.poses)))]
    cpu = platform.processor() or platform.machine()
    print(f"device CPU ({cpu}), {os.cpu_count()} cores, torch threads {torch.get_num_threads()}, garment V = "
          f"{ds.garment.vertices.shape[0]}, body V = {ds.body.vertices.shape[0]}, {args.reps} updates a row\n")
    print("| model | seam method | update ms | prediction + body alone ms | updates / s |\n|---|---|---|---|---|",
          flush=True)
    rows = {}
    combos = [("whole", None)] if pred.whole_net is not None else []
    if pred.patch_net is not None:
        combos += [("patches", m) for m in ("average", "pca", "hierarchy")]
    try:
        for model, method in combos:
            viewer.model.value = {"whole": "whole", "patches": "stitched patches"}[model]
            if method:
                viewer.method.value = method  # pca: its basis is fitted here, before the timing

            ms = mean_ms(lambda p: viewer.refresh(p, None), poses, args.reps)
            ms_pred = mean_ms(lambda p, model=model, method=method: view_meshes(pred, p, model, method), poses,
                              args.reps)
            key = model if method is None else f"patches_{method}"
            rows[key] = {"update_ms": round(ms, 2), "predictor_ms": round(ms_pred, 2),
                         "updates_per_s": round(1000 / ms, 1)}
            print(f"| {model} | {method or '-'} | {ms:.1f} | {ms_pred:.1f} | {1000 / ms:.1f} |", flush=True)
    finally:
        viewer.close()
        viewer.server.stop()
    out = {"bench": "view", "device": f"CPU ({cpu}), {os.cpu_count()} cores, {torch.get_num_threads()} threads",
           "rows": rows}
    if "whole" in rows:
        out["whole_meets_goal"] = rows["whole"]["updates_per_s"] >= GOAL_UPDATES_S
        for k, r in rows.items():
            if k != "whole":
                out[f"{k}_vs_whole_time"] = round(r["update_ms"] / rows["whole"]["update_ms"], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
