"""Benchmark the training step: the full pbc step against the bare network, side by side in one run.

    python bench/train.py [--data tshirt_small] [--models whole,patch] [--batch 32] [--reps 3]
                          [--device cpu|cuda] [--patch-id 7] [--set KEY=VALUE ...]

For each model (whole 6-channel image, one patch crop) and each variant:
    bare                      the same network and Adam on random (pose, image) tensors already in memory
    full, cache off, normal   a batch from the DataModule -> per-batch render (skinning, frames, offsets,
                              image) -> forward -> eq. 1 loss (+ normal loss through image -> vertices ->
                              normals when "on") -> backward -> Adam
    full, cache on, normal    the same, targets looked up in the DataModule's target cache
Samples/s of each, the ratio full / bare (goal >= 0.9 with the normal loss on: the data path must not be
the bottleneck) and the milliseconds of the step spent getting the targets. Variants run interleaved (one
step of each per round, median over rounds) so a shared machine's load hits all of them alike. Also
measured: building the cache, and the error a float16 image cache would add (image units = metres of
offset, and cm on the garment after sampling back to 3D), next to the representation floor (the float32
image's own round-trip error back to the draped vertices).
Batches are drawn with replacement from every sample of the data set, so a small data set serves any
batch size. Prints a table and, as the last line, JSON. Generates the dataset on first use.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.core.config import load_config  # noqa: E402
from pbc.data.datamodule import PoseVerts  # noqa: E402
from pbc.jobs.train import datamodule, net_config  # noqa: E402
from pbc.models.losses import image_loss  # noqa: E402
from pbc.models.module import ClothModule  # noqa: E402
from pbc.pixels.target import build_cache  # noqa: E402

NORMAL_WEIGHT = 0.01  # conf/loss/l1_normal.yaml's weight; the cost, not the value, is measured


def device_name(dev: torch.device) -> str:
    if dev.type == "cuda":
        return torch.cuda.get_device_name(dev)
    return f"{platform.processor() or platform.machine()} CPU, {torch.get_num_threads()} torch threads"


def sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def fp16_error(target, dm, dev) -> dict:
    """What storing the cached images as float16 changes: max |image16 - image32| (metres of offset) and
    the mean / max vertex distance (cm) of the positions decoded from each, next to the float32 image's own
    round-trip error to the draped vertices (the representation floor)."""
    idx = torch.as_tensor(sorted(int(i) for s in dm.splits.values() for i in s))
    pose = torch.from_numpy(dm.data.poses[idx.numpy()]).float().reshape(len(idx), -1)
    verts = torch.from_numpy(dm.data.verts[idx.numpy()]).float()
    c32 = build_cache(target, pose, verts, idx, dev, image_dtype=torch.float32, normals=False)
    c16 = build_cache(target, pose, verts, idx, dev, image_dtype=torch.float16, normals=False)
    batch = {"pose": pose.to(dev), "verts": verts.to(dev), "index": idx.to(dev)}
    t32, t16 = c32.lookup(batch), c16.lookup(batch)
    p32, p16 = target.positions(t32["image"], t32), target.positions(t16["image"], t16)
    ids = target.vertices
    sel = slice(None) if ids is None else ids.to(dev)
    d16 = (p16 - p32)[:, sel].norm(dim=-1) * 100
    floor = (p32 - batch["verts"])[:, sel].norm(dim=-1) * 100
    return {"image_max_abs_m": float((t16["image"] - t32["image"]).abs().max()),
            "image_max_abs_value_m": float(t32["image"].abs().max()),
            "fp16_vs_fp32_cm_mean": float(d16.mean()), "fp16_vs_fp32_cm_max": float(d16.max()),
            "floor_fp32_roundtrip_cm_mean": float(floor.mean()), "floor_fp32_roundtrip_cm_max": float(floor.max()),
            "bytes_per_sample_fp32": c32.nbytes // len(idx), "bytes_per_sample_fp16": c16.nbytes // len(idx)}


def bench_model(args, kind: str, dev: torch.device) -> dict:
    over = [f"data={args.data}", f"model={kind}", f"datamodule.batch_size={args.batch}",
            "paths.output_dir=/tmp/pbc_bench", *args.set]
    if kind == "patch":
        over.append(f"model.patch_id={args.patch_id}")
    cfg = load_config(over)
    dm = datamodule(cfg)
    target = dm.target
    ident = target.identity(dm.data)
    size = list(target.image_size)
    net_cfg = net_config(cfg, target)
    all_idx = sorted(int(i) for s in dm.splits.values() for i in s)
    samples = PoseVerts(dm.data, all_idx)
    gen = torch.Generator().manual_seed(0)

    def next_batch() -> dict:
        pick = torch.randint(len(samples), (args.batch,), generator=gen).tolist()
        items = [samples[i] for i in pick]
        return {k: torch.stack([it[k] for it in items]).to(dev) for k in items[0]}

    t0 = time.perf_counter()
    cache = dm.ensure_cache(dev)
    sync(dev)
    build_s = time.perf_counter() - t0

    def optimise(loss, opt) -> None:
        """The part every variant shares: backward, Adam, and a sync so GPU timings are real."""
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sync(dev)

    def module(normal_weight: float) -> ClothModule:
        m = ClothModule(net_cfg, kind, cfg.model.space, {"norm": "l1", "normal_weight": normal_weight,
                                                         "edge_weight": 0.0}, 1e-3, ident)
        m.attach(target).to(dev).train()
        m.log_dict = lambda *a, **k: None  # no Trainer here: logging is not what is measured
        return m

    data_s: dict[str, list[float]] = {}

    def full(name: str, normal_weight: float, cached: bool):
        m = module(normal_weight)
        opt = m.configure_optimizers()
        data_s[name] = []

        def step():
            dm.cache_targets, target.cache = cached, cache if cached else None
            b = next_batch()
            t = time.perf_counter()
            b = dm.on_after_batch_transfer(b, 0)
            sync(dev)
            data_s[name].append(time.perf_counter() - t)
            optimise(m.step(b, "train", 0)[0], opt)
        return step

    def bare():
        m = module(0.0)
        opt = m.configure_optimizers()
        pose = torch.randn(args.batch, 90, device=dev)
        image = torch.randn(args.batch, m.net.out_channels, *size, device=dev)
        mask = torch.ones(1, m.net.out_channels, *size, device=dev)

        def step():
            next_batch()  # the loader's share of the step is the same in every variant
            optimise(image_loss(m(pose), image, mask, "l1"), opt)
        return step

    variants = {"bare network": bare()}
    for cached in (False, True):
        for nw in (0.0, NORMAL_WEIGHT):
            name = f"full, cache {'on' if cached else 'off'}, normal {'on' if nw else 'off'}"
            variants[name] = full(name, nw, cached)
    times: dict[str, list[float]] = {k: [] for k in variants}
    for rnd in range(args.warmup + args.reps):  # interleaved rounds: shared load hits every variant alike
        for name, fn in variants.items():
            t = time.perf_counter()
            fn()
            if rnd >= args.warmup:
                times[name].append(time.perf_counter() - t)
    dm.cache_targets, target.cache = True, cache
    med = {k: statistics.median(v) for k, v in times.items()}
    bare_t = med["bare network"]
    out = {"image": size, "num_vertices": ident["num_vertices"], "samples": len(all_idx),
           "cache_build_s": round(build_s, 3),
           "cache_gib": None if cache is None else round(cache.nbytes / 2**30, 4),
           "samples_per_s": {k: round(args.batch / v, 2) for k, v in med.items()},
           "ratio_to_bare": {k: round(bare_t / v, 3) for k, v in med.items()},
           # the targets' share of a step (render, or cache lookup), ms: the part the cache takes away
           "data_path_ms": {k: round(1000 * statistics.median(v[args.warmup:]), 2) for k, v in data_s.items()}}
    out["fp16_cache"] = fp16_error(target, dm, dev)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="tshirt_small")
    ap.add_argument("--models", default="whole,patch")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--reps", type=int, default=3, help="timed rounds (one step of every variant each)")
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--patch-id", type=int, default=7)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--set", nargs="*", default=[], help="extra config overrides (e.g. data.dir=...)")
    args = ap.parse_args()
    torch.manual_seed(0)
    dev = torch.device(args.device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: no CUDA device here; use --device cpu")
    out = {"device": device_name(dev), "device_type": dev.type, "batch": args.batch, "reps": args.reps,
           "data": args.data, "models": {}}
    for kind in args.models.split(","):
        out["models"][kind] = bench_model(args, kind, dev)

    print(f"device: {out['device']}   batch {args.batch}, median of {args.reps} interleaved rounds")
    for kind, r in out["models"].items():
        print(f"\n{kind} {r['image']} ({r['samples']} samples; cache {r['cache_gib']} GiB built in "
              f"{r['cache_build_s']} s)")
        print(f"  {'step':34s} {'samples/s':>10s} {'x bare':>7s} {'targets ms':>10s}")
        for name, sps in r["samples_per_s"].items():
            ms = r["data_path_ms"].get(name)
            print(f"  {name:34s} {sps:10.2f} {r['ratio_to_bare'][name]:7.3f} {'' if ms is None else f'{ms:10.1f}'}")
        e = r["fp16_cache"]
        print(f"  fp16 image cache: max |d image| {e['image_max_abs_m']:.2e} m (values up to "
              f"{e['image_max_abs_value_m']:.3f} m); decoded vertices {e['fp16_vs_fp32_cm_mean']:.2e} cm mean, "
              f"{e['fp16_vs_fp32_cm_max']:.2e} cm max; fp32 round-trip floor {e['floor_fp32_roundtrip_cm_mean']:.2e}"
              f" cm mean, {e['floor_fp32_roundtrip_cm_max']:.2e} cm max")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
