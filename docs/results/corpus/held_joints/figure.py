"""The shipped shirt on a Bandai Namco walk, three frames, skinned through every joint as the clip poses them
against held to the joints it learnt (`ClothPredictor.held_joints`): held_vs_unheld.png beside this file.

    python docs/results/corpus/held_joints/figure.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from PIL import Image

from pbc.geometry.body.base import pose_body
from pbc.inference.poses import read_motion
from pbc.inference.predictor import ClothPredictor
from pbc.jobs.writers import contact_sheet

HERE = Path(__file__).resolve().parent
CLIP = HERE.parents[4] / "shared" / "corpus" / "motion" / "bandai_dataset-2_walk_feminine_001.bvh"
FRAMES = [60, 120, 180]

pred = ClothPredictor.from_pretrained("tshirt")
poses = torch.from_numpy(np.asarray(read_motion(CLIP, pred.dataset).poses)[FRAMES]).float()
held = pred(poses, model="whole")
pred.hold_unread = False
every = pred(poses, model="whole")
body = pose_body(pred.dataset.body, poses).numpy()
titles = [f"frame {f}, every joint skinned" for f in FRAMES] + [f"frame {f}, legs held at rest" for f in FRAMES]
out = contact_sheet(HERE / "held_vs_unheld.png", pred.dataset.garment.faces.numpy(), torch.cat([every, held]).numpy(),
                    titles, np.concatenate([body, body]), pred.dataset.body.faces.numpy())
Image.open(out).convert("RGB").quantize(64).save(out)  # a few hundred kB as a 64-colour palette
print(out)
