"""Preview figures of a dataset: the UV layout with the cage and patch ids, draped samples, OBJ exports,
and (with an image config) the pixels stage's cloth images, crop windows and round-trip error map.

Everything is written under `<dataset>/preview/` (PNG via matplotlib, meshes via pbc.geometry.meshio),
atomically.

    pbc preview DATASET_DIR [OUT_DIR] [--samples 3]    # the cloth-image figures only
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from pbc.core.io import save_figure  # noqa: E402
from pbc.data.dataset import ClothDataset, load_dataset  # noqa: E402
from pbc.geometry.body.base import pose_body  # noqa: E402
from pbc.geometry.meshio import SIDE_NAMES, write_garment_mesh, write_mesh  # noqa: E402
from pbc.pixels.preview import preview as cloth_image_preview  # noqa: E402
from pbc.sim.poses import plot_angle_histograms  # noqa: E402


def plot_uv_layout(ds: ClothDataset, path: Path) -> Path:
    """Both UV charts, faces coloured by patch, patch ids at their box centres, boxes drawn (512 px)."""
    g, cage = ds.garment, ds.cage
    patch_of = np.empty(g.vertices.shape[0], dtype=np.int64)
    for p in cage.patches:
        patch_of[p.vertices] = p.id
    uv = g.uv.numpy() * 512.0
    face_uv, face_side = g.face_uv.numpy(), g.face_side.numpy()
    face_patch = patch_of[g.faces.numpy()[:, 0]]
    cmap = plt.get_cmap("tab20")
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    for side, ax in enumerate(axes):
        sel = face_side == side
        polys = uv[face_uv[sel]]
        ax.add_collection(
            PolyCollection(polys, facecolors=cmap(face_patch[sel] % 20), edgecolors="k", linewidths=0.1, alpha=0.8)
        )
        for p in cage.patches:
            if p.side != side:
                continue
            r0, c0, r1, c1 = p.box_512
            ax.add_patch(plt.Rectangle((c0, r0), c1 - c0, r1 - r0, fill=False, lw=0.8, ec="k"))
            ax.text((c0 + c1) / 2, (r0 + r1) / 2, str(p.id), ha="center", va="center", fontsize=8, weight="bold")
        ax.set_xlim(0, 512)
        ax.set_ylim(512, 0)  # image convention: row 0 at the top
        ax.set_aspect("equal")
        ax.set_title(f"{SIDE_NAMES[side]} chart (512 px), patches and boxes")
    return save_figure(fig, path)


def _project(verts: np.ndarray, faces: np.ndarray, sign: float):
    """Visible, back-to-front sorted triangles of a mesh seen along -z (sign 1) or +z (sign -1).
    verts (V, 3), faces (F, 3) -> (triangles (K, 3, 2), Lambert shade (K,), face ids (K,))."""
    tri = verts[faces] * np.array([sign, 1.0, sign])
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    shade = 0.35 + 0.65 * np.clip(n @ light, 0, 1)
    ids = np.flatnonzero(n[:, 2] > 0)
    ids = ids[np.argsort(tri[ids, :, 2].mean(1))]
    return tri[ids][:, :, :2], shade[ids], ids


def _filled(polys: np.ndarray, colors: np.ndarray) -> PolyCollection:
    # the edge drawn in the face's own colour closes the anti-aliased hairline gaps between neighbours
    return PolyCollection(polys, facecolors=colors, edgecolors=colors, linewidths=0.4)


def view_limits(points: np.ndarray, pad: float = 0.03) -> tuple[tuple[float, float], tuple[float, float]]:
    """x and y limits (metres) of the front/back views that hold every point (N, 3): x symmetric about 0,
    since the back view mirrors x."""
    (x0, y0), (x1, y1) = points[:, :2].min(0), points[:, :2].max(0)
    half_w = max(abs(float(x0)), abs(float(x1))) + pad
    return (-half_w, half_w), (float(y0) - pad, float(y1) + pad)


def plot_samples(ds: ClothDataset, indices: list[int], path: Path, gap_max_cm: float | None = None) -> Path:
    """Front and back views (x-y projections, depth-sorted faces) of draped samples on their bodies.

    The garment is coloured by each vertex's distance to the nearest body vertex (cm) on one colour scale
    shared by every panel (0..`gap_max_cm`, default the 98th percentile over the shown samples); all panels
    share one frame that holds every point of every sample, raised arms included.
    """
    rot = torch.from_numpy(np.asarray(ds.poses[indices])).float()
    body_v = pose_body(ds.body, rot).numpy()
    bf, gf = ds.body.faces.numpy(), ds.garment.faces.numpy()
    garments = [np.asarray(ds.verts[i]) for i in indices]
    gaps = [cKDTree(b).query(g)[0] * 100.0 for b, g in zip(body_v, garments, strict=True)]
    vmax = float(gap_max_cm) if gap_max_cm else max(float(np.percentile(np.concatenate(gaps), 98)), 1e-3)
    cmap, norm = plt.get_cmap("viridis"), Normalize(0.0, vmax)
    (xlim, ylim) = view_limits(np.concatenate([*body_v, *garments]))
    fig, axes = plt.subplots(2, len(indices), figsize=(3.2 * len(indices), 7.4), squeeze=False,
                             layout="constrained")
    for col, i in enumerate(indices):
        for row, sign in enumerate((1.0, -1.0)):  # front view looks along -z, back view along +z
            ax = axes[row, col]
            polys, shade, _ = _project(body_v[col], bf, sign)
            ax.add_collection(_filled(polys, np.clip(np.array([0.8, 0.7, 0.6])[None] * shade[:, None], 0, 1)))
            polys, shade, ids = _project(garments[col], gf, sign)
            face_gap = gaps[col][gf[ids]].mean(1)
            colors = np.asarray(cmap(norm(face_gap)))[:, :3] * (0.45 + 0.55 * shade[:, None])
            ax.add_collection(_filled(polys, np.clip(colors, 0, 1)))
            ax.set_xlim(*xlim)
            ax.set_ylim(*ylim)
            ax.set_aspect("equal")
            ax.axis("off")
            ax.set_title(f"sample {i} {'front' if row == 0 else 'back'}", fontsize=9)
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=axes.ravel().tolist(), location="bottom",
                 shrink=0.5, aspect=40, extend="max", label="garment to nearest body vertex (cm)")
    return save_figure(fig, path)


def export_objs(ds: ClothDataset, indices: list[int], out: Path) -> list[Path]:
    """The draped garment (with its UVs and normals) and the posed body of each sample as OBJ files."""
    rot = torch.from_numpy(np.asarray(ds.poses[indices])).float()
    body_v = pose_body(ds.body, rot).numpy()
    paths = []
    for col, i in enumerate(indices):
        paths.append(write_garment_mesh(out / f"sample_{i:05d}_garment.obj", ds.garment, np.asarray(ds.verts[i]),
                                        header=[f"draped sample {i} of dataset {Path(ds.dir).name}"]))
        paths.append(write_mesh(out / f"sample_{i:05d}_body.obj", body_v[col], ds.body.faces.numpy()))
    return paths


def write_preview(directory: str | Path, cfg: DictConfig | None = None, n_samples: int = 4) -> list[Path]:
    """All preview figures and meshes of the dataset in `directory`. Returns the written paths."""
    ds = load_dataset(directory)
    out = Path(directory) / "preview"
    out.mkdir(exist_ok=True)
    indices = np.linspace(0, len(ds) - 1, min(n_samples, len(ds))).round().astype(int).tolist()
    paths = [plot_uv_layout(ds, out / "uv_layout.png"), plot_samples(ds, indices, out / "samples.png")]
    angles_path = Path(directory) / "angles.npy"
    if angles_path.is_file():
        plot_angle_histograms(np.load(angles_path), ds.body.skeleton, out / "pose_angles.png")
        paths.append(out / "pose_angles.png")
    paths += export_objs(ds, indices, out)
    if cfg is not None:  # cloth images, crop windows, round-trip error: the pixels stage's figures
        paths += cloth_image_preview(ds, out, cfg.image, space=str(OmegaConf.select(cfg, "model.space") or "local"))
    return paths
