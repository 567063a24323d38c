"""Per-stage cost of dataset generation on this machine: scene, pose sampling, skinning, drape, write.

    python bench/generate.py [data=tshirt_small] [n=6]

Prints a table and, as the last line, one JSON object of the figures. Samples/minute is projected for
`data.workers` processes (one drape per core: warp's CPU kernels are single-threaded). With
`sim.batch_size` > 1 (e.g. `data=tshirt_gpu n=512`) the n poses go through the batched drape as one
batch, after a warm-up batch that builds the worker's model (its build time, which includes loading
warp's kernels, is reported apart).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pbc.core.config import load_config
from pbc.core.io import atomic_path
from pbc.data.generate import batch_size, build_scene, drape_batch, drape_pose
from pbc.sim.drape import init_warp
from pbc.sim.poses import sample_poses, sampling_settings_from_config


def main(argv: list[str]) -> dict:
    n = int(next((a.split("=", 1)[1] for a in argv if a.startswith("n=")), 6))
    overrides = [a for a in argv if not a.startswith("n=")] or ["data=tshirt_small"]
    cfg = load_config(overrides)
    t0 = time.perf_counter()
    scene, wrap = build_scene(cfg)
    t_scene = time.perf_counter() - t0

    t0 = time.perf_counter()
    settings = sampling_settings_from_config(cfg.body.sampling)
    poses, _ = sample_poses(scene.body.skeleton, n, int(cfg.data.seed), scene.body, settings)
    t_pose = (time.perf_counter() - t0) / n
    poses = poses.numpy().astype(np.float32)

    batched = batch_size(cfg.sim) > 1
    # warm-up: warp compiles or loads its kernels once per process (and a batched worker builds its model)
    if batched:
        drape_batch(scene, poses[:1])
    else:
        drape_pose(scene, poses[0])
    recs, t_write = (drape_batch(scene, poses) if batched else []), []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            rec = recs[i] if batched else drape_pose(scene, poses[i])
            t0 = time.perf_counter()
            with atomic_path(Path(tmp) / f"{i}.npz", suffix=".npz") as f:
                np.savez(f, positions=rec["positions"])
            t_write.append(time.perf_counter() - t0)
            if not batched:
                recs.append(rec)
    skin = float(np.mean([r["t_skin"] for r in recs]))
    drape = float(np.mean([r["t_drape"] for r in recs]))
    write = float(np.mean(t_write))
    per_sample = t_pose + skin + drape + write
    workers = int(cfg.data.workers)
    figures = {
        "data": cfg.data.name,
        "device": str(init_warp(cfg.sim.kernel_cache_dir).get_device()),
        "batch_size": batch_size(cfg.sim),
        "batch_worlds": scene.batched.n_worlds if batched else 1,
        "model_build_s": round(scene.batched.build_seconds, 2) if batched else 0.0,
        "vertices": int(scene.garment.vertices.shape[0]),
        "samples": n,
        "scene_s": round(t_scene, 2),
        "sample_pose_s": round(t_pose, 4),
        "skin_s": round(skin, 4),
        "drape_s": round(drape, 2),
        "drape_max_s": round(max(r["t_drape"] for r in recs), 2),
        "write_s": round(write, 4),
        "drape_share": round(drape / per_sample, 3),
        "samples_per_min_per_core": round(60 / per_sample, 2),
        "workers": workers,
        "samples_per_min": round(60 * workers / per_sample, 2),
        "kept": int(sum(r["ok"] for r in recs)),
        "residual_max": float(max(r["residual"] for r in recs)),
        "projected_minutes_for_dataset": round(int(cfg.data.num_samples) * per_sample / workers / 60, 1),
    }
    print(f"{'stage':<16}{'seconds/sample':>16}")
    for k in ("sample_pose_s", "skin_s", "drape_s", "write_s"):
        print(f"{k[:-2]:<16}{figures[k]:>16.4f}")
    print(f"{'(scene, once)':<16}{t_scene:>16.2f}")
    print(
        f"{figures['vertices']} vertices: {figures['samples_per_min_per_core']} samples/min/core, "
        f"{figures['samples_per_min']} with {workers} workers; {cfg.data.name} ({cfg.data.num_samples} poses) "
        f"~{figures['projected_minutes_for_dataset']} min; kept {figures['kept']}/{n}"
    )
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main(sys.argv[1:])
