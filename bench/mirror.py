"""How good a mirrored sample (data.mirror) is: each of a data set's first poses and its mirror image are both
draped, and the mirror of the first drape is compared with the drape of the mirrored pose.

    python bench/mirror.py [data=tshirt_small] [poses=3]

Rows, one per pose: whether each drape passed the distortion check (D.6), the mean and largest distance
(mm) of the mirrored drape from the drape of the mirrored pose (what a mirrored training sample gets wrong),
and, for scale, the mean distance between the two drapes unmirrored (how much the cloth changes between
the pose and its mirror). The last line is one JSON object with the figures, naming the device.
"""

from __future__ import annotations

import json
import platform
import sys
import time

import numpy as np

from pbc.core.config import load_config
from pbc.data.generate import build_scene, dataset_poses, drape_pose, scene_mirror_map
from pbc.data.mirror import mirror_poses, mirror_verts


def main(argv: list[str]) -> dict:
    args = dict(a.split("=", 1) for a in argv)
    data, n = args.get("data", "tshirt_small"), int(args.get("poses", 3))
    cfg = load_config([f"data={data}", "data.mirror=true", f"data.num_samples={n}"])
    scene, _ = build_scene(cfg)
    poses, *_ = dataset_poses(cfg, scene)
    mm = scene_mirror_map(cfg, scene, poses)
    rows = []
    print(f"data={data}: garment {len(scene.garment.vertices)} vertices; mirror map: surface gap max "
          f"{mm.stats['garment_gap_max_m'] * 1000:.1f} mm, body gap max {mm.stats['body_gap_max_m'] * 1000:.1f} mm")
    print(f"{'pose':>4} {'kept (pose, mirror)':>20} {'mirror err mean mm':>19} {'max mm':>7} "
          f"{'unmirrored mm':>14} {'s':>6}")
    for i, pose in enumerate(poses):
        t0 = time.perf_counter()
        a = drape_pose(scene, pose, i)
        b = drape_pose(scene, mirror_poses(pose[None], mm)[0], i)
        err = 1000 * np.linalg.norm(mirror_verts(a["positions"][None], mm)[0] - b["positions"], axis=1)
        apart = 1000 * np.linalg.norm(a["positions"] - b["positions"], axis=1)
        row = {"pose": i, "kept": [bool(a["ok"]), bool(b["ok"])], "mirror_error_mean_mm": float(err.mean()),
               "mirror_error_max_mm": float(err.max()), "unmirrored_mean_mm": float(apart.mean()),
               "seconds": time.perf_counter() - t0}
        rows.append(row)
        print(f"{i:>4} {str(row['kept']):>20} {row['mirror_error_mean_mm']:>19.2f} {row['mirror_error_max_mm']:>7.1f} "
              f"{row['unmirrored_mean_mm']:>14.1f} {row['seconds']:>6.1f}", flush=True)
    summary = {"bench": "mirror", "data": data, "device": f"cpu ({platform.processor() or platform.machine()})",
               "poses": n, "mirror_error_mean_mm": float(np.mean([r["mirror_error_mean_mm"] for r in rows])),
               "keep_disagreements": sum(r["kept"][0] != r["kept"][1] for r in rows), "rows": rows,
               "mirror_map": mm.stats}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main(sys.argv[1:])
