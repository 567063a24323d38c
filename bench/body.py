"""The Anny body's costs against the mannequin's, side by side in one process, on this machine.

    python bench/body.py [poses=2] [repeats=5] [garment=tshirt_coarse]

Rows: Anny's model load from its asset cache (the cache's first build is not redone here: it is logged
once per machine, 82-158 s and 790 MB on 2 cores), the body build (mesh, merged weights, parts, fitted
primitives), posing at batch 1 and 32 (pbc's forward kinematics + linear blend skinning, and Anny's own
forward pass for the same poses), the shrink-wrap of the garment, and the drape seconds per sample of
the same garment and poses on each body (body=mannequin against body=anny_tpose: the procedural shirt is
modelled on a T-pose), and of the shirt sized to Anny (garment.size_to_body: Anny's chest, arm axis and
torso length; more vertices). Then the process's peak memory (RSS). The last line is one JSON object with the
figures and the ratios Anny / mannequin, naming the device.
"""

from __future__ import annotations

import json
import platform
import resource
import sys
import time

import numpy as np
import torch

from pbc.core.config import load_config
from pbc.data.generate import build_scene, drape_pose
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import ANNY_TO_PBC, anny_rest, check_phenotype, joint_table, load_anny_model
from pbc.geometry.body.base import pose_body
from pbc.geometry.body.skeleton import forward_kinematics
from pbc.sim.poses import SamplingSettings, euler_xzy_to_matrix, sample_angles, sample_poses


def timed(fn, repeats: int) -> float:
    """Median seconds of `repeats` calls (one warm-up call first)."""
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def anny_forward(cfg, body, rot):
    """Anny's own forward pass for pbc rotations (B, J, 3, 3), as tests/integration/test_anny.py runs it."""
    model = load_anny_model(str(cfg.rig), str(cfg.topology))
    phen = check_phenotype(cfg.phenotype, cfg.phenotype_ranges)
    rest = anny_rest(model, phen)
    column, _ = joint_table(cfg, list(model.bone_labels), list(model.bone_parents))
    C = ANNY_TO_PBC
    G = forward_kinematics(body.skeleton, rot.double())[..., :3, :3]
    W = rest["rest_bone_poses"].expand(rot.shape[0], -1, -1, -1).clone()
    W[..., :3, :3] = (C.T @ G @ C)[:, column] @ rest["rest_bone_poses"][:, :3, :3]
    with torch.no_grad():
        return model(W, phenotype_kwargs=phen, pose_parameterization="world-orient")["vertices"]


def main(argv: list[str]) -> dict:
    opts = dict(a.split("=", 1) for a in argv)
    n_poses, repeats = int(opts.get("poses", 2)), int(opts.get("repeats", 5))
    garment = opts.get("garment", "tshirt_coarse")
    out: dict = {"device": f"cpu ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads)"}
    rows = []

    t = time.perf_counter()
    acfg = load_config(["body=anny"]).body
    load_anny_model(str(acfg.rig), str(acfg.topology))
    out["anny_cached_load_s"] = time.perf_counter() - t
    rows.append(("Anny model load (cached)", "", f"{out['anny_cached_load_s']:.2f} s"))

    bodies = {}
    for name, key in (("mannequin", "mannequin"), ("anny", "anny")):
        cfg = load_config([f"body={key}"]).body
        t = time.perf_counter()
        bodies[name] = (cfg, body_from_config(cfg))
        out[f"{name}_build_s"] = time.perf_counter() - t
        rows.append((f"body build: {name}", f"{bodies[name][1].vertices.shape[0]:,} vertices",
                     f"{out[f'{name}_build_s']:.2f} s"))

    for B in (1, 32):
        for name, (cfg, body) in bodies.items():
            settings = SamplingSettings(halfnormal_joints=tuple(cfg.sampling.halfnormal_joints))
            rot = euler_xzy_to_matrix(torch.from_numpy(sample_angles(body.skeleton, B, np.random.default_rng(0),
                                                                     settings))).float()
            with torch.no_grad():
                s = timed(lambda body=body, rot=rot: pose_body(body, rot), repeats)
            out[f"{name}_pose_b{B}_ms"] = 1e3 * s
            rows.append((f"pbc posing: {name}", f"batch {B}", f"{1e3 * s:.1f} ms"))
            if name == "anny":
                s = timed(lambda cfg=cfg, body=body, rot=rot: anny_forward(cfg, body, rot), repeats)
                out[f"anny_forward_b{B}_ms"] = 1e3 * s
                rows.append(("Anny's own forward", f"batch {B}", f"{1e3 * s:.1f} ms"))

    # the same garment on both bodies (the ratio), then the garment sized to Anny (garment.size_to_body)
    for name, key, sized in (("mannequin", "mannequin", False), ("anny", "anny_tpose", False),
                             ("anny_sized", "anny_tpose", True)):
        t = time.perf_counter()
        scene, stats = build_scene(load_config([f"body={key}", f"garment={garment}",
                                                f"garment.size_to_body.enabled={str(sized).lower()}"]))
        key = f"{key}, sized shirt" if sized else key
        out[f"{name}_scene_s"] = time.perf_counter() - t
        rows.append((f"body + shrink-wrap: {key}", f"{garment}, max |sdf| {1e3 * stats['max_abs_sdf']:.0f} mm",
                     f"{out[f'{name}_scene_s']:.1f} s"))
        cfg = load_config([f"body={key.split(',')[0]}"]).body
        settings = SamplingSettings(halfnormal_joints=tuple(cfg.sampling.halfnormal_joints),
                                    posed_joints=tuple(cfg.sampling.posed_joints))
        poses, _ = sample_poses(scene.body.skeleton, n_poses, 1, scene.body, settings)  # pruned, as generate
        recs = [drape_pose(scene, p) for p in poses.numpy()]
        out[f"{name}_discarded"] = [r["reason"] for r in recs if not r["ok"]]
        out[f"{name}_drape_s_per_sample"] = float(np.mean([r["t_drape"] for r in recs]))
        out[f"{name}_drape_kept"] = int(sum(r["ok"] for r in recs))
        rows.append((f"drape: {key}", f"{n_poses} poses, {out[f'{name}_drape_kept']} kept",
                     f"{out[f'{name}_drape_s_per_sample']:.1f} s/sample"))

    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rows.append(("peak memory (RSS)", "whole process", f"{out['peak_rss_mb']:.0f} MB"))
    out["ratio_drape_anny_over_mannequin"] = out["anny_drape_s_per_sample"] / out["mannequin_drape_s_per_sample"]
    out["ratio_pose_b32_anny_over_mannequin"] = out["anny_pose_b32_ms"] / out["mannequin_pose_b32_ms"]
    out["ratio_pose_b32_anny_forward_over_pbc"] = out["anny_forward_b32_ms"] / out["anny_pose_b32_ms"]

    w = max(len(r[0]) for r in rows), max(len(r[1]) for r in rows)
    print(f"{'what':<{w[0]}}  {'case':<{w[1]}}  value")
    for a, b, c in rows:
        print(f"{a:<{w[0]}}  {b:<{w[1]}}  {c}")
    print(f"drape Anny / mannequin: {out['ratio_drape_anny_over_mannequin']:.2f}x (goal <= 1.5x)")
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}))
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
