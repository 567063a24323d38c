"""Latency of pose -> garment on this machine: whole model, 28 patches (loop vs stacked forms), seam methods.

    .venv/bin/python bench/predict.py                        # paper-size random decoders, stand-in shirt
    .venv/bin/python bench/predict.py --whole RUN --patches SWEEP_DIR   # trained runs
    .venv/bin/python bench/predict.py --device cuda          # on a GPU (the default when one is present)
Also measures the bfloat16 patch net (CPU AMX / AVX512-bf16) and its vertex distance to float32 in cm.
Prints a markdown table of the best-of-N milliseconds at batch 1 and batch 32 (full pose -> (B, V, 3),
skinning included). Timings are only comparable on a quiet machine; say when it is shared.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class Rows(list):
    """Rows printed as they are measured (a long run killed midway still shows what it has)."""

    def append(self, row) -> None:
        super().append(row)
        print(f"| {row[0]} | {row[1]} | {row[2]:.1f} |", flush=True)


DEVICE = torch.device("cpu")


def sync() -> None:
    """Wait for queued GPU work, so a timing covers the kernels and not only their launch."""
    if DEVICE.type == "cuda":
        torch.cuda.synchronize(DEVICE)


def best_ms(fn, reps: int) -> float:
    fn()  # warm-up: allocations, oneDNN primitive caches, cuDNN algorithm choice
    sync()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        sync()
        ts.append(time.perf_counter() - t0)
    return 1000 * min(ts)


def paper_predictor(stitch_cfg):
    """Random paper-size decoders (3.79M whole, 28 x 3.96M patches) on the stand-in coarse T-shirt."""
    import tempfile

    from hydra.utils import instantiate

    from pbc.inference.predictor import ClothPredictor

    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.evaluate_world import IMAGE, fake_dataset

    ds = fake_dataset(Path(tempfile.mkdtemp()) / "fake")
    patch_cfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf/model/patch.yaml").net)
    patch_cfg["output_size"] = [int(IMAGE.crop_size)] * 2
    whole_cfg = OmegaConf.load(ROOT / "conf/model/whole.yaml").net
    whole_cfg = OmegaConf.to_container(OmegaConf.merge({"image": IMAGE}, {"n": whole_cfg}), resolve=True)["n"]
    torch.manual_seed(0)
    whole = instantiate(whole_cfg).eval()
    patches = [instantiate(patch_cfg).eval() for _ in range(28)]
    return ClothPredictor(ds, IMAGE, whole, patches, stitch_cfg, device=DEVICE)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--whole")
    ap.add_argument("--patches", nargs="*")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--batches", type=int, nargs="*", default=[1, 32])
    ap.add_argument("--skip-loop", action="store_true")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu",
                    help="where the networks and the stitch run (default: cuda when present)")
    args = ap.parse_args()
    global DEVICE
    DEVICE = torch.device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    from pbc.inference.predictor import LoopPatchNet, StackedPatchNet

    stitch_cfg = OmegaConf.load(ROOT / "conf/stitch/average.yaml")
    if args.patches:
        from pbc.inference.predictor import ClothPredictor

        pred = ClothPredictor.from_runs(args.whole, args.patches, stitch_cfg, device=DEVICE)
    else:
        pred = paper_predictor(stitch_cfg)
    from pbc.inference.predictor import fit_training_pca

    pred.stitcher.pca = fit_training_pca(pred, 128, 4096)
    dev_name = torch.cuda.get_device_name(DEVICE) if DEVICE.type == "cuda" else "CPU"
    print(f"device {DEVICE} ({dev_name}), threads {torch.get_num_threads()}, V = {pred.faces.max().item() + 1}, "
          f"torch {torch.__version__}")

    forms = {"stacked (device default layout)": pred.patch_net}
    if not args.skip_loop:
        forms["loop of 28"] = LoopPatchNet(pred.patch_nets).eval().to(DEVICE)
    forms["stacked, all bmm"] = StackedPatchNet(pred.patch_nets, ("bmm",) * 5).eval().to(DEVICE)
    forms["stacked, all grouped CL"] = StackedPatchNet(pred.patch_nets, ("grouped",) * 5).eval().to(DEVICE)
    forms["stacked, all grouped (no CL)"] = StackedPatchNet(pred.patch_nets, ("grouped",) * 5,
                                                            False).eval().to(DEVICE)
    bf16 = StackedPatchNet(pred.patch_nets, dtype=torch.bfloat16).eval().to(DEVICE)
    forms["stacked, bfloat16"] = bf16
    forms["stacked, bfloat16, all grouped CL"] = StackedPatchNet(pred.patch_nets, ("grouped",) * 5,
                                                                 dtype=torch.bfloat16).eval().to(DEVICE)
    fp32_net = pred.patch_net

    def with_net(net, fn):
        """Run fn with the predictor's patch net swapped (the bf16 row of the full pipeline)."""
        pred.patch_net = net
        try:
            return fn()
        finally:
            pred.patch_net = fp32_net

    rows = Rows()
    print("\n| batch | what | ms |\n|---|---|---|", flush=True)
    for B in args.batches:
        pose = torch.from_numpy(pred.dataset.poses[:1]).float().expand(B, -1, -1, -1).contiguous().to(DEVICE)
        reps = args.reps if B == 1 else max(1, args.reps // 2)
        with torch.inference_mode():
            x = pose.reshape(B, -1)
            rows.append((B, "whole: pose -> mesh", best_ms(lambda pose=pose: pred(pose, model="whole"), reps)))
            for name, net in forms.items():
                if name.startswith("loop") and B > 1 and args.skip_loop:
                    continue
                rows.append((B, f"28 patch nets, {name}", best_ms(lambda net=net, x=x: net(x), reps)))
            crops = pred.patch_crops(pose)
            whole_off = pred.whole_offsets(pose)
            for m in ("average", "pca", "inpaint", "hierarchy", "hierarchy_detail"):
                if m == "inpaint" and B > 1:
                    continue  # seconds per sample: biharmonic solves on the CPU
                fn = lambda m=m, c=crops, w=whole_off: pred.stitcher(c, m, w)  # noqa: E731
                rows.append((B, f"stitch only: {m}", best_ms(fn, reps if m != "inpaint" else 1)))
            for m in ("average", "pca", "hierarchy", "hierarchy_detail"):
                fn = lambda m=m, pose=pose: pred(pose, method=m)  # noqa: E731
                rows.append((B, f"pose -> mesh: 28 patches + {m}", best_ms(fn, reps)))
            fn = lambda pose=pose: with_net(bf16, lambda: pred(pose, method="pca"))  # noqa: E731
            rows.append((B, "pose -> mesh: 28 patches (bfloat16) + pca", best_ms(fn, reps)))
    # what bf16 costs in accuracy: the same poses through both precisions, vertex distance in cm
    poses = torch.from_numpy(pred.dataset.poses[:32]).float().to(DEVICE)
    with torch.inference_mode():
        exact = pred(poses, method="pca")
        fast = with_net(bf16, lambda: pred(poses, method="pca"))
    diff_cm = 100 * (fast - exact).norm(dim=-1)
    print(f"\nbfloat16 vs float32 on {len(poses)} poses: vertex distance mean {diff_cm.mean():.4f} cm, "
          f"max {diff_cm.max():.4f} cm")
    ms = {f"b{b} {what}": round(t, 2) for b, what, t in rows}
    figures = {"device": f"{DEVICE} ({dev_name})", "threads": torch.get_num_threads(), "ms": ms,
               "bf16_vertex_diff_cm_mean": round(diff_cm.mean().item(), 5),
               "bf16_vertex_diff_cm_max": round(diff_cm.max().item(), 5)}
    for B in args.batches:  # side-by-side ratios of the same run
        stacked = ms.get(f"b{B} 28 patch nets, stacked (device default layout)")
        loop = ms.get(f"b{B} 28 patch nets, loop of 28")
        if stacked and loop:
            figures[f"b{B}_loop_over_stacked"] = round(loop / stacked, 3)
        full = ms.get(f"b{B} pose -> mesh: 28 patches + pca")
        whole = ms.get(f"b{B} whole: pose -> mesh")
        fast = ms.get(f"b{B} pose -> mesh: 28 patches (bfloat16) + pca")
        if full and fast:
            figures[f"b{B}_fp32_over_bf16_pipeline"] = round(full / fast, 3)
        if full and whole:
            figures[f"b{B}_patches_pca_over_whole"] = round(full / whole, 3)
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
