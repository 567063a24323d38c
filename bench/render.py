"""Benchmark cloth-image rendering: representation floor, batched operators vs a per-sample rasteriser,
and the DataModule's samples/s against the whole-shirt network's training samples/s.

    python bench/render.py [--data DIR] [--batch 32] [--reps 3]

Uses the dataset in --data (default data/tshirt_tiny_seed0) when it exists; otherwise the coarse
T-shirt with synthetic smooth offsets (the DataModule row is then skipped). Prints a table, and a
final line of JSON with the numbers and ratios.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from skimage.draw import polygon

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pbc.pixels.frames import to_offsets  # noqa: E402
from pbc.pixels.operators import ImageOperators, image_sizes  # noqa: E402


def per_sample_rasterise(garment, x: np.ndarray, res: int) -> np.ndarray:
    """The baseline: rasterise one sample (V, 3) with skimage, triangle by triangle -> (6, res, res)."""
    img = np.zeros((2, 3, res, res), np.float32)
    faces, uv, fuv, side = (
        np.asarray(a) for a in (garment.faces, garment.uv, garment.face_uv, garment.face_side)
    )
    for f in range(len(faces)):
        t = uv[fuv[f]] * res - 0.5
        rr, cc = polygon(t[:, 1], t[:, 0], (res, res))
        if not len(rr):
            continue
        a, b, c = t
        den = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if abs(den) < 1e-12:
            continue
        l1 = ((cc - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (rr - a[1])) / den
        l2 = ((b[0] - a[0]) * (rr - a[1]) - (cc - a[0]) * (b[1] - a[1])) / den
        w = np.stack([1 - l1 - l2, l1, l2], 1)
        img[side[f], :, rr, cc] = w @ x[faces[f]]
    return img.reshape(6, res, res)


def timed(fn, reps: int) -> float:
    fn()  # warm-up (per-device tensors, allocator)
    t = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t) / reps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(ROOT / "data/tshirt_tiny_seed0"))
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument(
        "--baseline-samples", type=int, default=4, help="per-sample rasteriser runs (then scaled)"
    )
    args = ap.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    image_cfg = OmegaConf.load(ROOT / "conf/image/default.yaml")
    sizes = image_sizes(image_cfg)
    data = None
    if (Path(args.data) / "manifest.json").is_file():
        from pbc.data.dataset import load_dataset
        from pbc.pixels.reconstruct import Skinner

        data = load_dataset(args.data)
        garment = data.garment
        n = min(len(data), args.batch)
        idx = np.arange(len(data))[:n]
        poses = torch.from_numpy(np.array(data.poses[idx]))
        verts = torch.from_numpy(np.array(data.verts[idx]))
        anchors, frames = Skinner(data.body, garment, data.embedding)(poses)
        x = to_offsets(verts, anchors, frames, "local")
        source = f"dataset {args.data} ({len(data)} samples, {n} used)"
    else:
        from pbc.core.config import load_garment_config
        from pbc.geometry.garment.tshirt import make_tshirt

        garment, _ = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt_coarse.yaml"))
        p = garment.vertices[None] * torch.linspace(0.5, 1.5, args.batch)[:, None, None]
        x = 0.01 * torch.stack(
            [torch.sin(9 * p[..., 1]), torch.cos(7 * p[..., 0]), torch.sin(5 * p[..., 2] + p[..., 0])], -1
        )
        source = "synthetic offsets on conf/garment/tshirt_coarse (no dataset found)"
    x = torch.cat([x] * (args.batch // len(x) + 1))[: args.batch]
    print(f"# source: {source}; V={x.shape[1]}; torch threads={torch.get_num_threads()}")
    out: dict = {"source": source, "num_vertices": int(x.shape[1])}

    # 1. representation floor: S(R(x)) vs x, per-vertex error in cm
    print(f"{'floor':<10}{'res':>6}{'exact':>7}{'mean cm':>12}{'max cm':>12}{'build s':>9}")
    for res, pad in ((256, sizes["whole_pad"]), (512, sizes["patch_pad"])):
        for exact in (False, True):
            t = time.perf_counter()
            ops = ImageOperators.for_garment(garment, res, pad, exact=exact)
            build = time.perf_counter() - t
            err = (ops.sample(ops.render(x)) - x).norm(dim=-1) * 100
            print(f"{'':<10}{res:>6}{exact!s:>7}{err.mean():>12.2e}{err.max():>12.2e}{build:>9.2f}")
            out[f"floor_{res}_{'exact' if exact else 'plain'}_cm"] = {
                "mean": float(err.mean()),
                "max": float(err.max()),
            }

    # 2. batched rendering at 512 vs the per-sample rasteriser
    res = sizes["patch_resolution"]
    gather = ImageOperators.for_garment(garment, res, sizes["patch_pad"])
    sparse = ImageOperators(gather.arrays, method="sparse")
    t_gather = timed(lambda: gather.render(x), args.reps)
    t_sparse = timed(lambda: sparse.render(x), args.reps)
    xn = x.numpy()
    k = min(args.baseline_samples, len(xn))
    t0 = time.perf_counter()
    for i in range(k):
        per_sample_rasterise(garment, xn[i], res)
    t_base = (time.perf_counter() - t0) / k * len(xn)
    print(f"\n{'render ' + str(len(xn)) + ' @' + str(res):<24}{'seconds':>10}{'ratio':>10}")
    for name, t in (
        ("per-sample skimage", t_base),
        ("batched gather", t_gather),
        ("batched sparse", t_sparse),
    ):
        print(f"{name:<24}{t:>10.4f}{t_base / t:>10.1f}")
    out.update(
        render_512_batch=len(xn),
        per_sample_s=t_base,
        gather_s=t_gather,
        sparse_s=t_sparse,
        ratio_gather=t_base / t_gather,
        ratio_sparse=t_base / t_sparse,
    )

    # 3. DataModule samples/s vs the whole-shirt network's training samples/s
    from pbc.models.decoder import ConvDecoder

    net = ConvDecoder(
        in_features=90,
        out_channels=6,
        output_size=(256, 256),
        start_size=(8, 8),
        start_channels=384,
        first_layer="conv_transpose",
    )
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    bs = 8
    pose = torch.randn(bs, 90)
    whole = ImageOperators.for_garment(garment, sizes["whole_resolution"], sizes["whole_pad"])
    target = whole.render(x[:bs])
    mask = whole.image_mask()

    def step():
        opt.zero_grad()
        loss = ((net(pose) - target).abs() * mask).sum() / mask.sum()
        loss.backward()
        opt.step()

    train_sps = bs / timed(step, args.reps)
    print(f"\n{'throughput':<24}{'samples/s':>10}")
    print(f"{'whole net train step':<24}{train_sps:>10.1f}")
    out["train_samples_per_s"] = train_sps
    if data is not None:
        from pbc.data.datamodule import ClothDataModule

        dm = ClothDataModule(args.data, image_cfg, target="whole", batch_size=bs)
        dm.setup("fit")

        def load_epoch():
            n = 0
            for b in dm.train_dataloader():
                dm.on_after_batch_transfer(b, 0)
                n += len(b["pose"])
            return n

        t = time.perf_counter()
        count = load_epoch()
        data_sps = count / (time.perf_counter() - t)
        print(f"{'datamodule (render)':<24}{data_sps:>10.1f}")
        out.update(datamodule_samples_per_s=data_sps, data_over_train=data_sps / train_sps)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
