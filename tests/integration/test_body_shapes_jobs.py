"""Shape as data on Anny end to end: `data.body_shape` drapes a dataset on two people of different height,
writes them (shapes.npz, person.npy), each sample's cloth follows its own person, a smoke training runs on
it and the predictor skins on the base person or on a given one. About a minute."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from pbc.config import load_config
from pbc.data.dataset import load_dataset
from pbc.data.generate import generate
from pbc.geometry.body import pose_body
from pbc.predict import ClothPredictor

PEOPLE = ["body=anny_tpose", "data=tshirt_tiny", "garment.fit_to_body.enabled=true", "data.num_samples=6",
          "data.body_shape={height:[0.2,0.8]}", "data.body_shapes=2", "data.workers=1"]


def test_a_dataset_of_two_people_drapes_trains_and_predicts(tmp_path, anny_body):
    overrides = [*PEOPLE, f"paths.data_dir={tmp_path}"]
    cfg = load_config(overrides)
    ds = load_dataset(generate(cfg))
    man, shapes = ds.manifest, ds.shapes
    assert len(shapes) == 2 and man["body_shapes"]["keys"] == list(shapes.keys)
    # the people differ in height (and only there): their rest bodies' heights a few cm apart
    h = shapes.values[:, shapes.keys.index("height")]
    assert ((0.2 <= h) & (h <= 0.8)).all() and abs(h[0] - h[1]) > 0.05
    others = [k for k in shapes.keys if k != "height"]
    assert (shapes.values[0, [shapes.keys.index(k) for k in others]]
            == shapes.values[1, [shapes.keys.index(k) for k in others]]).all()
    tall = np.ptp(shapes.vertices[..., 1].numpy(), axis=1)
    assert abs(tall[0] - tall[1]) > 0.03, tall
    assert np.array_equal(ds.person, np.asarray(man["source_index"]) % 2) and len(set(ds.person)) == 2
    # each drape rests on its own person: its nearest tenth of vertices sit at the contact distance (under a cm)
    # from that person's posed body, further from the other person's
    for i, k in enumerate(ds.person):
        pose, verts = torch.from_numpy(np.array(ds.poses[i:i + 1])), torch.from_numpy(np.array(ds.verts[i]))
        near = [float(torch.cdist(verts, pose_body(ds.person_body(p), pose)[0]).min(1).values.quantile(0.1))
                for p in (0, 1)]
        assert near[k] < near[1 - k], (i, k, near)
    # a smoke training on it (the datamodule's target cache skins each sample on its person)
    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "pbc.train", *overrides, "+experiment=whole", "trainer=smoke",
                        f"hydra.run.dir={run}"], cwd=root, env=dict(os.environ, PBC_ROOT=str(tmp_path)),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["status"] == "ok" and np.isfinite(metrics["train"]["vertex_error_cm"])
    assert metrics["data"]["fingerprint"]["body_shapes"] == man["body_shapes"]
    pred = ClothPredictor.from_runs(run)
    pose = torch.from_numpy(np.array(ds.poses[:1]))
    on_base, on_other = pred(pose), pred(pose, person=int(np.argmax(np.abs(h - float(cfg.body.phenotype.height)))))
    assert torch.isfinite(on_base).all() and (on_base - on_other).norm(dim=-1).max() > 0.01
