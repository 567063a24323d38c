"""docs/figures/starter_walk.png: four frames of the video `pbc predict` makes of the shipped starters on a walk.

    WALK=tests/data/bvh/cmu_mb_02_01_walk.bvh
    pbc predict --pretrained tshirt --poses $WALK --frames 1: --video mp4 --out /tmp/walk_tshirt
    pbc predict --pretrained trousers --poses $WALK --frames 1: --video mp4 --out /tmp/walk_trousers
    python docs/figures/starter_walk.py /tmp/walk_tshirt/motion.mp4 /tmp/walk_trousers/motion.mp4

Each row is one video, four frames spread over the clip, side by side.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image

OUT = Path(__file__).resolve().parent / "starter_walk.png"


def main(videos: list[str], per_row: int = 4) -> Path:
    rows = []
    for v in videos:
        import imageio_ffmpeg  # noqa: PLC0415 - the reader only this figure needs

        gen = imageio_ffmpeg.read_frames(v)
        meta = next(gen)
        w, h = meta["size"]
        frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]
        pick = np.linspace(0, len(frames) - 1, per_row).round().astype(int)
        rows.append(np.concatenate([frames[k] for k in pick], axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    Image.fromarray(np.concatenate(rows, axis=0)).save(OUT, optimize=True)
    return OUT


if __name__ == "__main__":
    print(main(sys.argv[1:]))
