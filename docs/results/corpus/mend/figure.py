"""The shipped shirt where it stretches most: on its own test pose with the longest edge, the simulator's drape,
the model's garment as it is, and the garment mended (`ClothPredictor.mend`); then the frame of Bandai Namco's dance
with the longest edge under the guard, as it is and mended: mend.png beside this file.

    python docs/results/corpus/mend/figure.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from PIL import Image

from pbc.geometry.body.base import pose_body
from pbc.geometry.mend import edge_ratios
from pbc.inference.poses import read_motion
from pbc.inference.predictor import ClothPredictor
from pbc.jobs.predict import guard_frames
from pbc.jobs.writers import contact_sheet

HERE = Path(__file__).resolve().parent
CLIP = HERE.parents[4] / "shared" / "corpus" / "motion" / "bandai_dataset-1_dance-short_normal_001.bvh"

pred = ClothPredictor.from_pretrained("tshirt")
ds = pred.dataset
edges, usual = pred.edge_lengths()
settings = pred.mend


def garments(poses: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(as the model gives them, mended) at poses (N, J, 3, 3)."""
    pred.mend = None
    raw = pred(poses, model="whole").numpy()
    pred.mend = settings
    return raw, pred(poses, model="whole").numpy()


def longest(v: np.ndarray) -> np.ndarray:
    return np.array([edge_ratios(x, edges, usual).max() for x in v])


test = np.asarray(ds.split("test"))
poses = torch.from_numpy(np.asarray(ds.poses)[test].astype(np.float32))
raw, mended = garments(poses)
k = int(longest(raw).argmax())
clip, _ = guard_frames(pred, read_motion(CLIP, ds).poses)
clip = torch.from_numpy(clip.astype(np.float32))
clip_raw, _ = garments(clip)
f = int(longest(clip_raw).argmax())
pair = clip[[f]]
pair_raw, pair_mended = garments(pair)
shown = [np.asarray(ds.verts)[test[k]], raw[k], mended[k], pair_raw[0], pair_mended[0]]
r = longest(np.stack(shown))
titles = [f"test pose {test[k]}: simulated ({r[0]:.1f}x)", f"as the model gives it ({r[1]:.1f}x)",
          f"mended ({r[2]:.1f}x)", f"dance frame {f}, guarded ({r[3]:.1f}x)", f"mended ({r[4]:.1f}x)"]
body = pose_body(ds.body, torch.cat([poses[[k]].repeat(3, 1, 1, 1), pair.repeat(2, 1, 1, 1)])).numpy()
out = contact_sheet(HERE / "mend.png", ds.garment.faces.numpy(), np.stack(shown).astype(np.float32), titles, body,
                    ds.body.faces.numpy())
Image.open(out).convert("RGB").quantize(64).save(out)  # a few hundred kB as a 64-colour palette
print(out, "longest edges:", np.round(r, 2).tolist())
