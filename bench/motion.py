"""Benchmark motion in, sequences out: a 1,000-frame BVH clip -> the whole-shirt model (batched) -> a mesh per
frame + the video + the animated GLB, stage by stage; the goal is under a minute on 2 CPU cores.

    .venv/bin/python bench/motion.py [--run RUN_DIR] [--frames 1000] [--threads 2] [--video mp4]

--run: a trained whole-shirt run (e.g. runs/main/latest/whole). Without it: the full-size mannequin
(conf/body, its default voxel) and the real T-shirt (conf/garment/tshirt.yaml, 3,153 vertices) with
stand-in offsets, and an untrained whole model of the real size (conf/model/whole.yaml at
conf/image/default.yaml: 3.8M parameters, 256 x 256): the same work per frame as a trained run.
Side by side in the same run: the batched prediction against one frame at a time, and the frame OBJ
writer against meshio's. Prints a table, then one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.core.runs import RunRecord, monitor  # noqa: E402
from pbc.geometry.body.skeleton import skeleton_from_config  # noqa: E402
from pbc.geometry.meshio import write_garment_mesh  # noqa: E402
from pbc.inference.poses import read_motion  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402
from pbc.jobs.predict import predict_sequence  # noqa: E402
from pbc.jobs.writers import FrameObjWriter  # noqa: E402
from pbc.motion.retarget import load_joint_map  # noqa: E402

GOAL_S = 60.0


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "CPU"


def walk_bvh(path: Path, frames: int, fps: float = 120.0) -> Path:
    """A CMU-MotionBuilder-named clip of the body's skeleton: arms swinging, spine and head turning (cm)."""
    skel = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
    table = load_joint_map("cmu_mb")
    heads = skel.rest_heads.double().numpy() * 100
    t = np.arange(frames) / fps
    lines = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 95 0", "CHANNELS 6 Xposition Yposition Zposition Zrotation "
             "Xrotation Yrotation"]
    cols = [np.stack([np.zeros_like(t), 95 + 2 * np.sin(4 * t), 100 * t, 10 * np.sin(2 * t), 0 * t, 0 * t], 1)]

    def joint(j, depth):
        par = skel.parents[j]
        off = heads[j] - (heads[par] if par >= 0 else 0)
        lines.extend([f"JOINT {table.joints[skel.names[j]]}", "{", "OFFSET " + " ".join(f"{x:.4f}" for x in off),
                      "CHANNELS 3 Zrotation Xrotation Yrotation"])
        phase = 0.3 * j
        name = skel.names[j]
        amp = (35.0, 25.0, 15.0) if name.endswith("arm") else (4.0, 6.0, 3.0)
        cols.append(np.stack([amp[0] * np.sin(2 * np.pi * t + phase) - (55.0 if name == "l_arm" else -55.0
                                                                          if name == "r_arm" else 0.0),
                              amp[1] * np.sin(2 * np.pi * 0.5 * t + phase), amp[2] * np.sin(2 * np.pi * t)], 1))
        kids = [k for k, p in enumerate(skel.parents) if p == j]
        for k in kids:
            joint(k, depth + 1)
        if not kids:
            y = skel.frames()[j][:, 1].double().numpy() * 10
            lines.extend(["End Site", "{", "OFFSET " + " ".join(f"{x:.4f}" for x in y), "}"])
        lines.append("}")

    joint(0, 1)
    lines.append("}")
    data = np.concatenate(cols, 1)
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1 / fps:.7f}"]
    lines += [" ".join(f"{x:.4f}" for x in row) for row in data]
    path.write_text("\n".join(lines) + "\n")
    return path


