"""docs/results/outfit/outfit.png: the shirt over the trousers on Anny, front view, on a held-out pose of each
starter, each model's own output (before) and composed (after), the whole body and the waist close up.

    .venv/bin/python docs/results/outfit/figure.py

Rendered by pbc.jobs.writers.render_frames as `pbc outfit predict`'s video is (pbc.jobs.outfit.outfit_layers):
every piece lifted over the skin alike, so a piece inside the one under it shows through it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))

from pbc.inference.outfit import OutfitPredictor  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402
from pbc.jobs.outfit import outfit_camera, outfit_layers, split_poses  # noqa: E402
from pbc.jobs.writers import render_frames  # noqa: E402
from pbc.motion.retarget import motion_settings  # noqa: E402

FRAMES = {"tshirt_test_00000": "the shirt's test pose 0", "trousers_test_00002": "the trousers' test pose 2"}
WAIST = (-0.30, 0.22)  # m: the heights of the close-up (the shirt's hem over the trousers' waist)


def main() -> Path:
    outfit = OutfitPredictor({n: ClothPredictor.from_pretrained(n) for n in ("tshirt", "trousers")})
    poses = split_poses(outfit, "test", None)
    rows = [poses.names.index(n) for n in FRAMES]
    result = outfit(poses.body[rows], {n: p[rows] for n, p in poses.pieces.items()})
    video = motion_settings().video
    cam = outfit_camera(outfit, result.vertices, result.bodies, 768)
    x0, y1, s, h, w = cam
    top, bottom = int((y1 - WAIST[1]) / s), int((y1 - WAIST[0]) / s)
    images = {k: render_frames(outfit_layers(outfit, v, result.bodies, list(range(len(rows))), video), cam,
                               list(video.light), list(video.background))
              for k, v in (("before", result.predicted), ("after", result.vertices))}
    fig, axes = plt.subplots(len(rows), 4, figsize=(13, 4.6 * len(rows)),
                             gridspec_kw={"width_ratios": [1, 1, 1.4, 1.4]}, squeeze=False)
    for r, title in enumerate(FRAMES.values()):
        shirt = result.frames[r][1]
        for c, (when, crop) in enumerate((("before", False), ("after", False), ("before", True), ("after", True))):
            img = images[when][r]
            ax = axes[r, c]
            ax.imshow(img[top:bottom] if crop else img)
            ax.axis("off")
            inside = shirt[f"inside_under_{when}"]
            ax.set_title(f"{title}, {'each model alone' if when == 'before' else 'composed'}"
                         f"{' (waist)' if crop else ''}\nshirt vertices inside the trousers: {inside}", fontsize=9)
    fig.suptitle("pbc outfit predict --pretrained tshirt trousers: trousers (inner, blue), shirt (outer, orange)")
    fig.tight_layout()
    out = HERE / "outfit.png"
    fig.savefig(out, dpi=90)
    return out


if __name__ == "__main__":
    print(main())
