"""PNG figures of the cloth images (paper section 4) for looking at a dataset.

One job: draw, for a few samples of a dataset, the front/back cloth images (one diverging colour map
per channel, symmetric about 0), the padded chart mask, the patch crop windows on the 512 image, and
the round-trip error map of plain bilinear sampling (per vertex, at its UV).

Takes a loaded dataset (this stage never reads one from disk); the command is
`pbc preview DATASET_DIR [OUT_DIR] [--samples 3] [config overrides, e.g. +experiment=necktie]`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from pbc.core.io import save_figure  # noqa: E402
from pbc.geometry.meshio import SIDE_NAMES
from pbc.pixels.frames import to_offsets  # noqa: E402
from pbc.pixels.operators import ImageOperators, image_sizes  # noqa: E402
from pbc.pixels.reconstruct import Skinner  # noqa: E402
from pbc.pixels.target import image_operators, make_target  # noqa: E402

# channel names of the offsets in each space (pbc.pixels.frames)
CHANNELS = {"local": ("du", "dv", "dn"), "root": ("dx", "dy", "dz"), "position": ("x", "y", "z")}


def cloth_image_figure(images: np.ndarray, mask: np.ndarray, path: Path, titles: list[str],
                       pieces: tuple[str, ...] = SIDE_NAMES, channels: tuple[str, ...] = CHANNELS["local"]) -> None:
    """images (N, 3P, H, W) of P pieces (chart sides), mask (P, H, W) -> rows = samples x piece, columns = the
    3 channels (+ mask)."""
    n, p = len(images), len(pieces)
    h, w = images.shape[-2:]
    fig, axes = plt.subplots(p * n, 4, figsize=(12, max(1.2, 3 * p * n * h / w) + 1), squeeze=False)
    for c in range(3):  # one symmetric scale per channel across samples, so pose changes are visible
        lim = max(float(np.abs(images[:, c::3]).max()), 1e-9)
        for i in range(n):
            for s in range(p):
                ax = axes[p * i + s, c]
                im = np.where(mask[s], images[i, 3 * s + c], np.nan)
                hm = ax.imshow(im, cmap="RdBu_r", vmin=-lim, vmax=lim)
                ax.set_title(f"{titles[i]} {pieces[s]} {channels[c]} (m)", fontsize=8)
                ax.axis("off")
        fig.colorbar(hm, ax=axes[:, c].tolist(), shrink=0.3)
    for i in range(n):
        for s in range(p):
            axes[p * i + s, 3].imshow(mask[s], cmap="gray")
            axes[p * i + s, 3].set_title("padded chart mask", fontsize=8)
            axes[p * i + s, 3].axis("off")
    save_figure(fig, path, dpi=80)


def crop_windows_figure(ops512: ImageOperators, image: np.ndarray, cage, crop_size: int, path: Path) -> None:
    """The 512 image's dn channel per side with every patch's crop window drawn on it."""
    fig, axes = plt.subplots(1, 2, figsize=(14, 7.6), layout="constrained")
    # one symmetric colour scale for both sides, so front and back compare
    lim = max(float(np.abs(image[[2, 5]][ops512.mask.numpy()]).max(initial=0.0)), 1e-9)
    for s in range(2):
        ax = axes[s]
        h = ax.imshow(np.where(ops512.mask[s].numpy(), image[3 * s + 2], np.nan), cmap="RdBu_r", vmin=-lim,
                      vmax=lim)
        for p in cage.patches:
            if p.side != s:
                continue
            r0, c0, size = ops512.crop_window(p.box_512, crop_size)
            ax.add_patch(Rectangle((c0 - 0.5, r0 - 0.5), size, size, fill=False, lw=1, ec=f"C{p.id % 10}"))
            ax.text(c0 + size / 2, r0 + size / 2, str(p.id), ha="center", va="center", fontsize=7)
        ax.set_title(f"{'front' if s == 0 else 'back'}: crop windows ({crop_size} px)")
        ax.axis("off")
    fig.colorbar(h, ax=axes.tolist(), location="bottom", shrink=0.4, aspect=40, label="dn offset (m)")
    save_figure(fig, path, dpi=80)


def round_trip_figure(garment, plain: ImageOperators, x: torch.Tensor, path: Path) -> float:
    """Per-vertex |S R x - x| (cm) of plain (uncorrected) operators at each vertex's UV; returns the mean."""
    err = ((plain.sample(plain.render(x)) - x).norm(dim=-1) * 100).mean(0).numpy()
    uv, side = np.asarray(garment.vertex_uv), np.asarray(garment.vertex_side)
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    for s in range(2):
        m = side == s
        h = axes[s].scatter(uv[m, 0], uv[m, 1], c=err[m], cmap="magma", s=12, vmin=0, vmax=err.max())
        axes[s].set_xlim(0, 1)
        axes[s].set_ylim(1, 0)
        axes[s].set_aspect("equal")
        axes[s].set_title(f"{'front' if s == 0 else 'back'}: plain round-trip error at {plain.res} (cm)")
    fig.colorbar(h, ax=axes.tolist(), shrink=0.6)
    save_figure(fig, path, dpi=80)
    return float(err.mean())


def preview(data, out_dir: str | Path, image_cfg, samples: int = 3, space: str = "local") -> list[Path]:
    """Write the PNGs for the first `samples` samples of a loaded dataset `data`; returns their paths.

    The cloth images are the whole model's target in offset space `space` (pbc.pixels.target: the square
    image, or the window a garment's charts fill, as training serves it); the crop windows and the
    round-trip error use local offsets, with the patch operators training uses and the plain (uncorrected)
    ones the round trip compares against, uncached.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sizes = image_sizes(image_cfg)
    idx = np.arange(min(samples, len(data)))
    skinner = Skinner(data.body, data.garment, data.embedding)
    batch = {"pose": torch.from_numpy(np.array(data.poses[idx])), "verts": torch.from_numpy(np.array(data.verts[idx]))}
    whole = make_target(data, image_cfg, "whole", space=space, skinner=skinner).render(batch)
    x = to_offsets(batch["verts"], whole["anchors"], whole["frames"], "local")
    ops512 = image_operators(data, image_cfg, "patch")
    plain = ImageOperators.for_garment(data.garment, sizes["patch_resolution"], sizes["patch_pad"], exact=False)
    paths = [out / "cloth_images.png", out / "crop_windows.png", out / "round_trip_error.png"]
    cloth_image_figure(whole["image"].numpy(), whole["mask"][0, ::3].numpy() > 0, paths[0],
                       [f"sample {i}" for i in idx], tuple(SIDE_NAMES[s] for s in sizes["whole_sides"]),
                       CHANNELS[space])
    crop_windows_figure(ops512, ops512.render(x[:1]).numpy()[0], data.cage, sizes["crop_size"], paths[1])
    round_trip_figure(data.garment, plain, x, paths[2])
    return paths