def stand_in_run(root: Path) -> Path:
    """The full-size body and shirt with stand-in offsets, and an untrained real-size whole model run."""
    from pbc.core.config import load_garment_config
    from pbc.data.dataset import save_embedding
    from pbc.geometry.body.base import save_body
    from pbc.geometry.body.mannequin import build_mannequin
    from pbc.geometry.cage.base import save_cage
    from pbc.geometry.garment.base import save_garment_obj
    from pbc.geometry.garment.tshirt import make_tshirt
    from pbc.geometry.shrinkwrap import embed_points
    from pbc.models.module import ClothModule
    from pbc.pixels.reconstruct import Skinner
    from pbc.sim.poses import euler_xzy_to_matrix

    body = build_mannequin(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))
    garment, cage = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt.yaml"))
    V, J = garment.vertices.shape[0], len(body.skeleton.names)
    emb = embed_points(garment.vertices.numpy(), body, np.zeros(V, np.int64), 16)
    rng = np.random.default_rng(0)
    lim = body.skeleton.limits_deg.double().numpy()
    poses = euler_xzy_to_matrix(torch.from_numpy(rng.uniform(lim[..., 0], lim[..., 1], (40, J, 3)))).float()
    anchors, frames = Skinner(body, garment, emb)(poses)
    verts = anchors + 0.015 * frames[:, :, 2]  # 1.5 cm along the body's normal (frames' rows are the axes)
    d = root / "data"
    d.mkdir(parents=True)
    np.save(d / "poses.npy", poses.numpy())
    np.save(d / "verts.npy", verts.numpy().astype(np.float32))
    save_garment_obj(garment, d / "garment.obj")
    save_cage(cage, d / "cage.json", V)
    save_body(body, d / "body.npz")
    save_embedding(emb, d / "embedding.npz")
    (d / "manifest.json").write_text(json.dumps({"format_version": 1, "garment_hash": "bench", "counts": {
        "kept": 40}, "splits": {"train": list(range(32)), "val": list(range(32, 36)), "test": list(range(36, 40))}}))
    image = OmegaConf.load(ROOT / "conf/image/default.yaml")
    net = OmegaConf.to_container(OmegaConf.load(ROOT / "conf/model/whole.yaml").net)
    net["output_size"] = [int(image.whole_resolution)] * 2
    identity = {"garment_hash": "bench", "kind": "whole", "patch_id": None, "space": "local"}
    m = ClothModule(net=net, kind="whole", space="local", loss={"norm": "l1", "normal_weight": 0.0,
                                                                 "edge_weight": 0.0}, lr=1e-3, identity=identity)
    with torch.no_grad():  # a mean image of 1.5 cm along the normal (du, dv, dn per side), as a trained one's
        m.net.head.weight.mul_(0.01)
        m.net.output_mean[:, 2::3] = 0.015
    run = root / "whole"
    ck = run / "checkpoints" / "epoch_000.ckpt"
    ck.parent.mkdir(parents=True)
    torch.save({"hyper_parameters": dict(m.hparams), "state_dict": m.state_dict()}, ck)
    RunRecord(kind="whole", optimized_metric=monitor("whole"), best_checkpoint=str(ck), identity=identity,
              config={"data": {"dir": str(d)}, "image": OmegaConf.to_container(image)}).write(run)
    return run


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", help="a whole-shirt run dir (default: a stand-in of the real sizes)")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--video", default="mp4", choices=("mp4", "gif"))
    ap.add_argument("--batch-size", type=int, default=32)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    tmp = Path(tempfile.mkdtemp(prefix="pbc_bench_motion_"))
    run = Path(args.run) if args.run else stand_in_run(tmp)
    clip = walk_bvh(tmp / "walk.bvh", args.frames)
    predictor = ClothPredictor.from_runs(run)
    ds = predictor.dataset

    t0 = time.perf_counter()
    motion = read_motion(clip, ds)
    t_read = time.perf_counter() - t0
    res = predict_sequence(predictor, motion, tmp / "out", video=args.video, batch_size=args.batch_size,
                           progress=False)
    total = time.perf_counter() - t0
    stages = {"read + retarget": t_read, **res["seconds_by_stage"]}

    # side by side: batched against one frame at a time (32 frames), the frame writer against meshio's (50)
    poses = torch.from_numpy(motion.poses[:32]).float()
    with torch.inference_mode():
        t = time.perf_counter()
        predictor(poses, model="whole")
        batched = (time.perf_counter() - t) / 32
        t = time.perf_counter()
        for p in poses:
            predictor(p[None], model="whole")
        single = (time.perf_counter() - t) / 32
    verts = np.load(tmp / "out" / "vertices.npy")
    w = FrameObjWriter(ds.garment, tmp / "w" / "first.obj", verts[0])
    t = time.perf_counter()
    for k in range(50):
        w.write(tmp / "w" / f"fast_{k}.obj", verts[k])
    fast = (time.perf_counter() - t) / 50
    t = time.perf_counter()
    for k in range(50):
        write_garment_mesh(tmp / "w" / f"meshio_{k}.obj", ds.garment, verts[k])
    slow = (time.perf_counter() - t) / 50
    video = tmp / "out" / res["files"]["video"]

    device = f"cpu ({cpu_name()}), {torch.get_num_threads()} threads"
    print(f"bench/motion.py: {args.frames} BVH frames -> {res['num_vertices']}-vertex garment, "
          f"{len(ds.body.vertices)}-vertex body; {device}; run {'given' if args.run else 'stand-in (untrained)'}")
    print(f"{'stage':<28}{'seconds':>10}{'ms/frame':>10}")
    for k, v in stages.items():
        print(f"{k:<28}{v:>10.2f}{1000 * v / args.frames:>10.2f}")
    print(f"{'total (wall)':<28}{total:>10.2f}{1000 * total / args.frames:>10.2f}   goal < {GOAL_S:.0f} s: "
          f"{'met' if total < GOAL_S else 'NOT met'}")
    print(f"whole model per frame: batched {batched * 1000:.1f} ms, one at a time {single * 1000:.1f} ms "
          f"({single / batched:.2f}x)")
    print(f"OBJ per frame: frame writer {fast * 1000:.1f} ms, meshio {slow * 1000:.1f} ms ({slow / fast:.1f}x)")
    print(f"video {video.name}: {video.stat().st_size / 1e6:.1f} MB; garment.glb "
          f"{(tmp / 'out' / 'garment.glb').stat().st_size / 1e6:.1f} MB; output in {tmp}")
    print(json.dumps({"device": device, "frames": args.frames, "vertices": res["num_vertices"],
                      "body_vertices": len(ds.body.vertices), "stand_in_run": not args.run,
                      "seconds": {k: round(v, 3) for k, v in stages.items()}, "total_s": round(total, 2),
                      "goal_s": GOAL_S, "goal_met": total < GOAL_S,
                      "predict_ms_per_frame": {"batched": round(batched * 1000, 2), "single": round(single * 1000, 2)},
                      "batched_speedup": round(single / batched, 2),
                      "obj_ms_per_frame": {"frame_writer": round(fast * 1000, 2), "meshio": round(slow * 1000, 2)},
                      "obj_writer_speedup": round(slow / fast, 2)}))


if __name__ == "__main__":
    main()
