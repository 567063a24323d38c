"""Edit a cloth image to edit the shirt (appendix B, Fig. 2): image-space edits -> a new 3D garment.

One job: take a cloth image (a dataset sample rendered with the garment's operators, or a whole-shirt
model's prediction), change its pixels, and rebuild the garment with the project's sample operator
(`ImageOperators.sample`) and skinning (`Skinner`, `from_offsets`). Edits, all restricted to a region mask:

- shift:    add (du, dv) metres to the tangent channels  -> the shirt slides over the body;
- normal:   add dn metres to the normal channel (inflate > 0, shrink < 0) and/or scale it by (1 + gain);
- feature:  paint a grayscale PNG (white = 1) into the normal channel inside a UV rectangle, times an
            amplitude in metres (a fold, a pocket bulge: the "blue brush" of the appendix).

Region masks are pixel masks `(2, H, W)` in [0, 1] (front, back): a UV rectangle on one side, a painted
PNG, or a patch of the cage (its pixels plus the bilinear taps of its vertices, so every vertex of the
patch reads only edited pixels). A vertex moves by the edit at its 4 bilinear taps: one whose taps all
have mask 1 gets the whole edit, one whose taps all have mask 0 does not move at all.

    python -m pbc.edit data=tshirt_tiny --sample 0 --normal 0.01 --patch 7 --out /tmp/edit
    python -m pbc.edit data=tshirt_tiny --run <whole run dir> --sample 3 --shift-u 0.02 --rect 0 0.2 0.3 0.8 0.6
    python -m pbc.edit data=tshirt_small --sample 0 --feature folds.png --feature-amplitude 0.01 \
        --feature-rect 0 0.3 0.45 0.7 0.75 --gallery --out docs/figures/edit

Writes edited.npy (the edited image, (6, H, W)), before.obj / after.obj (garment OBJ with UVs),
edit.png (images above, meshes below, displacement in the last column) and edit.json (what was done,
the mean / max vertex displacement).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from skimage.io import imread  # noqa: E402
from skimage.transform import resize  # noqa: E402
from skimage.util import img_as_float  # noqa: E402
from torch import Tensor  # noqa: E402

from pbc.core.config import load_config  # noqa: E402
from pbc.core.io import save_figure, save_npy, write_json  # noqa: E402
from pbc.core.runs import read_run, run_image_config  # noqa: E402
from pbc.data.dataset import load_dataset  # noqa: E402
from pbc.geometry.garment.base import save_garment_obj  # noqa: E402
from pbc.inference.predictor import load_decoder  # noqa: E402
from pbc.pixels.reconstruct import images_to_positions  # noqa: E402
from pbc.pixels.target import make_target  # noqa: E402

matplotlib.use("Agg")


CM = 100.0


# EditSpec's numeric fields and the pbc.edit flags that set them (named in its error)
EDIT_FLAGS = {"shift_u": "--shift-u", "shift_v": "--shift-v", "normal": "--normal", "normal_gain": "--normal-gain",
              "feature_amplitude": "--feature-amplitude"}


@dataclass(frozen=True)
class EditSpec:
    """An image edit; every field at its default is the identity. Lengths in metres."""

    shift_u: float = 0.0  # added to du (tangent, along the garment's u)
    shift_v: float = 0.0  # added to dv
    normal: float = 0.0  # added to dn: > 0 inflates, < 0 shrinks
    normal_gain: float = 0.0  # dn *= (1 + gain) inside the mask
    feature: np.ndarray | None = None  # (2, H, W) painted field in [0, 1] (see `place_feature`)
    feature_amplitude: float = 0.0  # metres added to dn where the feature is 1

    def __post_init__(self) -> None:
        # checked here, when the edit is made and before anything is written: a NaN (--normal nan) would
        # otherwise flow through every pixel and vertex into edited.npy and after.obj
        bad = []
        for name, flag in EDIT_FLAGS.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating) \
                    or not np.isfinite(float(v)):
                bad.append(f"{name}={v!r} ({flag})")
        if bad:
            raise ValueError(f"edit values must be finite numbers (metres; normal_gain a factor): got "
                             f"{', '.join(bad)}; pass e.g. --normal 0.01")

    def is_identity(self) -> bool:
        return (self.shift_u == 0 and self.shift_v == 0 and self.normal == 0 and self.normal_gain == 0
                and (self.feature is None or self.feature_amplitude == 0))


# ------------------------------------------------------------------------------------------- masks
def rect_mask(res: int, side: int, uv_rect: tuple[float, float, float, float]) -> Tensor:
    """Pixels whose centre lies in the UV rectangle (u0, v0, u1, v1) of chart `side` -> (2, H, W) float."""
    u0, v0, u1, v1 = (float(x) for x in uv_rect)
    if not (0 <= u0 < u1 <= 1 and 0 <= v0 < v1 <= 1):
        raise ValueError(f"UV rectangle {uv_rect} must be u0 < u1, v0 < v1 inside [0, 1] (u0 v0 u1 v1)")
    if side not in (0, 1):
        raise ValueError(f"side must be 0 (front) or 1 (back), got {side}")
    c = (torch.arange(res) + 0.5) / res
    inside = ((c >= v0) & (c <= v1))[:, None] & ((c >= u0) & (c <= u1))[None, :]
    out = torch.zeros(2, res, res)
    out[side] = inside.float()
    return out


def read_gray_png(path: str | Path) -> np.ndarray:
    """A grayscale (or RGB, averaged) PNG -> (h, w) float64 in [0, 1], white = 1."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no image at {path}: give a grayscale PNG (white = full effect)")
    img = img_as_float(imread(path))
    if img.ndim == 3:
        img = img[..., :3].mean(-1) if img.shape[-1] >= 3 else img[..., 0]
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a 2-D grayscale image, got shape {img.shape}")
    return img


