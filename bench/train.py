"""Benchmark the training step: the full pbc step against the bare network, in one run.

    python bench/train.py [--data tshirt_tiny] [--model whole] [--batch 8] [--steps 5] [--res 256]

Full step = a real batch from the DataModule -> on-the-fly rendering (skinning, frames, offsets, image)
-> forward -> eq. 1 loss (+ normal loss through image -> vertices -> 3D when on) -> backward -> Adam.
Bare step = the same network and optimiser on random (pose, image) tensors already in memory, L1 loss.
Samples/s of each and the ratio full / bare (goal >= 0.9: the data path must not be the bottleneck).
Prints a table and, as the last line, JSON. Generates the dataset on first use.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.config import load_config  # noqa: E402
from pbc.losses import image_loss  # noqa: E402
from pbc.models.module import ClothModule  # noqa: E402
from pbc.train import datamodule, net_config  # noqa: E402


def timed(fn, steps: int, warmup: int = 1) -> float:
    """Seconds per call of fn (after warm-up)."""
    for _ in range(warmup):
        fn()
    t = time.perf_counter()
    for _ in range(steps):
        fn()
    return (time.perf_counter() - t) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="tshirt_tiny")
    ap.add_argument("--model", default="whole", choices=["whole", "patch"])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--res", type=int, default=256, help="image.whole_resolution (whole model)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = ap.parse_args()
    torch.manual_seed(0)
    dev = torch.device(args.device)

    cfg = load_config([f"data={args.data}", f"model={args.model}", f"image.whole_resolution={args.res}",
                       f"datamodule.batch_size={args.batch}", "paths.output_dir=/tmp/pbc_bench"])
    dm = datamodule(cfg)
    target = dm.target
    ident = target.identity(dm.data)
    size = list(target.image_size)
    net_cfg = net_config(cfg, target)
    batches = [b for _, b in zip(range(4), dm.train_dataloader(), strict=False)]
    batches = [b for b in batches if b["pose"].shape[0] == args.batch] or batches
    rows, out = [], {"device": str(dev), "model": args.model, "batch": args.batch, "image": size,
                     "num_vertices": ident["num_vertices"]}

    def optimise(loss, opt) -> None:
        """The part both steps share: backward, Adam, and a sync so GPU timings are real."""
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if dev.type == "cuda":
            torch.cuda.synchronize()

    def full(normal_weight: float):
        m = ClothModule(net_cfg, args.model, cfg.model.space, {"norm": "l1", "normal_weight": normal_weight,
                                                                "edge_weight": 0.0}, 1e-3, ident)
        m.attach(target).to(dev).train()
        m.log_dict = lambda *a, **k: None  # no Trainer here: logging is not what is measured
        opt = m.configure_optimizers()
        it = iter(range(10**9))

        def step():
            b = batches[next(it) % len(batches)]
            b = dm.on_after_batch_transfer({k: v.to(dev) for k, v in b.items()}, 0)
            optimise(m.step(b, "train", 0)[0], opt)
        return step

    def bare():
        m = ClothModule(net_cfg, args.model, cfg.model.space, {"norm": "l1", "normal_weight": 0.0,
                                                                "edge_weight": 0.0}, 1e-3, ident).to(dev)
        opt = m.configure_optimizers()
        pose = torch.randn(args.batch, 90, device=dev)
        target = torch.randn(args.batch, m.net.out_channels, *size, device=dev)
        mask = torch.ones(1, m.net.out_channels, *size, device=dev)

        def step():
            optimise(image_loss(m(pose), target, mask, "l1"), opt)
        return step

    t_bare = timed(bare(), args.steps)
    for name, fn in [("bare network (random tensors)", None), ("full pbc step, normal loss off", 0.0),
                     ("full pbc step, normal loss on", 0.01)]:
        t = t_bare if fn is None else timed(full(fn), args.steps)
        rows.append((name, args.batch / t, t_bare / t))
    out["samples_per_s"] = {r[0]: round(r[1], 2) for r in rows}
    out["ratio_full_normal_off"] = round(rows[1][2], 3)
    out["ratio_full_normal_on"] = round(rows[2][2], 3)
    print(f"{'step':34s} {'samples/s':>10s} {'x bare':>7s}")
    for name, sps, ratio in rows:
        print(f"{name:34s} {sps:10.2f} {ratio:7.3f}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
