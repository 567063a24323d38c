"""Cost and quality of one Style3D drape from the skinned start, coarse and full T-shirt, on this machine.

    python bench/drape.py [poses=2]

For each garment (conf/garment/tshirt_coarse.yaml, tshirt.yaml) on the mannequin: shrink-wrap once, then
for the rest pose and a few fixed poses skin the garment onto the posed body and drape it. Prints a table
(vertices, frames, wall and CPU seconds, residual, max penetration in mm against the whole posed body
mesh and against each vertex's own part (what D.6 asks the solver to enforce), triangle area ratio
min/max against the pattern, D.6 verdict) and, as the last line,
one JSON object of the figures. CPU seconds are the per-core cost (the wall clock includes waiting for a
shared core); the first drape of the process is a warm-up that loads (or compiles) warp's kernels.

    python bench/drape.py batch=1,8,32 [garment=tshirt_coarse] [poses=N] [single=4] [overrides...]

Single-world against batched (pbc/sim/batched.py) side by side in one run, on warp's default device
(cuda:0 when present): `single` poses draped one at a time, then for each K one model of K worlds
(built once, the build timed apart) draping `poses` poses (default 2K: a world that stops takes the
next pose). Per row: samples/s (steady state, build excluded), CPU seconds per sample (the per-core
cost) and per drape-frame, build seconds, mean frames, the largest per-drape residual, kept samples,
and the mean/max distance in mm of the batched drapes from the single drapes of the same poses.
Extra `key=value` arguments are config overrides
(e.g. sim.max_frames=100).

    python bench/drape.py compare [poses=6] [real=6] [batch=8] [worlds=K] [data=tshirt_small] [old=KEY=VALUE,...]
                                  [overrides...]

Kept drapes per CPU-hour, the settings before the real-motion fixes (`OLD_SIM`: Style3D's untangling force
on, newton's value; the shear stiffness at 10; 20 frames a second; no fold rule; a model built for every
drape; a clip's frames as retargeted) against the config's (with `sim.reuse_model`, one model per setting
reused for the poses in turn, as a generation worker drapes, its build's CPU counted in the first drape; and a
clip's arms fitted to the body, pbc.motion.fit), side by side in one run on the same poses: the data config's
first `poses` sampled poses and `real` frames of the CMU clips in tests/data/bvh (arms hanging, walking),
each pose draped old then new so both share the machine's load alike, then (batch=K > 1) each pose set
again with the new settings in one batched model of K worlds, or `worlds` (1: one model reused for the poses
in turn) (pbc/sim/batched.py, what `sim.batch_size=K sim.batch_worlds=W` generates with; its one-off build
reported apart). `old=KEY=VALUE,...` puts those settings in place of
`OLD_SIM` (a change's own before and after; both then take a clip's frames with the arms fitted).
Any other KEY=VALUE is a config override of both (an imported garment: `garment=obj garment.obj=PATH
garment.uv_unit=m 'garment.charts={front:0,back:1}'`). Per setting and pose set: keep rate, discard reasons,
mean frames, CPU seconds a drape and kept drapes per CPU-hour; the ratios to old.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from pbc.core.config import load_config
from pbc.geometry.body.base import pose_body
from pbc.geometry.body.mannequin import build_mannequin
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.shrinkwrap import embedded_points, shrinkwrap
from pbc.sim.drape import (
    check_garment_result,
    closest_points,
    drape_garment,
    part_meshes,
    pattern_triangles,
    rest_triangle_areas,
    triangle_area_ratios,
)
from pbc.sim.poses import euler_xzy_to_matrix

ROOT = Path(__file__).resolve().parents[1]

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
    body = build_mannequin(cfg.body)
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
            for k, (pv, pf) in enumerate(part_meshes(bv[0].numpy(), body.faces.numpy(), body.parts.numpy())):
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


def device_name(cache_dir=None) -> str:
    """What the drape runs on, in words: the GPU's name, or the CPU's model and core count."""
    import os
    import platform

    from pbc.sim.drape import init_warp

    wp = init_warp(cache_dir)  # the config's kernel cache: a bare init would compile every kernel afresh
    dev = wp.get_device()
    if dev.is_cuda:
        return f"{dev.alias} ({dev.name})"
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"cpu ({model}, {os.cpu_count()} cores visible)"


def bench_args(argv: list[str], own: tuple[str, ...]) -> tuple[dict[str, str], list[str]]:
    """Split KEY=VALUE arguments into the bench's own (keys in `own`) and config overrides (every other one:
    sim.fps=10, garment=obj, garment.obj=PATH)."""
    mine = tuple(f"{k}=" for k in own)
    return (dict(a.split("=", 1) for a in argv if a.startswith(mine)),
            [a for a in argv if "=" in a and not a.startswith(mine)])


def batched_main(argv: list[str]) -> dict:
    """Single-world vs batched drape, side by side (see the module docstring)."""
    from pbc.data.generate import build_scene
    from pbc.sim.batched import batched_drape_for_garment
    from pbc.sim.poses import sample_poses, sampling_settings_from_config

    args, overrides = bench_args(argv, ("batch", "single", "poses", "garment"))
    ks = [int(k) for k in args["batch"].split(",")]
    n_single = int(args.get("single", 4))
    n_poses = args.get("poses")
    cfg = load_config([f"garment={args.get('garment', 'tshirt_coarse')}", *overrides])
    scene, _ = build_scene(cfg)
    n_all = max(n_single, 2 * max(ks) if n_poses is None else int(n_poses))
    settings = sampling_settings_from_config(cfg.body.sampling)
    poses, _ = sample_poses(scene.body.skeleton, n_all, int(cfg.data.seed), scene.body, settings)
    starts, bodies = [], []
    for pose in poses:
        bv = pose_body(scene.body, pose[None].float())
        starts.append(embedded_points(bv, scene.body.faces, scene.embedding)[0].numpy())
        bodies.append(bv[0].numpy())
    starts, bodies = np.stack(starts), np.stack(bodies)
    garment, body, emb, sim = scene.garment, scene.body, scene.embedding, cfg.sim
    device = device_name(sim.kernel_cache_dir)
    print(f"# device: {device}; garment {garment.vertices.shape[0]} vertices; {n_all} sampled poses", flush=True)

    t0 = time.perf_counter()  # warm-up: load (or compile) the kernels of both paths outside the timings
    drape_garment(garment, starts[0], bodies[0], body, emb, sim)
    batched_drape_for_garment(garment, body, emb, sim, 1, starts[0], bodies[0]).run(starts[:1], bodies[:1])
    print(f"# warm-up: {time.perf_counter() - t0:.1f} s", flush=True)

    def row(mode, k, results, wall, cpu, build, ref=None):
        n = len(results)
        kept = sum(check_garment_result(r, garment, sim)[0] for r in results)
        out = {"mode": mode, "K": k, "poses": n, "build_s": round(build, 2), "wall_s": round(wall, 2),
               "samples_per_s": round(n / wall, 3), "cpu_s_per_sample": round(cpu / n, 3),
               "frames_max": max(r.iterations for r in results),
               "frames_mean": round(float(np.mean([r.iterations for r in results])), 1),
               # the kernels' efficiency apart from how long the poses take to settle
               "cpu_ms_per_drape_frame": round(1000 * cpu / sum(r.iterations for r in results), 3),
               "residual_max": round(max(float(r.residual) for r in results), 5),
               "converged": sum(r.converged for r in results), "kept": int(kept)}
        if ref is not None:
            m = min(len(ref), n)
            d = 1000 * np.linalg.norm(np.stack([r.positions for r in results[:m]]).astype(np.float64)
                                      - np.stack([r.positions for r in ref[:m]]), axis=-1)
            out.update(vs_single_poses=m, vs_single_mean_mm=round(float(d.mean()), 4),
                       vs_single_max_mm=round(float(d.max()), 4),
                       same_decisions=all(check_garment_result(a, garment, sim) == check_garment_result(b, garment, sim)
                                          for a, b in zip(results[:m], ref[:m], strict=True)))
        return out

    rows = []
    t0, c0 = time.perf_counter(), time.process_time()
    single = [drape_garment(garment, starts[i], bodies[i], body, emb, sim) for i in range(n_single)]
    rows.append(row("single", 1, single, time.perf_counter() - t0, time.process_time() - c0, 0.0))
    for k in ks:
        n = 2 * k if n_poses is None else int(n_poses)
        t0 = time.perf_counter()
        bd = batched_drape_for_garment(garment, body, emb, sim, k, starts[0], bodies[0])
        build = time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        res = bd.run(starts[:n], bodies[:n])
        rows.append(row("batched", bd.n_worlds, res, time.perf_counter() - t0, time.process_time() - c0, build, single))
        rows[-1]["mb_per_world"] = round(bd.bytes_per_world / 2**20, 2)
        del bd

    base = rows[0]
    print(f"{'mode':8s} {'K':>4s} {'poses':>5s} {'build s':>8s} {'samples/s':>10s} {'cpu s/sample':>13s} "
          f"{'vs single':>10s} {'cpu ms/frame':>12s} {'frames':>6s} {'residual':>9s} {'kept':>5s} "
          f"{'mean mm':>8s} {'max mm':>8s}")
    for r in rows:
        r["speedup_samples_per_s"] = round(r["samples_per_s"] / base["samples_per_s"], 2)
        r["cpu_per_sample_vs_single"] = round(r["cpu_s_per_sample"] / base["cpu_s_per_sample"], 3)
        print(f"{r['mode']:8s} {r['K']:4d} {r['poses']:5d} {r['build_s']:8.2f} {r['samples_per_s']:10.3f} "
              f"{r['cpu_s_per_sample']:13.3f} {r['cpu_per_sample_vs_single']:9.2f}x "
              f"{r['cpu_ms_per_drape_frame']:12.2f} {r['frames_mean']:6.1f} "
              f"{r['residual_max']:9.5f} {r['kept']:3d}/{r['poses']:<3d} {r.get('vs_single_mean_mm', 0.0):8.4f} "
              f"{r.get('vs_single_max_mm', 0.0):8.4f}", flush=True)
    figures = {"device": device, "garment": cfg.garment.name, "vertices": int(garment.vertices.shape[0]),
               "sim": {k: cfg.sim[k] for k in ("fps", "substeps", "iterations", "linear_iterations", "tolerance",
                                               "max_frames", "batch_check_every")},
               "cpu_per_sample_vs_single": {f"K={r['K']}": r["cpu_per_sample_vs_single"] for r in rows[1:]},
               "rows": rows}
    print(json.dumps(figures))
    return figures


# the drape before the real-motion fixes (docs/results/real_motion_drapes): untangling on, the soft shear, 20
# frames a second, judged where the speed rule first holds
OLD_SIM = ["sim.self_collision_stiffness.untangle=1.0", "sim.stretch_ke=[100.0,100.0,10.0]", "sim.fps=20",
           "sim.fold_frames=0", "sim.reuse_model=false"]
REAL_CLIPS = ("tests/data/bvh/cmu_mb_02_01_walk.bvh", "tests/data/bvh/cmu_mb_01_01_lfingers.bvh")


def real_motion_poses(skeleton, n: int) -> tuple[np.ndarray, list[str]]:
    """Up to n frames (n, J, 3, 3) of the CMU excerpts, spread evenly over their frames (frame 0 of a
    release file is the converter's calibration pose, not motion), with their names."""
    from pbc.motion.bvh import read_bvh
    from pbc.motion.retarget import bvh_to_poses, choose_joint_map, parse_frames

    poses, names = [], []
    for path in REAL_CLIPS:
        bvh = read_bvh(ROOT / path)
        motion = bvh_to_poses(bvh, skeleton, choose_joint_map(bvh, "auto"), parse_frames("1:"))
        poses += list(np.asarray(motion.poses))
        names += [f"{Path(path).stem}[{k + 1}]" for k in range(len(motion.poses))]
    pick = np.unique(np.linspace(0, len(poses) - 1, min(n, len(poses))).round().astype(int))
    return np.stack([poses[i] for i in pick]), [names[i] for i in pick]


def compare_main(argv: list[str]) -> dict:
    """Old against new drape settings on sampled and real-motion poses (see the module docstring)."""
    from pbc.data.generate import build_scene, reuses_model
    from pbc.motion.fit import clear_clip_arms
    from pbc.motion.retarget import motion_settings
    from pbc.sim.batched import batched_drape_for_garment
    from pbc.sim.poses import sample_poses, sampling_settings_from_config

    args, overrides = bench_args(argv, ("poses", "real", "batch", "worlds", "data", "old"))
    base = [f"data={args.get('data', 'tshirt_small')}", *overrides]
    # old=KEY=VALUE,...: the settings a change replaced, against the config's, both on clips with fitted arms
    old_sim = args["old"].split(",") if "old" in args else OLD_SIM
    cfg_new, cfg_old = load_config(base), load_config([*base, *old_sim])
    scene, _ = build_scene(cfg_new)
    garment, body, emb = scene.garment, scene.body, scene.embedding
    n_sampled, n_real = int(args.get("poses", 6)), int(args.get("real", 6))
    sampled, _ = sample_poses(body.skeleton, n_sampled, int(cfg_new.data.seed), body,
                              sampling_settings_from_config(cfg_new.body.sampling))
    sets = [("sampled", np.asarray(sampled)[:n_sampled], [f"sample {i}" for i in range(n_sampled)])]
    if n_real > 0:
        sets.append(("real", *real_motion_poses(body.skeleton, n_real)))
    device = device_name(cfg_new.sim.kernel_cache_dir)
    print(f"# device: {device}; {cfg_new.data.name}: garment {garment.vertices.shape[0]} vertices; "
          f"old = {' '.join(old_sim)}", flush=True)
    bv = pose_body(body, torch.from_numpy(np.asarray(sets[0][1][:1])).float())
    t0 = time.perf_counter()  # warm-up: load (or compile) the kernels outside the timings
    start = embedded_points(bv, body.faces, emb).numpy()
    drape_garment(garment, start[0], bv[0].numpy(), body, emb, cfg_new.sim)
    if reuses_model(cfg_new.sim):  # and the batched model's own
        batched_drape_for_garment(garment, body, emb, cfg_new.sim, 1, start[0], bv[0].numpy()).run(start, bv.numpy())
    print(f"# warm-up: {time.perf_counter() - t0:.1f} s", flush=True)

    # the new pipeline takes a clip's frames with their arms fitted to the body (pbc.motion.fit), the old one as
    # retargeted; a sampled pose is the same for both
    fitted_sets = {name: (clear_clip_arms(np.asarray(poses), body, motion_settings().clear_arms)[0]
                          if name == "real" else np.asarray(poses)) for name, poses, _ in sets}
    models = {}  # setting -> its reused model (sim.reuse_model), built by its first drape

    def drape(setting, sim, start, body_v):
        """One drape as generation makes it with `sim`: in the setting's reused model, or a model of its own."""
        if not reuses_model(sim):
            return drape_garment(garment, start, body_v, body, emb, sim)
        c0, t0 = time.process_time(), time.perf_counter()
        if setting not in models:
            models[setting] = batched_drape_for_garment(garment, body, emb, sim, 1, start, body_v)
        res = models[setting].run(start[None], body_v[None])[0]
        res.cpu_seconds, res.seconds = time.process_time() - c0, time.perf_counter() - t0
        return res

    rows = []
    for set_name, poses, names in sets:
        for pose, fitted, name in zip(poses, fitted_sets[set_name], names, strict=True):
            for setting, cfg in (("old", cfg_old), ("new", cfg_new)):
                use = np.asarray(pose) if setting == "old" and "old" not in args else fitted
                bv = pose_body(body, torch.from_numpy(np.asarray(use, np.float32))[None])
                start = embedded_points(bv, body.faces, emb)[0].numpy()
                res = drape(setting, cfg.sim, start, bv[0].numpy())
                ok, reason = check_garment_result(res, garment, cfg.sim)
                rows.append({"set": set_name, "pose": name, "setting": setting, "frames": int(res.iterations),
                             "cpu_s": round(res.cpu_seconds, 2), "wall_s": round(res.seconds, 2), "ok": ok,
                             "reason": reason or "kept", "residual": round(float(res.residual), 5)})
                r = rows[-1]
                print(f"{set_name:8s} {name:32s} {setting:4s} frames={r['frames']:4d} cpu={r['cpu_s']:6.2f}s "
                      f"wall={r['wall_s']:6.2f}s {r['reason']}", flush=True)

    batch = int(args.get("batch", 8))
    # worlds=1: one world reused for the set's poses in turn (a worker's model built once, not per drape)
    worlds = int(args.get("worlds", batch))
    settings = ["old", "new"]
    if batch > 1:  # the new settings through the batched model: one model of `worlds` worlds for each pose set
        setting = f"new_k{worlds}"
        settings.append(setting)
        for set_name, set_poses, names in sets:
            bvs = pose_body(body, torch.from_numpy(np.asarray(fitted_sets[set_name])).float())
            starts = embedded_points(bvs, body.faces, emb).numpy()
            c0, t0 = time.process_time(), time.perf_counter()
            bd = batched_drape_for_garment(garment, body, emb, cfg_new.sim, min(worlds, len(set_poses)), starts[0],
                                           bvs[0].numpy())
            build_cpu = time.process_time() - c0
            results = bd.run(starts, bvs.numpy())
            print(f"# {set_name}: {setting} built in {time.perf_counter() - t0:.1f} s ({build_cpu:.1f} CPU s, "
                  "not counted: a generation worker builds it once)", flush=True)
            for res, name in zip(results, names, strict=True):
                ok, reason = check_garment_result(res, garment, cfg_new.sim)
                rows.append({"set": set_name, "pose": name, "setting": setting, "frames": int(res.iterations),
                             "cpu_s": round(res.cpu_seconds, 2), "wall_s": round(res.seconds, 2), "ok": ok,
                             "reason": reason or "kept", "residual": round(float(res.residual), 5)})

    summary = {}
    print(f"\n{'poses':8s} {'setting':8s} {'n':>3s} {'kept':>5s} {'keep rate':>9s} {'mean frames':>11s} "
          f"{'cpu s/drape':>11s} {'kept/cpu-h':>10s}  discards")
    for set_name in ("sampled", "real", "all"):
        for setting in settings:
            rs = [r for r in rows if r["setting"] == setting and set_name in ("all", r["set"])]
            if not rs:
                continue
            cpu = sum(r["cpu_s"] for r in rs)
            kept = sum(r["ok"] for r in rs)
            reasons = {k: sum(r["reason"] == k for r in rs) for k in sorted({r["reason"] for r in rs}) if k != "kept"}
            s = {"n": len(rs), "kept": kept, "keep_rate": round(kept / len(rs), 3),
                 "mean_frames": round(float(np.mean([r["frames"] for r in rs])), 1),
                 "cpu_s_per_drape": round(cpu / len(rs), 2), "kept_per_cpu_hour": round(3600 * kept / cpu, 1),
                 "discards": reasons}
            summary.setdefault(set_name, {})[setting] = s
            print(f"{set_name:8s} {setting:8s} {s['n']:3d} {kept:5d} {s['keep_rate']:9.2f} {s['mean_frames']:11.1f} "
                  f"{s['cpu_s_per_drape']:11.2f} {s['kept_per_cpu_hour']:10.1f}  {reasons}")
        if set_name not in summary:  # real=0
            continue
        old = summary[set_name]["old"]
        for setting in settings[1:]:
            new = summary[set_name][setting]
            summary[set_name][f"cpu_per_drape_{setting}_over_old"] = round(new["cpu_s_per_drape"]
                                                                           / old["cpu_s_per_drape"], 3)
            summary[set_name][f"kept_per_cpu_hour_{setting}_over_old"] = (
                round(new["kept_per_cpu_hour"] / old["kept_per_cpu_hour"], 2) if old["kept_per_cpu_hour"] else None)
    figures = {"device": device, "data": str(cfg_new.data.name), "vertices": int(garment.vertices.shape[0]),
               "old": old_sim, "overrides": overrides, "summary": summary, "rows": rows}
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    if sys.argv[1:2] == ["compare"]:
        compare_main(sys.argv[2:])
    elif any(a.startswith("batch=") for a in sys.argv[1:]):
        batched_main(sys.argv[1:])
    else:
        main(sys.argv[1:])