def png_mask(path: str | Path, res: int, side: int | None = None) -> Tensor:
    """A painted mask: a (H, W) PNG applies to chart `side`; a (H, 2W) PNG holds front | back side by side.

    Resized to the image resolution (nearest, so unpainted pixels stay exactly 0) -> (2, H, W) in [0, 1].
    """
    img = read_gray_png(path)
    out = torch.zeros(2, res, res)
    if side is None:
        if img.shape[1] != 2 * img.shape[0]:
            raise ValueError(f"{path}: a mask for both charts is twice as wide as high (front | back); "
                             f"got {img.shape}, or pass --mask-side 0|1 for one chart")
        halves = (img[:, : img.shape[1] // 2], img[:, img.shape[1] // 2:])
        for s, h in enumerate(halves):
            out[s] = torch.from_numpy(resize(h, (res, res), order=0, anti_aliasing=False)).float()
    else:
        out[side] = torch.from_numpy(resize(img, (res, res), order=0, anti_aliasing=False)).float()
    return out.clamp(0, 1)


def patch_mask(ops, patch) -> Tensor:
    """Pixels of a cage patch plus the 4 bilinear taps of each of its vertices -> (2, H, W) float.

    With the taps included every vertex of the patch reads only edited pixels (its whole edit); vertices
    of neighbouring patches that share a tap pixel get part of it.
    """
    res = ops.res
    out = torch.zeros(2 * res * res)
    side = int(patch.side)
    out.view(2, res, res)[side] = torch.from_numpy(ops.patch_pixels(patch)).float()
    taps = np.asarray(ops.arrays["S_pix"])[np.asarray(patch.vertices, np.int64)].reshape(-1)
    out[torch.from_numpy(taps)] = 1.0
    return out.view(2, res, res)


def place_feature(img: np.ndarray, res: int, side: int, uv_rect: tuple[float, float, float, float]) -> np.ndarray:
    """A grayscale feature (h, w) resized (bilinear) into a UV rectangle of chart `side` -> (2, H, W)."""
    m = rect_mask(res, side, uv_rect)[side].numpy().astype(bool)
    rows, cols = np.nonzero(m.any(1))[0], np.nonzero(m.any(0))[0]
    if not len(rows) or not len(cols):
        raise ValueError(f"UV rectangle {uv_rect} covers no pixel at resolution {res}")
    out = np.zeros((2, res, res))
    out[side, rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1] = resize(
        img, (len(rows), len(cols)), order=1, anti_aliasing=True)
    return out


# ------------------------------------------------------------------------------------------- edit
def apply_edit(images: Tensor, mask: Tensor, spec: EditSpec, chart: Tensor | None = None) -> Tensor:
    """Edit cloth images inside a region.

    images (B, 6, H, W) front (du, dv, dn) then back; mask (2, H, W) in [0, 1]; chart (2, H, W) bool:
    where the image is defined (pixels outside stay untouched, e.g. zero) -> (B, 6, H, W), a new tensor.
    """
    B, C, H, W = images.shape
    if C != 6 or tuple(mask.shape) != (2, H, W):
        raise ValueError(f"images must be (B, 6, H, W) and the mask (2, H, W); got {tuple(images.shape)} and "
                         f"{tuple(mask.shape)} (render the mask at the image's resolution)")
    m = mask.to(images)
    if chart is not None:
        m = m * chart.to(images)
    out = images.clone()
    feat = None
    if spec.feature is not None:
        feat = torch.as_tensor(spec.feature).to(images)
        if tuple(feat.shape) != (2, H, W):
            raise ValueError(f"feature must be placed at the image's resolution (2, {H}, {W}), got {tuple(feat.shape)}")
    for s in range(2):
        ms = m[s]
        out[:, 3 * s] += spec.shift_u * ms
        out[:, 3 * s + 1] += spec.shift_v * ms
        dn = images[:, 3 * s + 2]
        add = spec.normal + spec.normal_gain * dn
        if feat is not None:
            add = add + spec.feature_amplitude * feat[s]
        out[:, 3 * s + 2] += add * ms
    return out


def reconstruct(images: Tensor, ops, anchors: Tensor, frames: Tensor, space: str = "local") -> Tensor:
    """Edited images (B, 6, H, W) -> garment positions (B, V, 3): the project's sample + skin + offset."""
    return images_to_positions(images, ops, anchors, frames, space)


# ------------------------------------------------------------------------------------------- sources
@dataclass
class Source:
    """A cloth image and what it needs to become a garment again."""

    image: Tensor  # (1, 6, H, W)
    anchors: Tensor  # (1, V, 3)
    frames: Tensor  # (1, V, 3, 3)
    ops: object  # ImageOperators at the image's resolution
    space: str
    garment: object
    cage: object
    what: str


def source_from_dataset(ds, index: int, image_cfg, run: str | None = None) -> Source:
    """Sample `index` of a dataset: its draped offsets rendered (run=None), or a whole-shirt model's
    prediction for its pose (run = the model's run dir).

    image_cfg: the `image` config node; the image is at its whole_resolution. A run's prediction is read
    under the run's own image config (recorded by pbc.train), `image_cfg` only when the run has none.
    Operators and skinning come from the whole-shirt cloth target (`pbc.pixels.target.make_target`).
    """
    if not 0 <= index < len(ds):
        raise ValueError(f"sample {index} is out of range: the dataset {ds.dir} has {len(ds)} samples")
    pose = torch.from_numpy(np.array(ds.poses[index], np.float32))[None]
    if run is None:
        target = make_target(ds, image_cfg, "whole")
        verts = torch.from_numpy(np.array(ds.verts[index], np.float32))[None]
        t = target.render({"pose": pose, "verts": verts})
        image, anchors, frames = t["image"], t["anchors"], t["frames"]
        what = f"dataset sample {index}"
    else:
        info = read_run(run)
        if info.kind != "whole":
            raise ValueError(f"{run}: a {info.kind.value!r} run; image editing needs a whole-shirt run "
                             "(6-channel image)")
        net, hp = load_decoder(info.checkpoint)
        target = make_target(ds, run_image_config(info, image_cfg), "whole", space=hp.get("space", "local"))
        with torch.inference_mode():
            image = net.eval()(pose.reshape(1, -1)).float()
        if tuple(image.shape[-2:]) != target.image_size:
            raise ValueError(f"{run}: the model predicts {tuple(image.shape[-2:])} images but its image config "
                             f"says {target.image_size}; pass the run's image.whole_resolution as an override")
        image = image * target.ops.image_mask()
        anchors, frames = target.skinner(pose)
        what = f"prediction of {info.path} for the pose of sample {index}"
    return Source(image.contiguous(), anchors, frames, target.ops, target.space, ds.garment, ds.cage, what)


# ------------------------------------------------------------------------------------------- figure
def draw_mesh(ax, verts: np.ndarray, faces: np.ndarray, values: np.ndarray | None = None, vmax: float = 1.0,
              cmap: str = "viridis") -> None:
    """Front view (along -z) of a mesh, shaded by its normal, or coloured by per-vertex `values`."""
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    order = np.argsort(tri[:, :, 2].mean(1))  # painter's algorithm
    shade = 0.3 + 0.7 * np.abs(n[order, 2])
    if values is None:
        colors = plt.cm.gray(shade)
    else:
        colors = plt.get_cmap(cmap)(np.clip(values[faces].mean(1)[order] / max(vmax, 1e-12), 0, 1))
        colors[:, :3] *= (0.5 + 0.5 * shade)[:, None]
    ax.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=colors, linewidths=0))
    ax.set_xlim(verts[:, 0].min() - 0.02, verts[:, 0].max() + 0.02)
    ax.set_ylim(verts[:, 1].min() - 0.02, verts[:, 1].max() + 0.02)
    ax.set_aspect("equal")
    ax.axis("off")


