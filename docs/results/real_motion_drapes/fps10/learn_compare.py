"""Models learnt from fps-10 drapes against models learnt from fps-20 drapes, each scored on both kinds of drape.

    python docs/results/real_motion_drapes/fps10/learn_compare.py WORK10 WORK20 > OUT

WORK10, WORK20: work folders of docs/results/learning_curve_cpu/learning_curve.py run with `--override sim.fps=10`
and `--override sim.fps=20` (the same 500 D.3 draws of tshirt_small, the whole model, its pool's training split).
Each model (every run under WORK*/runs*/: seeds) is scored against its own training mean shape on: each pool's
test split (the same sampler's poses, draped at 20 and at 10 frames a second; the other pool's test poses only
where the model did not train on that draw) and the 18 CMU frames of tests/data/bvh with their arms fitted, draped
both ways here. Also: how far the two drapes of the test poses both pools hold lie apart. Last line: one JSON.
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "bench"))
from drape import real_motion_poses  # noqa: E402 - bench/drape.py, put on the path above

from pbc.core.config import load_config
from pbc.data.dataset import load_dataset
from pbc.data.generate import build_scene
from pbc.geometry.body.base import pose_body
from pbc.geometry.shrinkwrap import start_points
from pbc.inference.predictor import ClothPredictor
from pbc.motion.fit import clear_clip_arms
from pbc.motion.retarget import motion_settings
from pbc.pretrained.pack import mean_training_offsets, score
from pbc.sim.drape import check_garment_result, drape_garment

works = {"fps10": Path(sys.argv[1]), "fps20": Path(sys.argv[2])}
pools = {k: load_dataset(next((w / "data").iterdir())) for k, w in works.items()}
# every trained run of each work folder: runs/ (the learning curve's, seed 0), runs_seed1/ ... (seed=1)
runs = {(k, r.parent.name): r for k, w in works.items() for r in sorted(w.glob("runs*/*")) if r.is_dir()}
preds = {key: ClothPredictor.from_runs(r) for key, r in runs.items()}
means = {key: mean_training_offsets(p) for key, p in preds.items()}
# the draws (generation sample ids) each model trained on: the pools' splits differ (their kept sets do), so a
# pool's test poses are scored only where the model never saw them
trained = {key: set(np.asarray(p.dataset.manifest["source_index"])[p.dataset.split("train")].tolist())
           for key, p in preds.items()}
source = {k: np.asarray(pool.manifest["source_index"]) for k, pool in pools.items()}

sets = {}
for k, pool in pools.items():
    t = pool.split("test")
    sets[f"test_{k}"] = (np.asarray(pool.poses[t], np.float32), np.asarray(pool.verts[t], np.float32), source[k][t])

# the CMU frames, arms fitted, draped at each frame rate (cached beside WORK10)
cache = works["fps10"] / "mocap_fitted.npz"
if not cache.is_file():
    cfgs = {k: load_config(["data=tshirt_small", f"sim.fps={k[3:]}"]) for k in works}
    scene, _ = build_scene(cfgs["fps20"])
    body = scene.body
    poses, names = real_motion_poses(body.skeleton, 18)
    poses = clear_clip_arms(np.asarray(poses), body, motion_settings().clear_arms)[0].astype(np.float32)
    out = {"poses": poses, "names": np.array(names)}
    for k, c in cfgs.items():
        verts, verdicts = [], []
        for name, pose in zip(names, poses, strict=True):
            bv = pose_body(body, torch.from_numpy(pose)[None])
            start = start_points(bv, body.faces, scene.embedding, float(c.sim.thickness))[0]
            r = drape_garment(scene.garment, start, bv[0], body, scene.embedding, c.sim)
            verts.append(r.positions.astype(np.float32))
            verdicts.append(check_garment_result(r, scene.garment, c.sim)[1] or "kept")
            print(f"# mocap {k} {name}: {verdicts[-1]} ({r.iterations} frames)", flush=True)
        out[f"verts_{k}"], out[f"verdicts_{k}"] = np.stack(verts), np.array(verdicts)
    np.savez(cache, **out)
z = np.load(cache)
for k in works:
    sets[f"mocap_{k}"] = (z["poses"], z[f"verts_{k}"], None)

rows = []
print(f"{'model':12s} {'run':10s} {'scored on':12s} {'poses':>5s} {'model cm':>9s} {'mean shape':>10s} {'ratio':>6s} "
      f"{'beats mean':>10s}")
for m, pred in preds.items():
    for s, (p, v, src) in sets.items():
        unseen = np.ones(len(p), bool) if src is None else ~np.isin(src, list(trained[m]))
        p, v = p[unseen], v[unseen]
        r = score(pred, torch.from_numpy(p), torch.from_numpy(v), means[m])
        row = {"model": f"learnt_{m[0]}", "run": m[1], "scored_on": s, "poses": len(p),
               "model_cm": round(float(r["model"].mean()), 4),
               "mean_shape_cm": round(float(r["mean_shape"].mean()), 4),
               "ratio": round(float(r["model"].mean() / r["mean_shape"].mean()), 4),
               "beats_mean_on": int((r["model"] < r["mean_shape"]).sum())}
        rows.append(row)
        print(f"{row['model']:12s} {m[1]:10s} {s:12s} {row['poses']:5d} {row['model_cm']:9.3f} "
              f"{row['mean_shape_cm']:10.3f} {row['ratio']:6.2f} {row['beats_mean_on']:6d}/{row['poses']}")

# the two drapes of the test poses both pools hold (the same draw: the same pose)
t10, t20 = (set(source[k][pools[k].split("test")].tolist()) for k in ("fps10", "fps20"))
row_of = {k: {int(s): i for i, s in enumerate(source[k])} for k in source}
common = sorted(t10 & t20)
gaps = [1000 * np.linalg.norm(pools["fps10"].verts[row_of["fps10"][i]] - pools["fps20"].verts[row_of["fps20"][i]],
                              axis=1) for i in common]
mocap_gap = 1000 * np.linalg.norm(z["verts_fps10"] - z["verts_fps20"], axis=2)
drapes = {"common_test_poses": len(common),
          "mean_mm": round(float(np.mean([g.mean() for g in gaps])), 2) if gaps else None,
          "p95_mm": round(float(np.mean([np.quantile(g, 0.95) for g in gaps])), 2) if gaps else None,
          "mocap_mean_mm": round(float(mocap_gap.mean()), 2),
          "mocap_kept": {k: int((z[f"verdicts_{k}"] == "kept").sum()) for k in works},
          "pool_counts": {k: pools[k].manifest["counts"] for k in pools}}
print(f"\nfps 10 vs fps 20 drapes of the {len(common)} test poses in both pools: {drapes['mean_mm']} mm mean "
      f"(95th percentile {drapes['p95_mm']}); of the 18 CMU frames: {drapes['mocap_mean_mm']} mm; "
      f"CMU frames kept {drapes['mocap_kept']}")
print(json.dumps({"rows": rows, "drapes": drapes, "runs": {f"{k}/{d}": str(r) for (k, d), r in runs.items()}}))
