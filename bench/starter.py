"""The starter models' quality gate: held-out real motion, draped by pbc's own simulator, scored against the model.

    python bench/starter.py [--model tshirt] [--clip walk.bvh ...] [--every K] [--out docs/results/starter]

For a shipped model (`--model NAME`, pbc/pretrained/NAME) or a trained whole/fc run dir: every motion frame of
the CMU excerpts in tests/data/bvh (a walk, the start of a jump; frame 0 of each, the converter's calibration
pose, skipped) and of each `--clip` (every K-th frame), retargeted onto the model's body as `pbc predict` takes
a clip (arms a retarget hangs inside the torso raised out of it: pbc.motion.fit). Each frame is

- flagged when a joint the model reads leaves its training poses' range (`run_pose_range`, as pbc predict),
- draped by pbc's simulator in the model's own data config (its run's `sim` node, its garment, body and
  embedding): kept or discarded by the D.6 check,
- scored: the model's vertex error against that drape, beside the training mean shape's (its recorded mean
  offsets, skinned), in cm, on the kept frames.

The issue's targets: the model at most 0.6x the mean shape's error, at most 10% of a walk's frames flagged, at
least 90% of frames kept by the simulator. Prints a table per clip, one line per target (pass / fail), and as
its last line one JSON object of the figures with the device. `--out` also writes results.json and
walk.png: a walk's frames, the simulation beside the model, each titled with its error.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.core.runs import RunRecord  # noqa: E402
from pbc.data.generate import Scene, drape_pose  # noqa: E402
from pbc.geometry.body.base import pose_body  # noqa: E402
from pbc.inference.poses import read_motion, run_pose_range  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402
from pbc.inference.scores import frame_errors  # noqa: E402
from pbc.jobs.writers import contact_sheet  # noqa: E402
from pbc.motion.ranges import range_report  # noqa: E402
from pbc.motion.retarget import motion_settings  # noqa: E402
from pbc.pretrained import PREFIX, pretrained_dir, shipped_models  # noqa: E402

CLIPS = [ROOT / "tests/data/bvh/cmu_mb_02_01_walk.bvh", ROOT / "tests/data/bvh/cmu_mb_01_01_lfingers.bvh"]
TARGETS = {"model_over_mean_shape": 0.6, "walk_flagged": 0.10, "kept": 0.90}


def open_model(name: str) -> tuple[ClothPredictor, Path]:
    """A shipped model by name, or a run dir."""
    if name in shipped_models() or name.startswith(PREFIX):
        d = pretrained_dir(name.removeprefix(PREFIX))
    else:
        d = Path(name)
    return ClothPredictor.from_runs(d), d


def clip_frames(pred: ClothPredictor, path: Path, every: int) -> tuple[np.ndarray, list[str]]:
    """(N, J, 3, 3) poses of a clip on the model's body, and each frame's label."""
    builtin = path in CLIPS
    motion = read_motion(path, pred.dataset, frames="1:" if builtin else f"::{every}")
    first = 1 if builtin else 0
    step = 1 if builtin else every
    for note in motion.notes:
        print(f"# {path.name}: {note}")
    return motion.poses.astype(np.float32), [f"{path.stem} {first + k * step}" for k in range(len(motion.poses))]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="tshirt", help="a shipped model's name or a whole/fc run dir")
    ap.add_argument("--clip", action="append", default=[], help="another .bvh clip (repeatable)")
    ap.add_argument("--every", type=int, default=10, help="every K-th frame of a --clip (default 10)")
    ap.add_argument("--out", type=Path, default=None, help="write results.json and walk.png here")
    args = ap.parse_args(argv)
    from bench.drape import device_name  # noqa: PLC0415 - the sibling benchmark's device line, after sys.path is set

    pred, run_dir = open_model(args.model)
    cfg = OmegaConf.create(RunRecord.read(run_dir).config)
    ds = pred.dataset
    scene = Scene(ds.body, ds.garment, ds.cage, ds.embedding, cfg.sim)
    rng = run_pose_range(pred)[0]
    tol = float(motion_settings().range_tolerance_deg)
    device = device_name(cfg.sim.get("kernel_cache_dir"))
    print(f"# device: {device}; model {args.model}: {len(ds.garment.vertices)} garment vertices, "
          f"reads {len(pred.read_joints())} of {len(ds.body.skeleton.names)} joints", flush=True)
    rows, per_clip, sheet = [], {}, None
    for path in [*CLIPS, *[Path(c) for c in args.clip]]:
        poses, labels = clip_frames(pred, path, args.every)
        report = range_report(poses.astype(np.float64), rng, list(ds.body.skeleton.names), tol)
        flagged = np.isin(np.arange(len(poses)), report["frames_outside"])
        drapes, kept, secs = [], [], []
        for pose, label in zip(poses, labels, strict=True):
            t = time.process_time()
            r = drape_pose(scene, pose, 0)
            secs.append(time.process_time() - t)
            drapes.append(r["positions"])
            kept.append(bool(r["ok"]))
            print(f"{label:28s} {'kept' if r['ok'] else r['reason']:16s} {r['iterations']:4d} frames "
                  f"{secs[-1]:5.1f} CPU s{'  flagged' if flagged[len(kept) - 1] else ''}", flush=True)
        drapes = np.stack(drapes).astype(np.float32)
        model, mean, positions = frame_errors(pred, poses, drapes)
        kept = np.array(kept)
        for k, label in enumerate(labels):
            rows.append({"clip": path.name, "frame": label, "kept": bool(kept[k]), "flagged": bool(flagged[k]),
                         "model_cm": round(float(model[k]), 4), "mean_shape_cm": round(float(mean[k]), 4)})
        on = kept if kept.any() else np.ones_like(kept)
        per_clip[path.name] = {
            "frames": len(labels), "kept": int(kept.sum()), "flagged": int(flagged.sum()),
            "model_cm": round(float(model[on].mean()), 4), "mean_shape_cm": round(float(mean[on].mean()), 4),
            "ratio": round(float(model[on].mean() / mean[on].mean()), 3),
            "scored_on": "kept frames" if kept.any() else "every frame (none kept)",
            "cpu_s_per_drape": round(float(np.mean(secs)), 2)}
        if sheet is None and args.out is not None:  # the first clip (the walk): drape beside model, titled
            sheet = _walk_sheet(args.out, ds, poses, drapes, positions, labels, model, mean, kept)
    kept_all = np.array([r["kept"] for r in rows])
    model_all = np.array([r["model_cm"] for r in rows])
    mean_all = np.array([r["mean_shape_cm"] for r in rows])
    on = kept_all if kept_all.any() else np.ones_like(kept_all)
    walk = per_clip[CLIPS[0].name]
    figures = {
        "device": device, "model": args.model, "frames": len(rows), "kept": int(kept_all.sum()),
        "kept_rate": round(float(kept_all.mean()), 3),
        "walk_flagged_rate": round(walk["flagged"] / walk["frames"], 3),
        "model_cm": round(float(model_all[on].mean()), 4), "mean_shape_cm": round(float(mean_all[on].mean()), 4),
        "model_over_mean_shape": round(float(model_all[on].mean() / mean_all[on].mean()), 3),
        "per_clip": per_clip}
    figures["targets"] = {
        "model_over_mean_shape": {"target": f"<= {TARGETS['model_over_mean_shape']}",
                                  "pass": figures["model_over_mean_shape"] <= TARGETS["model_over_mean_shape"]},
        "walk_flagged": {"target": f"<= {TARGETS['walk_flagged']}",
                         "pass": figures["walk_flagged_rate"] <= TARGETS["walk_flagged"]},
        "kept": {"target": f">= {TARGETS['kept']}", "pass": figures["kept_rate"] >= TARGETS["kept"]}}
    print("\n| clip | frames | kept | flagged | model (cm) | mean shape (cm) | ratio | scored on |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, c in per_clip.items():
        print(f"| {name} | {c['frames']} | {c['kept']} | {c['flagged']} | {c['model_cm']:.3f} | "
              f"{c['mean_shape_cm']:.3f} | {c['ratio']:.2f} | {c['scored_on']} |")
    for name, t in figures["targets"].items():
        print(f"# target {name} {t['target']}: {'pass' if t['pass'] else 'FAIL'}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps({**figures, "rows": rows}, indent=1) + "\n")
    print(json.dumps(figures))
    return figures


def _walk_sheet(out: Path, ds, poses, drapes, positions, labels, model, mean, kept, panels: int = 6) -> Path:
    """walk.png: `panels` frames spread over the clip, each as its drape then the model's garment."""
    out.mkdir(parents=True, exist_ok=True)
    pick = np.unique(np.linspace(0, len(poses) - 1, min(panels, len(poses))).round().astype(int))
    bodies = pose_body(ds.body, torch.from_numpy(poses[pick])).numpy()
    verts, titles, under = [], [], []
    for n, k in enumerate(pick):
        verts += [drapes[k], positions[k]]
        under += [bodies[n], bodies[n]]
        titles += [f"{labels[k]}: drape{'' if kept[k] else ' (discarded)'}",
                   f"model {model[k]:.2f} cm (mean {mean[k]:.2f})"]
    return contact_sheet(out / "walk.png", ds.garment.faces.numpy(), np.stack(verts), titles, np.stack(under),
                         ds.body.faces.numpy())


if __name__ == "__main__":
    main()
