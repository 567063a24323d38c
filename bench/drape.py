"""Cost and quality of one Style3D drape from the skinned start, coarse and full T-shirt, on this machine.

    python bench/drape.py [poses=2]

For each garment (conf/garment/tshirt_coarse.yaml, tshirt.yaml) on the mannequin: shrink-wrap once, then
for the rest pose and a few fixed poses skin the garment onto the posed body and drape it. Prints a table
(vertices, frames, wall and CPU seconds, residual, max penetration in mm against the whole posed body
mesh and against each vertex's own part (what D.6 asks the solver to enforce), triangle area ratio
min/max against the pattern, D.6 verdict) and, as the last line,
one JSON object of the figures. CPU seconds are the per-core cost (the wall clock includes waiting for a
shared core); the first drape of the process is a warm-up that loads (or compiles) warp's kernels.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import torch

from pbc.config import load_config
from pbc.geometry.body import build_body, pose_body
from pbc.geometry.garment import make_tshirt
from pbc.geometry.shrinkwrap import embedded_points, shrinkwrap
from pbc.sim.drape import (
    _part_meshes,
    check_garment_result,
    closest_points,
    drape_garment,
    pattern_triangles,
    rest_triangle_areas,
    triangle_area_ratios,
)
from pbc.sim.poses import euler_xzy_to_matrix

# fixed, plausible poses (Euler degrees per axis (x, y, z), see pbc.sim.poses): rest; arms down 45 and
# a forward bend; left arm raised and swung forward, right arm down, torso twisted and leaning
POSES = {
    "rest": {},
    "arms_down_bend": {"l_arm": (0, 0, -45), "r_arm": (0, 0, -45), "spine": (15, 0, 0)},
    "arm_up_twist": {"l_arm": (20, 0, 40), "r_arm": (0, 0, -30), "spine1": (0, 10, 0), "lower_back": (0, 10, 8)},
}


def pose_rotations(skel, spec: dict) -> torch.Tensor:
    angles = torch.zeros(len(skel.names), 3)
    for name, xyz in spec.items():
        angles[skel.names.index(name)] = torch.tensor(xyz, dtype=torch.float32)
    return euler_xzy_to_matrix(angles)[None]  # (1, J, 3, 3)


def main(argv: list[str]) -> dict:
    n_poses = int(next((a.split("=", 1)[1] for a in argv if a.startswith("poses=")), len(POSES)))
    cfg = load_config([])
    body = build_body(cfg.body)
    rows = []
    for gname in ("tshirt_coarse", "tshirt"):
        gcfg = load_config([f"garment={gname}"]).garment
        garment, cage = make_tshirt(gcfg)
        emb, _ = shrinkwrap(garment, cage, body, gcfg.shrinkwrap)
        faces = garment.faces.numpy()
        rest = rest_triangle_areas(pattern_triangles(garment.uv.numpy(), garment.face_uv.numpy(), garment.uv_scale))
        warm = True
        for pname in list(POSES)[:n_poses]:
            bv = pose_body(body, pose_rotations(body.skeleton, POSES[pname]))
            start = embedded_points(bv, body.faces, emb)[0].numpy()
            if warm:  # load/compile kernels outside the measurement
                t0 = time.perf_counter()
                drape_garment(garment, start, bv[0].numpy(), body, emb, cfg.sim)
                print(f"# warm-up drape ({gname}): {time.perf_counter() - t0:.1f} s", flush=True)
                warm = False
            res = drape_garment(garment, start, bv[0].numpy(), body, emb, cfg.sim)
            sd, _ = closest_points(res.positions, bv[0].numpy(), body.faces.numpy())
            # what the solver enforces (D.6): clearance of each vertex from its own (capped) part mesh
            own = np.full(len(sd), np.inf)
            for k, (pv, pf) in enumerate(_part_meshes(bv[0].numpy(), body.faces.numpy(), body.parts.numpy())):
                sel = emb.part.numpy() == k
                if sel.any():
                    own[sel] = closest_points(res.positions[sel], pv, pf)[0]
            ratio = triangle_area_ratios(res.positions, faces, rest)
            ratio0 = triangle_area_ratios(start, faces, rest)
            ok, reason = check_garment_result(res, garment, cfg.sim)
            rows.append(
                {
                    "garment": gname,
                    "pose": pname,
                    "vertices": int(garment.vertices.shape[0]),
                    "frames": int(res.iterations),
                    "seconds": round(res.seconds, 2),
                    "cpu_seconds": round(res.cpu_seconds, 2),
                    "residual": round(float(res.residual), 5),
                    "converged": bool(res.converged),
                    "max_penetration_mm": round(1000 * max(0.0, -float(sd.min())), 2),
                    "min_clearance_mm": round(1000 * float(sd.min()), 2),
                    "own_part_penetration_mm": round(1000 * max(0.0, -float(own.min())), 2),
                    "own_part_min_clearance_mm": round(1000 * float(own.min()), 2),
                    "area_ratio_min": round(float(ratio.min()), 3),
                    "area_ratio_max": round(float(ratio.max()), 3),
                    "start_area_ratio_min": round(float(ratio0.min()), 3),
                    "start_area_ratio_max": round(float(ratio0.max()), 3),
                    "mean_move_mm": round(1000 * float(np.linalg.norm(res.positions - start, axis=1).mean()), 1),
                    "ok": ok,
                    "reason": reason,
                }
            )
            r = rows[-1]
            print(
                f"{gname:14s} {pname:15s} V={r['vertices']:5d} frames={r['frames']:4d} wall={r['seconds']:6.2f}s "
                f"cpu={r['cpu_seconds']:6.2f}s res={r['residual']:.4f} conv={r['converged']} "
                f"pen={r['max_penetration_mm']:.2f}mm own-part pen={r['own_part_penetration_mm']:.2f}mm "
                f"own clear={r['own_part_min_clearance_mm']:.2f}mm "
                f"area=[{r['area_ratio_min']:.3f}, {r['area_ratio_max']:.3f}] "
                f"(start [{r['start_area_ratio_min']:.3f}, {r['start_area_ratio_max']:.3f}]) "
                f"move={r['mean_move_mm']}mm {'ok' if ok else reason}",
                flush=True,
            )
    summary = {}
    for gname in ("tshirt_coarse", "tshirt"):
        rs = [r for r in rows if r["garment"] == gname]
        summary[gname] = {
            "vertices": rs[0]["vertices"],
            "mean_seconds": round(float(np.mean([r["seconds"] for r in rs])), 2),
            "mean_cpu_seconds": round(float(np.mean([r["cpu_seconds"] for r in rs])), 2),
            "max_residual": max(r["residual"] for r in rs),
            "all_converged": all(r["converged"] for r in rs),
            "max_penetration_mm": max(r["max_penetration_mm"] for r in rs),
            "own_part_max_penetration_mm": max(r["own_part_penetration_mm"] for r in rs),
            "own_part_min_clearance_mm": min(r["own_part_min_clearance_mm"] for r in rs),
            "area_ratio_min": min(r["area_ratio_min"] for r in rs),
            "area_ratio_max": max(r["area_ratio_max"] for r in rs),
        }
    figures = {"sim": {k: cfg.sim[k] for k in ("fps", "substeps", "iterations", "linear_iterations", "tolerance")},
               "summary": summary, "rows": rows}
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main(sys.argv[1:])
