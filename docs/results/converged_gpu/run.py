"""Models trained to convergence on one GPU: the learning curve (issue 33) and the paper's Tables 1-2 (issue 37).

    python docs/results/converged_gpu/run.py WORK --pack DIR [--deadline-s 480] [--parallel 6] [--budget 60000]

One pool of drapes (pack.py: the default data config, 923 kept, 739 training drapes and their 739 mirror
images), every model trained by `python -m pbc.train` to the same budget of samples seen under a cosine
decay with early stopping, several runs at once on the one GPU. Jobs start in priority order and each gets
Lightning's `max_time` up to the deadline, so a run cut short still tests its best checkpoint and says so
(`stopped_by`). Each finished whole-model run is scored with its own training mean shape on the pool's
sampled test poses and on the motion-capture frames (pbc.pretrained.pack.score).

Jobs (name: data, model):
- table1_{loss}_s{seed}: the 1,478 mirrored rows, the whole CNN under loss l1, l2, l2_normal, l1_normal
  (table1_l1 is also Table 2's CNN column and the curve's mirrored 739-pose point);
- table2_{experiment}_s{seed}: the same rows, the six fully connected baselines (L1);
- table2_l2_{experiment}_s{seed}: the same six under L2 (the loss the CNN does best with here);
- curve_n{n}_s{seed}: the first n training drapes without mirrors, the whole CNN under L1;
- hier_patches_s{seed}: the same rows as Table 1, the 28 patch models (L1) as one stacked job
  (`+experiment=patches`), then `pbc.evaluate` stitches them under every seam method beside table1_l1_s{seed}
  (the hierarchy: whole vs stitched patches, one evaluation per seed: evaluate_s{seed} in results.json).
`--only` takes job name prefixes and also orders the jobs: the first prefix's jobs start first.
Writes WORK/results.json and, with --out, a tarball of every run dir without its checkpoints.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from pbc.data.dataset import load_dataset
from pbc.data.mirror import MIRROR
from pbc.data.subset import subset_dataset
from pbc.inference.predictor import ClothPredictor
from pbc.pretrained.pack import mean_training_offsets, score

REPO = Path(__file__).resolve().parents[3]
LOSSES = ("l1", "l2", "l2_normal", "l1_normal")
FC = ("fc_direct_local", "fc_pca_local", "fc_direct_root", "fc_pca_root", "fc_direct_position", "fc_pca_position")
SIZES = (50, 100, 200, 400, 739)


def unpack(pack: Path, work: Path) -> Path:
    """The pool rebuilt from the pack (mirror rows remade, checked against the packed sha256)."""
    pool = work / "pool"
    meta = json.loads((pack / "pack.json").read_text())
    if (pool / "verts.npy").is_file():
        return pool
    shutil.copytree(pack / "pool", pool, dirs_exist_ok=True)
    man = json.loads((pool / "manifest.json").read_text())
    kept = np.load(pool / "verts_kept.npy")
    mm = np.load(pack / "mirror_map.npz")
    v = np.asarray(kept[man["mirrored"]["of"]], np.float64)
    mirrored = (np.einsum("nkcd,kc->nkd", v[:, mm["tri"]], mm["bary"]) @ MIRROR).astype(np.float32)
    verts = np.concatenate([kept, mirrored])
    same = hashlib.sha256(verts.tobytes()).hexdigest() == meta["verts_sha256"]
    print(f"pool rebuilt: {verts.shape}, identical to the CPU side's: {same}", flush=True)
    np.save(pool / "verts.npy", verts)
    (pool / "verts_kept.npy").unlink()
    (work / "pool_identical.txt").write_text(str(same))
    ops = pack / "operators"
    if ops.is_dir():
        dest = Path(os.environ.get("PBC_CACHE_DIR", Path.home() / ".cache/pbc")) / "operators"
        dest.mkdir(parents=True, exist_ok=True)
        for f in ops.iterdir():
            shutil.copy2(f, dest / f.name)
    return pool


def jobs(seeds: tuple[int, ...]) -> list[dict]:
    """Every job, in the order they start: each table's first seed, the curve, then the second seeds."""
    out = []
    for seed in seeds:
        out += [dict(name=f"table1_{loss}_s{seed}", data="n0739_mirror", experiment="whole", loss=loss, seed=seed)
                for loss in LOSSES]
        out += [dict(name=f"table2_{e}_s{seed}", data="n0739_mirror", experiment=e, loss="l1", seed=seed) for e in FC]
        out += [dict(name=f"table2_l2_{e}_s{seed}", data="n0739_mirror", experiment=e, loss="l2", seed=seed)
                for e in FC]
        out += [dict(name=f"curve_n{n:04d}_s{seed}", data=f"n{n:04d}_plain", experiment="whole", loss="l1", seed=seed)
                for n in SIZES]
        out.append(dict(name=f"hier_patches_s{seed}", data="n0739_mirror", experiment="patches", loss="l1", seed=seed))
    # the first seed of everything first: a deadline cuts second seeds, not whole tables
    return sorted(out, key=lambda j: j["seed"])


