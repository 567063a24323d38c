"""The whole-shirt model's test error against the number of training poses, with and without mirroring.

    python docs/results/learning_curve_cpu/learning_curve.py [WORK_DIR] [--sizes 50,100,200,400,all]
           [--samples-seen 2000] [--num-samples 1200]

Resumable: each step leaves its result under WORK_DIR (default /tmp/pbc_learning_curve) and is skipped
when found, so the job can be stopped and started again; results.json and learning_curve.png are
rewritten here after every trained point.

1. The pool: `pbc.generate data=tshirt_small data.num_samples=N data.mirror=true` (the default data config,
   N poses from the D.3 sampler, each training drape's mirror image added after the split).
2. The held-out motion-capture frames: every frame but the calibration frame 0 of the two CMU excerpts in
   tests/data/bvh (a walk, the start of a jump), draped on the same scene with the same settings. No D.6
   verdict keeps them out (none passes it today: docs/results/real_motion_drapes): they are scored as
   drapes of poses the model never saw, with the verdict recorded beside each.
3. For each size n and mirroring off/on: a dataset whose training split is the pool's first n drapes (and
   their mirror images), tested on the pool's test split (pbc.data.subset); the whole model trained on it
   by `python -m pbc.train +experiment=whole` for the same number of samples seen at every size
   (`--samples-seen`; epochs = ceil(samples seen / training rows)), so a point differs from the next by its
   data, not its compute; then scored with its own training mean shape (the mean offsets of its n poses)
   on the sampled test poses and on the motion-capture frames.
"""

from __future__ import annotations

import argparse
import math
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from pbc.core.config import load_config
from pbc.core.io import read_json, save_figure, write_json
from pbc.data.dataset import load_dataset
from pbc.data.generate import build_scene, drape_pose, generate
from pbc.data.subset import originals_and_mirrors, subset_dataset
from pbc.inference.predictor import ClothPredictor
from pbc.motion.bvh import read_bvh
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, parse_frames
from pbc.pretrained.pack import mean_training_offsets, score

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
SAMPLES_SEEN = 2000  # the curve's budget per point; a point trained for another budget is named for it
CLIPS = (REPO / "tests/data/bvh/cmu_mb_02_01_walk.bvh", REPO / "tests/data/bvh/cmu_mb_01_01_lfingers.bvh")


def pool_config(work: Path, data: str, num_samples: int) -> list[str]:
    return [f"data={data}", f"data.num_samples={num_samples}", "data.mirror=true",
            f"paths.data_dir={work / 'data'}"]


def mocap_set(work: Path, overrides: list[str]) -> dict:
    """The motion-capture frames and pbc's drapes of them (cached in work/mocap.npz)."""
    path = work / "mocap.npz"
    if not path.is_file():
        scene, _ = build_scene(load_config(overrides))
        poses, verts, verdicts = [], [], []
        for clip in CLIPS:
            bvh = read_bvh(clip)
            frames = np.asarray(bvh_to_poses(bvh, scene.body.skeleton, choose_joint_map(bvh, "auto"),
                                             parse_frames("1:")).poses, np.float32)
            for k, pose in enumerate(frames):
                rec = drape_pose(scene, pose)
                poses.append(pose)
                verts.append(rec["positions"])
                verdicts.append(f"{clip.stem}[{k + 1}] {rec['reason'] or 'kept'}")
                print(f"mocap drape {len(poses)}: {verdicts[-1]} ({rec['iterations']} frames)", flush=True)
        np.savez(path.with_suffix(".tmp.npz"), poses=np.stack(poses), verts=np.stack(verts),
                 verdicts=np.array(verdicts))
        path.with_suffix(".tmp.npz").replace(path)
    z = np.load(path)
    return {"poses": z["poses"], "verts": z["verts"], "verdicts": [str(v) for v in z["verdicts"]]}


def train_point(work: Path, pool, overrides: list[str], n: int, mirrors: bool, samples_seen: int) -> dict:
    """Train (or find) the point's run; returns its record without scores."""
    data_name = f"n{n:04d}_{'mirror' if mirrors else 'plain'}"
    name = data_name + ("" if samples_seen == SAMPLES_SEEN else f"_s{samples_seen}")
    sub = work / "subsets" / data_name
    run = work / "runs" / name
    done = run / "learning_curve_point.json"
    if done.is_file():
        return read_json(done)
    if not (sub / "manifest.json").is_file():
        subset_dataset(pool, sub, n, mirrors=mirrors)
    rows = len(load_dataset(sub).split("train"))
    epochs = max(1, math.ceil(samples_seen / rows))
    cmd = [sys.executable, "-m", "pbc.train", "+experiment=whole", *overrides, f"data.dir={sub}", "trainer=cpu",
           f"trainer.max_epochs={epochs}", f"trainer.check_val_every_n_epoch={max(1, epochs // 4)}",
           "trainer.enable_progress_bar=false", f"hydra.run.dir={run}", "test=false"]
    print(f"{name}: {rows} training rows, {epochs} epochs: {' '.join(cmd[2:])}", flush=True)
    t0 = time.time()
    subprocess.run(cmd, check=True, cwd=REPO)
    record = {"name": name, "train_poses": n, "mirrors": mirrors, "train_rows": rows, "epochs": epochs,
              "budget": samples_seen, "samples_seen": epochs * rows, "train_wall_s": round(time.time() - t0, 1)}
    write_json(done, record)
    return record


