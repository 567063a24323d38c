"""All patch models in one job vs. one job per patch: training samples/s of ALL patches, side by side.

    python bench/train_patches.py [--data tshirt_tiny] [--batch 8] [--steps 3] [--device cuda]
                                  [--start-channels 64] [--patch-res 128] [--loss l1_normal]

stacked    = `+experiment=patches`: one render of the patch-resolution image per batch, every crop cut from
             it (PatchesTarget), one forward/backward of the stacked grouped-conv network
             (pbc.models.stacked), the per-patch losses summed, one Adam step.
sequential = what the P single-patch jobs do for the same batch: per patch, render its crop (PatchTarget),
             forward/backward of its own decoder, its own Adam step; P times.
Both start from the same weights (the sequential decoders are the stacked net's blocks) and see the same
raw batch on the device. Reported: samples/s counted once per sample for all P patches (a sample is done
when every patch has stepped on it), and stacked / sequential. Goal on a GPU: >= 3x. Network size and
patch resolution default to the config (paper size); pass smaller ones on a CPU. The last line is JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hydra.utils import instantiate  # noqa: E402

from pbc.core.config import load_config  # noqa: E402
from pbc.jobs.train import datamodule, net_config  # noqa: E402
from pbc.models.module import ClothModule  # noqa: E402


def timed(fn, steps: int, dev: torch.device, warmup: int = 1) -> float:
    """Seconds per call of fn after warm-up (GPU work waited for)."""
    for _ in range(warmup):
        fn()
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    t = time.perf_counter()
    for _ in range(steps):
        fn()
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    return (time.perf_counter() - t) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="tshirt_tiny")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--start-channels", type=int, default=None, help="patch decoder width (config: 512)")
    ap.add_argument("--patch-res", type=int, default=None, help="image.patch_resolution (config: 512)")
    ap.add_argument("--loss", default="l1", help="a conf/loss option (l1_normal: with the normal loss)")
    ap.add_argument("--data-dir", default=None, help="paths.data_dir (where the datasets live)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message=".*self.trainer.*")  # steps outside a Trainer: logging is a no-op
    dev = torch.device(args.device)
    over = [f"data={args.data}", "+experiment=patches", f"loss={args.loss}",
            f"datamodule.batch_size={args.batch}", "paths.output_dir=/tmp/pbc_bench_patches"]
    if args.start_channels:
        over.append(f"model.net.start_channels={args.start_channels}")
    if args.patch_res:
        over.append(f"image.patch_resolution={args.patch_res}")
    if args.data_dir:
        over.append(f"paths.data_dir={args.data_dir}")
    cfg = load_config(over)
    dm = datamodule(cfg)
    target = dm.target
    torch.manual_seed(0)
    stacked = instantiate(cfg.model, net=net_config(cfg, target), identity=target.identity(dm.data),
                          summary={}).attach(target).to(dev)
    P = target.num_patches
    singles = []
    for p, sub in enumerate(target.patches):
        m = ClothModule(stacked.net.decoder_config(), "patch", cfg.model.space, stacked.hparams.loss, cfg.model.lr,
                        sub.identity(dm.data), patch_id=sub.patch_id).attach(sub)
        m.net.load_state_dict(stacked.net.patch_state(p))
        singles.append(m.to(dev))
    raw = next(iter(dm.train_dataloader()))
    raw = {k: v.to(dev) if torch.is_tensor(v) else v for k, v in raw.items()}
    B = raw["pose"].shape[0]

    def step(module, opt, render):
        loss, _ = module.step(render(raw), "train", 0)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    opt_s = stacked.configure_optimizers()
    opts = [m.configure_optimizers() for m in singles]
    stacked.train()
    for m in singles:
        m.train()

    def run_stacked():
        step(stacked, opt_s, target.render)

    def run_sequential():
        for m, o in zip(singles, opts, strict=True):
            step(m, o, m.target.render)

    t_stacked = timed(run_stacked, args.steps, dev)
    t_seq = timed(run_sequential, args.steps, dev)
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    S = target.image_size[0]
    net = cfg.model.net
    print(f"device {dev} ({name}); {P} patches of {S}x{S} from the {target.resolution} px image, start_channels "
          f"{net.start_channels}, batch {B}, loss {args.loss}, {args.steps} timed steps, torch {torch.__version__}")
    print("\n| arm | s per batch (all patches) | samples/s (all patches) |\n|---|---|---|")
    print(f"| stacked (one job) | {t_stacked:.3f} | {B / t_stacked:.1f} |")
    print(f"| sequential ({P} single-patch steps) | {t_seq:.3f} | {B / t_seq:.1f} |")
    ratio = t_seq / t_stacked
    print(f"\nstacked / sequential: {ratio:.2f}x (goal on a GPU: >= 3x)")
    print(json.dumps({"device": f"{dev} ({name})", "num_patches": P, "crop": S, "resolution": target.resolution,
                      "start_channels": int(net.start_channels), "batch": B, "loss": args.loss,
                      "stacked_samples_per_s": round(B / t_stacked, 2),
                      "sequential_samples_per_s": round(B / t_seq, 2), "stacked_over_sequential": round(ratio, 3)}))


if __name__ == "__main__":
    main()
