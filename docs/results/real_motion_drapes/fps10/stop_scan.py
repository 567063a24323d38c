"""Stop settings against the settled cloth: frames, CPU seconds, D.6 verdict and the distance (mm) of each
setting's drape from the same pose's drape run on to 0.5 mm/s (fps 20, up to 600 frames).

    python docs/results/real_motion_drapes/fps10/stop_scan.py 0,1,4 "sim.fps=10,sim.velocity_damping=0.05" ...

Poses: the given indices of tshirt_small's D.3 draws (seed 0); each extra argument is one setting (comma-separated
overrides), beside the config (fps20) and sim.fps=10. Output: stop_scan.txt.
"""

import sys
import time

import numpy as np
import torch

from pbc.core.config import load_config
from pbc.data.generate import build_scene
from pbc.geometry.body.base import pose_body
from pbc.geometry.shrinkwrap import embedded_points
from pbc.sim.drape import check_garment_result, drape_garment
from pbc.sim.poses import sample_poses, sampling_settings_from_config

base = ["data=tshirt_small"]
sets = {"fps20": [], "fps10": ["sim.fps=10"]}
for arg in sys.argv[2:]:
    sets[arg] = arg.split(",")
ref = load_config(base + ["sim.tolerance=0.0005", "sim.fold_frames=0"])
cfgs = {k: load_config(base + v) for k, v in sets.items()}
scene, _ = build_scene(ref)
body, g, emb = scene.body, scene.garment, scene.embedding
idx = [int(i) for i in sys.argv[1].split(",")]
poses, _ = sample_poses(
    body.skeleton, max(idx) + 1, int(ref.data.seed), body, sampling_settings_from_config(ref.body.sampling)
)
for i in idx:
    bv = pose_body(body, torch.from_numpy(np.asarray(poses[i], np.float32))[None])
    start = embedded_points(bv, body.faces, emb)[0].numpy()
    rr = drape_garment(g, start, bv[0].numpy(), body, emb, ref.sim)
    for k, c in cfgs.items():
        t = time.process_time()
        r = drape_garment(g, start, bv[0].numpy(), body, emb, c.sim)
        t = time.process_time() - t
        d = 1000 * np.linalg.norm(r.positions - rr.positions, axis=1)
        print(
            f"pose {i} {k:40s} frames {r.iterations:4d} cpu {t:5.1f} {check_garment_result(r, g, c.sim)[1] or 'kept':16s} to settled mean {d.mean():5.1f} p95 {np.quantile(d, 0.95):5.1f}",
            flush=True,
        )