def train_argv(job: dict, work: Path, rows: int, budget: int, max_time_s: int, pool_overrides: list[str],
               trainer: str = "gpu") -> list[str]:
    epochs = max(2, math.ceil(budget / rows))
    every = max(1, math.ceil(epochs / 40))  # about 40 validations a run, whatever its size
    hms = time.strftime("%H:%M:%S", time.gmtime(max(60, max_time_s)))
    return [sys.executable, "-m", "pbc.train", f"+experiment={job['experiment']}", f"loss={job['loss']}",
            f"data.dir={work / 'subsets' / job['data']}", *pool_overrides, f"seed={job['seed']}", f"trainer={trainer}",
            "callbacks=early_stopping", "callbacks.early_stopping.patience=8", "+model/scheduler=cosine",
            f"trainer.max_epochs={epochs}", f"trainer.check_val_every_n_epoch={every}",
            f"callbacks.last_checkpoint.every_n_epochs={every}",
            f"+trainer.max_time=00:{hms}", "trainer.enable_progress_bar=false",
            f"hydra.run.dir={work / 'runs' / job['name']}", "test=true"]


def score_run(run: Path, pool, mocap) -> dict:
    pred = ClothPredictor.from_runs(run)
    mean = mean_training_offsets(pred)
    test = pool.split("test")
    out = {}
    sets = (("sampled", pool.poses[test], pool.verts[test]), ("mocap", mocap["poses"], mocap["verts"]))
    for key, poses, verts in sets:
        s = score(pred, torch.from_numpy(np.asarray(poses, np.float32)),
                  torch.from_numpy(np.asarray(verts, np.float32)), mean)
        out[key] = {"model_cm": round(float(s["model"].mean()), 4),
                    "mean_shape_cm": round(float(s["mean_shape"].mean()), 4),
                    "ratio": round(float(s["model"].mean() / s["mean_shape"].mean()), 4),
                    "beats_mean_on": int((s["model"] < s["mean_shape"]).sum()), "poses": len(s["model"])}
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--pack", type=Path, required=True)
    ap.add_argument("--deadline-s", type=float, default=480)
    ap.add_argument("--parallel", type=int, default=6)
    ap.add_argument("--budget", type=int, default=60000, help="samples seen per run (epochs = budget / rows)")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--only", default="", help="comma list of job name prefixes (a smoke run)")
    ap.add_argument("--trainer", default="gpu", help="trainer preset (cpu: a smoke run here)")
    ap.add_argument("--extra", default="", help="space-separated overrides added to every pbc.train call (a smoke "
                    "run: 'trainer.limit_train_batches=2 trainer.limit_val_batches=1')")
    ap.add_argument("--eval-methods", default="", help="comma list of seam methods pbc.evaluate scores (default: "
                    "its conf's all six; a subset when the call's time is short)")
    ap.add_argument("--out", type=Path, help="where the tarball of run dirs (no checkpoints) and results go")
    args = ap.parse_args(argv)
    t0 = time.time()
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    pool = load_dataset(unpack(args.pack, work))
    z = np.load(args.pack / "mocap.npz")
    mocap = {"poses": z["poses"], "verts": z["verts"]}
    todo = jobs(tuple(int(s) for s in args.seeds.split(",")))
    if args.only:  # the prefixes filter and order: a job starts in the order of the first prefix it matches
        prefixes = args.only.split(",")
        rank = {j["name"]: next((k for k, p in enumerate(prefixes) if j["name"].startswith(p)), None) for j in todo}
        todo = sorted((j for j in todo if rank[j["name"]] is not None), key=lambda j: rank[j["name"]])
    # the pool's own data settings (the default data config with these), so that pbc.train accepts its data
    # (the pool was draped before the shear stiffness went from 10 to 40: its own value is named)
    shear = pool.manifest["sim"]["stretch_ke"]
    pool_overrides = [f"data.num_samples={pool.manifest['counts']['requested']}", "data.mirror=true",
                      "sim.stretch_ke=[" + ",".join(repr(float(x)) for x in shear) + "]"]
    rows = {}
    for name in sorted({j["data"] for j in todo}):
        sub = work / "subsets" / name
        if not (sub / "manifest.json").is_file():
            n, kind = int(name[1:5]), name.split("_")[1]
            subset_dataset(pool, sub, n, mirrors=kind == "mirror")
        rows[name] = len(load_dataset(sub).split("train"))
    print(f"{len(todo)} jobs; subsets ready at {time.time() - t0:.0f} s: {rows}", flush=True)
    results_path = work / "results.json"
    results = json.loads(results_path.read_text())["runs"] if results_path.is_file() else {}
    lock = threading.Lock()

    def run(job: dict) -> None:
        left = args.deadline_s - (time.time() - t0)
        run_dir = work / "runs" / job["name"]
        if job["name"] in results or left < 120:
            return
        argv = train_argv(job, work, rows[job["data"]], args.budget, int(left - 60), pool_overrides,
                          args.trainer) + args.extra.split()
        ts = time.time()
        with open(work / f"{job['name']}.log", "w") as log:
            code = subprocess.run(argv, cwd=REPO, stdout=log, stderr=subprocess.STDOUT).returncode
        rec = dict(job, train_rows=rows[job["data"]], returncode=code, wall_s=round(time.time() - ts, 1))
        m = run_dir / "metrics.json"
        if m.is_file():
            met = json.loads(m.read_text())
            rec.update(epochs=met.get("epochs"), test=met.get("test"), val_best=met.get("val_best"),
                       seconds=met.get("seconds"), best_checkpoint=Path(str(met.get("best_checkpoint"))).name)
        print(f"[{time.time() - t0:5.0f} s] {job['name']}: rc {code}, {rec['wall_s']} s, "
              f"test {json.dumps(rec.get('test'))[:160]}", flush=True)
        with lock:
            results[job["name"]] = rec
            results_path.write_text(json.dumps({"runs": results}, indent=1))

    with ThreadPoolExecutor(args.parallel) as ex:
        list(ex.map(run, todo))
    evals = {}  # the hierarchy: each seed's stitched patches beside its whole model, while the runs are scored
    for seed in sorted({j["seed"] for j in todo if j["experiment"] == "patches"}):
        whole, patches = results.get(f"table1_l1_s{seed}", {}), results.get(f"hier_patches_s{seed}", {})
        if whole.get("returncode") == 0 and patches.get("returncode") == 0 and f"evaluate_s{seed}" not in results:
            out = work / f"evaluate_s{seed}"
            argv = [sys.executable, "-m", "pbc.evaluate", f"whole_run='{work / 'runs' / f'table1_l1_s{seed}'}'",
                    f"patch_runs='{work / 'runs' / f'hier_patches_s{seed}'}'", f"hydra.run.dir={out}"]
            if args.eval_methods:
                argv.append(f"methods=[{args.eval_methods}]")
            log = open(work / f"evaluate_s{seed}.log", "w")  # noqa: SIM115 - closed when the process is waited on
            evals[seed] = (subprocess.Popen(argv, cwd=REPO, stdout=log, stderr=subprocess.STDOUT), log, out,
                           time.time())
    for name, rec in results.items():  # scoring after training: the GPU is free by then
        if rec["experiment"] == "whole" and rec.get("returncode") == 0 and "sampled" not in rec:
            try:
                rec.update(score_run(work / "runs" / name, pool, mocap))
                print(f"{name}: sampled {rec['sampled']}, mocap {rec['mocap']}", flush=True)
            except Exception as e:  # noqa: BLE001 - a failed score is recorded, the others still run
                rec["score_error"] = f"{type(e).__name__}: {e}"
    for seed, (proc, log, out, ts) in evals.items():
        code = proc.wait()
        log.close()
        rec = {"experiment": "evaluate", "seed": seed, "returncode": code, "wall_s": round(time.time() - ts, 1)}
        if (out / "metrics.json").is_file():
            rec["metrics"] = json.loads((out / "metrics.json").read_text())
        print(f"evaluate_s{seed}: rc {code}, {rec['wall_s']} s", flush=True)
        results[f"evaluate_s{seed}"] = rec
    meta = {"device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
            "torch": torch.__version__, "budget_samples": args.budget, "parallel": args.parallel,
            "pool_rebuilt_identical": (work / "pool_identical.txt").read_text(),
            "wall_s": round(time.time() - t0, 1)}
    results_path.write_text(json.dumps({"meta": meta, "runs": results}, indent=1))
    print(json.dumps(meta), flush=True)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        shutil.copy2(results_path, args.out / "results.json")
        with tarfile.open(args.out / "runs.tgz", "w:gz") as tar:
            for p in sorted((work / "runs").glob("*")):
                tar.add(p, arcname=f"runs/{p.name}",
                        filter=lambda ti: None if ti.name.endswith((".ckpt", ".obj")) else ti)
            for p in sorted(work.glob("*.log")):
                tar.add(p, arcname=f"logs/{p.name}")
            for p in sorted(work.glob("evaluate_s*")):
                tar.add(p, arcname=p.name, filter=lambda ti: None if ti.name.endswith((".ckpt", ".obj")) else ti)
        data = (args.out / "runs.tgz").read_bytes()
        if len(data) > 15 * 2**20:  # the machine returns files of at most 16 MiB: parts, rejoined by `cat`
            (args.out / "runs.tgz").unlink()
            for k in range(0, len(data), 15 * 2**20):
                (args.out / f"runs.tgz.part{k // (15 * 2**20)}").write_bytes(data[k:k + 15 * 2**20])


if __name__ == "__main__":
    main(sys.argv[1:])
