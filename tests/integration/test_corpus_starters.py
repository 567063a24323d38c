"""The quick slice of bench/corpus.py on every corpus clip, for each shipped starter (no drape): read, flagged
past the model's data, and never shattered under the default guard.

Shattered: a predicted edge past 3x its usual length (the median over the model's shipped drapes; the simulator's
own drapes of corpus frames stay within 1.6x). The trousers hold that. The shirt stretches a few front-hem edges
between the thighs past it on its own test poses too (docs/results/corpus): for it, no corpus frame may stretch an
edge more than its own test poses do."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pbc.geometry.meshops import edge_stretch, mesh_edges
from pbc.inference.poses import read_motion
from pbc.inference.predictor import ClothPredictor
from pbc.jobs.predict import guard_frames

SHATTER = 3.0


def predicted(pred, poses):
    with torch.inference_mode():
        return pred(torch.from_numpy(np.asarray(poses, np.float32)), model="whole").numpy()


@pytest.mark.parametrize("name", ["trousers", "tshirt"])
def test_no_corpus_frame_shatters_under_the_default_guard(corpus, name):
    pred = ClothPredictor.from_pretrained(name)
    ds = pred.dataset
    edges = mesh_edges(ds.garment.faces.numpy())
    verts = np.asarray(ds.verts)
    usual = np.median(np.linalg.norm(verts[:, edges[:, 0]] - verts[:, edges[:, 1]], axis=-1), 0)
    own = edge_stretch(predicted(pred, ds.poses), edges, usual).max()  # its own test poses
    limit = SHATTER if name == "trousers" else max(SHATTER, own)
    shattered, flagged, frames = [], 0, 0
    for path in sorted((corpus / "motion").rglob("*.bvh")):
        m = read_motion(path, ds, frames="::4")
        poses, report = guard_frames(pred, m.poses)
        assert report["guard"] == "nearest" and report["known"] is not None  # the model carries its poses
        worst = edge_stretch(predicted(pred, poses), edges, usual)
        if (worst > limit).any():
            shattered.append(f"{path.name}: {int((worst > limit).sum())} frames, up to {worst.max():.1f}x")
        flagged += report["known"]["num_flagged"]
        frames += len(poses)
    assert not shattered, f"past {limit:.2f}x:\n" + "\n".join(shattered)
    assert 0 < flagged < frames  # the flags tell frames apart: some, not all
