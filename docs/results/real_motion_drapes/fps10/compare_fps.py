"""The drape at sim.fps 20 (the config) against sim.fps 10, on the same poses: frames, D.6 verdicts, and how far
apart the two drapes' vertices end (mm: mean, 95th percentile, max).

    python docs/results/real_motion_drapes/fps10/compare_fps.py [tshirt_small] > OUT

The data config's first 8 sampled poses and 4 CMU frames (arms fitted); the last line is one JSON object.
"""

import json
import sys
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
a, b = load_config([f"data={data}"]), load_config([f"data={data}", "sim.fps=10"])
scene, _ = build_scene(a)
body, g, emb = scene.body, scene.garment, scene.embedding
poses, _ = sample_poses(body.skeleton, 8, int(a.data.seed), body, sampling_settings_from_config(a.body.sampling))
real, names = real_motion_poses(body.skeleton, 4)
real = clear_clip_arms(np.asarray(real), body, motion_settings().clear_arms)[0]
rows = []
for name, pose in [*[(f"sample {i}", p) for i, p in enumerate(np.asarray(poses))], *zip(names, real, strict=True)]:
    bv = pose_body(body, torch.from_numpy(np.asarray(pose, np.float32))[None])
    start = embedded_points(bv, body.faces, emb)[0].numpy()
    r = [drape_garment(g, start, bv[0].numpy(), body, emb, c.sim) for c in (a, b)]
    v = [check_garment_result(x, g, c.sim)[1] or "kept" for x, c in zip(r, (a, b), strict=True)]
    d = 1000 * np.linalg.norm(r[0].positions - r[1].positions, axis=1)
    rows.append(dict(pose=name, frames=[x.iterations for x in r], verdict=v, mean_mm=round(float(d.mean()), 2),
                     p95_mm=round(float(np.quantile(d, 0.95)), 2), max_mm=round(float(d.max()), 2)))
    print(rows[-1], flush=True)
print(json.dumps({"data": data, "rows": rows}))
