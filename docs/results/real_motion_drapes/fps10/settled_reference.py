"""How far the drape stopped at sim.fps 20 (the config) and at sim.fps 10 each lie from where the cloth settles.

    python docs/results/real_motion_drapes/fps10/settled_reference.py [tshirt_small] > OUT

The reference of a pose is its drape at fps 20 run on with a stop tolerance ten times tighter (0.5 mm/s) up to
600 frames; the same at fps 10 says whether the two frame rates settle to the same cloth. The data config's first
8 sampled poses and 4 CMU frames (arms fitted), as compare_fps.py; distances in mm (mean, 95th percentile, max
over the vertices). The last line is one JSON object.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "bench"))
from drape import real_motion_poses  # noqa: E402 - bench/drape.py, put on the path above

from pbc.core.config import load_config
from pbc.data.generate import build_scene
from pbc.geometry.body.base import pose_body
from pbc.geometry.shrinkwrap import embedded_points
from pbc.motion.fit import clear_clip_arms
from pbc.motion.retarget import motion_settings
from pbc.sim.drape import check_garment_result, drape_garment
from pbc.sim.poses import sample_poses, sampling_settings_from_config

data = sys.argv[1] if len(sys.argv) > 1 else "tshirt_small"
settings = {
    "fps20": [],
    "fps10": ["sim.fps=10"],
    "settled20": ["sim.tolerance=0.0005", "sim.fold_frames=0"],
    "settled10": ["sim.fps=10", "sim.tolerance=0.0005", "sim.fold_frames=0"],
}
cfgs = {k: load_config([f"data={data}", *v]) for k, v in settings.items()}
a = cfgs["fps20"]
scene, _ = build_scene(a)
body, g, emb = scene.body, scene.garment, scene.embedding
poses, _ = sample_poses(body.skeleton, 8, int(a.data.seed), body, sampling_settings_from_config(a.body.sampling))
real, names = real_motion_poses(body.skeleton, 4)
real = clear_clip_arms(np.asarray(real), body, motion_settings().clear_arms)[0]


def gap(x, y):
    d = 1000 * np.linalg.norm(x - y, axis=1)
    return [round(float(d.mean()), 2), round(float(np.quantile(d, 0.95)), 2), round(float(d.max()), 2)]


rows = []
for name, pose in [*[(f"sample {i}", p) for i, p in enumerate(np.asarray(poses))], *zip(names, real, strict=True)]:
    bv = pose_body(body, torch.from_numpy(np.asarray(pose, np.float32))[None])
    start = embedded_points(bv, body.faces, emb)[0].numpy()
    r, frames, verdict, secs = {}, {}, {}, {}
    for k, c in cfgs.items():
        t0 = time.process_time()
        res = drape_garment(g, start, bv[0].numpy(), body, emb, c.sim)
        secs[k] = round(time.process_time() - t0, 1)
        r[k], frames[k] = res.positions, res.iterations
        verdict[k] = check_garment_result(res, g, c.sim)[1] or "kept"
    row = dict(pose=name, frames=frames, verdict=verdict, cpu_s=secs,
               fps20_to_settled20=gap(r["fps20"], r["settled20"]), fps10_to_settled20=gap(r["fps10"], r["settled20"]),
               settled10_to_settled20=gap(r["settled10"], r["settled20"]),
               fps10_to_settled10=gap(r["fps10"], r["settled10"]),
               fps10_to_fps20=gap(r["fps10"], r["fps20"]))
    rows.append(row)
    print(row, flush=True)
print(json.dumps({"data": data, "settings": settings, "rows": rows}))