def image_rgb(image: Tensor, chart: Tensor, scale: float) -> np.ndarray:
    """(6, H, W) -> (H, 2W, 3) front | back, offsets mapped to [0, 1] around 0.5 (the paper's colours)."""
    halves = []
    for s in range(2):
        x = image[3 * s:3 * s + 3].detach().cpu().numpy().transpose(1, 2, 0)
        rgb = np.clip(0.5 + x / (2 * scale), 0, 1)
        rgb[~chart[s].numpy()] = 1.0
        halves.append(rgb)
    return np.concatenate(halves, 1)


def edit_figure(path: Path, images: list[Tensor], positions: list[Tensor], titles: list[str], faces: Tensor,
                chart: Tensor) -> Path:
    """Fig. 2 of the appendix: cloth images (top), their garments (middle), one column per image, and the
    displacement from the first column colour-coded in cm (bottom)."""
    n = len(images)
    scale = max(float(images[0].abs().max()), 1e-6)
    fig, axes = plt.subplots(3, n, figsize=(2.9 * n, 7.6), squeeze=False)
    f = faces.cpu().numpy()
    positions = [p.reshape(-1, 3) for p in positions]  # (1, V, 3) or (V, 3)
    base = positions[0].cpu().numpy()
    disp = [np.linalg.norm(p.cpu().numpy() - base, axis=1) * CM for p in positions]
    vmax = max(max(float(d.max()) for d in disp), 1e-6)
    for c in range(n):
        axes[0, c].imshow(image_rgb(images[c][0], chart, scale))
        axes[0, c].set_title(titles[c], fontsize=8)
        axes[0, c].axis("off")
        draw_mesh(axes[1, c], positions[c].cpu().numpy(), f)
        if c:
            draw_mesh(axes[2, c], positions[c].cpu().numpy(), f, disp[c], vmax)
            axes[2, c].set_title(f"moved {disp[c].mean():.2f} cm mean, {disp[c].max():.2f} max", fontsize=7)
        else:
            axes[2, c].axis("off")
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=matplotlib.colors.Normalize(0, vmax))
    fig.colorbar(sm, ax=axes[2].tolist(), shrink=0.7, label="displacement (cm)")
    return save_figure(fig, path, dpi=90)