def score_point(work: Path, record: dict, pool, mocap: dict) -> dict:
    pred = ClothPredictor.from_runs(work / "runs" / record["name"])
    mean = mean_training_offsets(pred)
    test = pool.split("test")
    sampled = score(pred, torch.from_numpy(np.asarray(pool.poses[test], np.float32)),
                    torch.from_numpy(np.asarray(pool.verts[test], np.float32)), mean)
    real = score(pred, torch.from_numpy(mocap["poses"]), torch.from_numpy(mocap["verts"]), mean)
    out = dict(record)
    for key, s in (("sampled", sampled), ("mocap", real)):
        out[key] = {"model_cm": round(float(s["model"].mean()), 4),
                    "mean_shape_cm": round(float(s["mean_shape"].mean()), 4),
                    "ratio": round(float(s["model"].mean() / s["mean_shape"].mean()), 4),
                    "beats_mean_on": int((s["model"] < s["mean_shape"]).sum()), "poses": len(s["model"])}
    return out


def plot(results: list[dict], path: Path, data: str) -> None:
    import matplotlib  # noqa: PLC0415 - only the figure needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, key, title in ((axes[0], "sampled", "held-out sampled poses (D.3)"),
                           (axes[1], "mocap", "held-out motion-capture frames (CMU)")):
        groups = sorted({(r["mirrors"], r.get("budget", SAMPLES_SEEN)) for r in results})
        for mirrors, budget in groups:
            pts = sorted((r for r in results if r["mirrors"] == mirrors and r.get("budget", SAMPLES_SEEN) == budget),
                         key=lambda r: r["train_poses"])
            style = ("--" if mirrors else "-") + ("o" if budget == SAMPLES_SEEN else "^")
            x = [r["train_poses"] for r in pts]
            tag = ("mirrored" if mirrors else "plain") + ("" if budget == SAMPLES_SEEN else f", {budget:,} seen")
            ax.plot(x, [r[key]["model_cm"] for r in pts], style, color="C0" if budget == SAMPLES_SEEN else "C2",
                    label=f"model ({tag})")
            if budget == SAMPLES_SEEN:
                ax.plot(x, [r[key]["mean_shape_cm"] for r in pts], style[:-1] + "s", color="C1",
                        label=f"training mean shape ({tag})")
        ax.set_xscale("log")
        ticks = sorted({r["train_poses"] for r in results})
        ax.set_xticks(ticks, [str(t) for t in ticks])
        ax.minorticks_off()
        ax.set_xlabel("training poses (draped; mirror images not counted)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("mean vertex error (cm)")
    axes[1].legend(fontsize=8)
    fig.suptitle(f"Whole-shirt model vs its training mean shape, {data}: {SAMPLES_SEEN:,} samples seen per point")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv: list[str]) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("work", nargs="?", default="/tmp/pbc_learning_curve", type=Path)
    ap.add_argument("--sizes", default="50,100,200,400,all")
    ap.add_argument("--samples-seen", type=int, default=SAMPLES_SEEN)
    ap.add_argument("--num-samples", type=int, default=1200)
    ap.add_argument("--mirror", choices=("both", "off", "on"), default="both")
    ap.add_argument("--data", default="tshirt_small", help="the data config of the pool (tshirt_tiny: a smoke run)")
    ap.add_argument("--override", action="append", default=[], help="one more config override of the pool "
                    "(a smoke run: sim.max_frames=30); it is part of the pool's identity")
    ap.add_argument("--out", default=HERE, type=Path, help="where results.json and learning_curve.png go")
    args = ap.parse_args(argv)
    work = args.work.resolve()
    overrides = pool_config(work, args.data, args.num_samples) + args.override
    pool = load_dataset(generate(load_config(overrides)))
    mocap = mocap_set(work, overrides)
    n_all = len(originals_and_mirrors(pool)[0])
    sizes = sorted({n_all if s == "all" else min(int(s), n_all) for s in args.sizes.split(",")})
    modes = {"both": (False, True), "off": (False,), "on": (True,)}[args.mirror]
    results_path = args.out / "results.json"
    old = read_json(results_path)["points"] if results_path.is_file() else []
    results = {r["name"]: r for r in old}
    for n in sizes:
        for mirrors in modes:
            record = train_point(work, pool, overrides, n, mirrors, args.samples_seen)
            if record["name"] not in results or "sampled" not in results[record["name"]]:
                results[record["name"]] = score_point(work, record, pool, mocap)
                r = results[record["name"]]
                print(f"{r['name']}: sampled {r['sampled']['model_cm']:.3f} vs mean "
                      f"{r['sampled']['mean_shape_cm']:.3f} cm; mocap {r['mocap']['model_cm']:.3f} vs "
                      f"{r['mocap']['mean_shape_cm']:.3f} cm", flush=True)
            points = sorted(results.values(), key=lambda r: (r["train_poses"], r["mirrors"]))
            write_json(results_path, {
                "machine": f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} threads, cpu",
                "pool": {"dir": str(pool.dir), "kept": len(pool), "train_poses": n_all,
                         "test_poses": len(pool.split("test")), "counts": pool.manifest["counts"]},
                "mocap": {"frames": len(mocap["poses"]), "verdicts": mocap["verdicts"]},
                "data": args.data, "samples_seen": args.samples_seen, "points": points})
            plot(points, args.out / "learning_curve.png", args.data)
    return list(results.values())


if __name__ == "__main__":
    main(sys.argv[1:])
