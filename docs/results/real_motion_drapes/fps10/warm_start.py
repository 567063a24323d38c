"""Warm start: the drape started from the rest pose's settled drape (its offsets in the body's local frames, carried
onto the posed body) against the skin-tight start: frames, and how far each lies from the cold start's settled
drape; then the warm start run on to settle too (how far apart two starts' equilibria lie).

    python docs/results/real_motion_drapes/fps10/warm_start.py 0,1 [overrides,...] > warm_start.txt
"""

import sys
import time

import numpy as np
import torch

from pbc.core.config import load_config
from pbc.data.generate import build_scene
from pbc.geometry.body.base import pose_body
from pbc.geometry.shrinkwrap import start_points
from pbc.pixels.frames import embedded_anchors, from_offsets, tangent_frames, to_offsets
from pbc.sim.drape import check_garment_result, drape_garment
from pbc.sim.poses import sample_poses, sampling_settings_from_config

extra = sys.argv[2].split(",") if len(sys.argv) > 2 else []
base = ["data=tshirt_small"]
ref = load_config(base + ["sim.tolerance=0.0005", "sim.fold_frames=0"])
cfg = load_config(base + extra)
scene, _ = build_scene(ref)
body, g, emb = scene.body, scene.garment, scene.embedding
idx = [int(i) for i in sys.argv[1].split(",")]
poses, _ = sample_poses(
    body.skeleton, max(idx) + 1, int(ref.data.seed), body, sampling_settings_from_config(ref.body.sampling)
)


def setup(pose):
    bv = pose_body(body, torch.from_numpy(np.asarray(pose, np.float32))[None])
    st = start_points(bv, body.faces, emb, float(ref.sim.thickness))
    return bv, st, embedded_anchors(bv, body.faces, emb), tangent_frames(bv, body.faces, g, emb)


rest = np.broadcast_to(np.eye(3, dtype=np.float32), np.asarray(poses[0]).shape)
bv, st, an, fr = setup(rest)
t = time.process_time()
r0 = drape_garment(g, st[0], bv[0].numpy(), body, emb, ref.sim)
print("rest settled frames", r0.iterations, "cpu", time.process_time() - t, check_garment_result(r0, g, ref.sim))
off = to_offsets(torch.from_numpy(r0.positions)[None].float(), an, fr)
for i in idx:
    bv, st, an, fr = setup(poses[i])
    rr = drape_garment(g, st[0], bv[0].numpy(), body, emb, ref.sim)
    warm = from_offsets(off, an, fr)[0].numpy()
    for name, start in (("cold", st[0].numpy()), ("warm", warm)):
        t = time.process_time()
        r = drape_garment(g, start, bv[0].numpy(), body, emb, cfg.sim)
        t = time.process_time() - t
        d = 1000 * np.linalg.norm(r.positions - rr.positions, axis=1)
        print(
            f"pose {i} {name} {extra} frames {r.iterations:4d} cpu {t:5.1f} {check_garment_result(r, g, cfg.sim)[1] or 'kept':16s} to settled(cold) mean {d.mean():5.1f} p95 {np.quantile(d, 0.95):5.1f}",
            flush=True,
        )
    # warm settled too
    rw = drape_garment(g, warm, bv[0].numpy(), body, emb, ref.sim)
    d = 1000 * np.linalg.norm(rw.positions - rr.positions, axis=1)
    print(
        f"pose {i} settled warm vs settled cold mean {d.mean():5.1f} p95 {np.quantile(d, 0.95):5.1f} frames {rw.iterations}",
        flush=True,
    )