# ------------------------------------------------------------------------------------------- CLI
def _mask_from_args(args, src: Source) -> Tensor:
    res = src.ops.res
    given = [x for x in (args.patch, args.mask, args.rect) if x is not None]
    if len(given) > 1:
        raise ValueError("give one region: --patch ID, --mask PNG or --rect SIDE U0 V0 U1 V1")
    if args.patch is not None:
        if not 0 <= args.patch < len(src.cage.patches):
            raise ValueError(f"--patch {args.patch}: the cage has patches 0..{len(src.cage.patches) - 1}")
        return patch_mask(src.ops, src.cage.patches[args.patch])
    if args.mask is not None:
        return png_mask(args.mask, res, args.mask_side)
    if args.rect is not None:
        return rect_mask(res, int(args.rect[0]), tuple(args.rect[1:]))
    return torch.ones(2, res, res)


def run_edit(args) -> dict:
    # the numbers first (EditSpec checks them), before the dataset is opened or anything written
    EditSpec(args.shift_u, args.shift_v, args.normal, args.normal_gain, None, args.feature_amplitude)
    cfg = load_config(args.overrides + ([f"image.whole_resolution={args.resolution}"] if args.resolution else []))
    ds = load_dataset(args.data_dir or cfg.data.dir)
    src = source_from_dataset(ds, args.sample, cfg.image, run=args.run)
    res = src.ops.res
    mask = _mask_from_args(args, src)
    feature = None
    if args.feature is not None:
        if args.feature_rect is None:
            raise ValueError("--feature needs --feature-rect SIDE U0 V0 U1 V1 (where to paint it)")
        feature = place_feature(read_gray_png(args.feature), res, int(args.feature_rect[0]),
                                tuple(args.feature_rect[1:]))
    spec = EditSpec(args.shift_u, args.shift_v, args.normal, args.normal_gain, feature, args.feature_amplitude)
    out = Path(args.out)
    chart = src.ops.mask
    edited = apply_edit(src.image, mask, spec, chart)
    before = reconstruct(src.image, src.ops, src.anchors, src.frames, src.space)
    after = reconstruct(edited, src.ops, src.anchors, src.frames, src.space)
    out.mkdir(parents=True, exist_ok=True)
    save_npy(out / "edited.npy", edited[0].numpy())
    save_garment_obj(replace(src.garment, vertices=before[0]), out / "before.obj")
    save_garment_obj(replace(src.garment, vertices=after[0]), out / "after.obj")
    disp = (after - before).norm(dim=-1)[0] * CM
    images, positions, titles = [src.image, edited], [before, after], ["input", "edited"]
    if args.gallery:
        # the appendix's Fig. 2 row: each kind of edit on its own, with the magnitudes given (or 1-2 cm)
        s = args.shift_u or args.shift_v or 0.02
        dn = args.normal or 0.01
        demo = [("shift u", EditSpec(shift_u=s)), ("shift v", EditSpec(shift_v=s)),
                (f"inflate {dn * CM:+.1f} cm", EditSpec(normal=abs(dn))),
                (f"shrink {-abs(dn) * CM:+.1f} cm", EditSpec(normal=-abs(dn)))]
        if feature is not None:
            demo.append(("painted feature", EditSpec(feature=feature, feature_amplitude=args.feature_amplitude)))
        images, positions, titles = [src.image], [before], ["input"]
        for name, sp_ in demo:
            img = apply_edit(src.image, mask, sp_, chart)
            images.append(img)
            positions.append(reconstruct(img, src.ops, src.anchors, src.frames, src.space))
            titles.append(name)
    edit_figure(out / "edit.png", images, positions, titles, src.garment.faces, chart)
    record = {
        "source": src.what, "resolution": res, "space": src.space,
        "edit": {"shift_u": spec.shift_u, "shift_v": spec.shift_v, "normal": spec.normal,
                 "normal_gain": spec.normal_gain, "feature": args.feature, "feature_rect": args.feature_rect,
                 "feature_amplitude": spec.feature_amplitude},
        "region": {"patch": args.patch, "mask": args.mask, "rect": args.rect},
        "masked_pixels": int((mask * chart).gt(0).sum()),
        "vertices_moved": int((disp > 1e-6).sum()), "num_vertices": int(disp.numel()),
        "displacement_cm": {"mean": float(disp.mean()), "max": float(disp.max())},
    }
    write_json(out / "edit.json", record)
    return record
