"""Shape as data on Anny end to end: `data.body_shape` drapes a dataset on two people of different height,
writes them (shapes.npz, person.npy), each sample's cloth follows its own person, a smoke training runs on
it and the predictor skins on the base person or on a given one; `pbc predict` puts a split's poses each on its own
person (its vertex error is against them) and `--person K` every pose on person K. About a minute."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.cli import exit_code  # noqa: E402

from pbc.cli.predict import main as predict_main  # noqa: E402
from pbc.core.config import load_config  # noqa: E402
from pbc.data.dataset import load_dataset  # noqa: E402
from pbc.data.generate import generate  # noqa: E402
from pbc.geometry.body.base import pose_body  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402

PEOPLE = ["body=anny_tpose", "data=tshirt_tiny", "garment.size_to_body.enabled=true", "data.num_samples=6",
          "data.body_shape={height:[0.1,0.9]}", "data.body_shapes=2", "data.workers=1"]


def test_a_dataset_of_two_people_drapes_trains_and_predicts(tmp_path, anny_body, capsys):
    overrides = [*PEOPLE, f"paths.data_dir={tmp_path}"]
    cfg = load_config(overrides)
    ds = load_dataset(generate(cfg))
    man, shapes = ds.manifest, ds.shapes
    assert len(shapes) == 2 and man["body_shapes"]["keys"] == list(shapes.keys)
    # the people differ in height (and only there): their rest bodies' heights a few cm apart
    h = shapes.values[:, shapes.keys.index("height")]
    assert ((0.1 <= h) & (h <= 0.9)).all() and abs(h[0] - h[1]) > 0.05
    others = [k for k in shapes.keys if k != "height"]
    assert (shapes.values[0, [shapes.keys.index(k) for k in others]]
            == shapes.values[1, [shapes.keys.index(k) for k in others]]).all()
    tall = np.ptp(shapes.vertices[..., 1].numpy(), axis=1)
    assert abs(tall[0] - tall[1]) > 0.03, tall
    assert np.array_equal(ds.person, np.asarray(man["source_index"]) % 2) and len(set(ds.person)) == 2
    # each drape rests on its own person (heights far apart: with a shirt this loose a few cm of stature move its
    # contact by under a millimetre): its nearest tenth of vertices sit at the contact distance (under a cm)
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

    # pbc predict: a split's poses each on its own person, so the error is against what was simulated there
    out = tmp_path / "pred"
    assert exit_code(predict_main, [str(run), "--poses", "train", "--body", "--sheet", "2", "--out", str(out)]) == 0
    res = json.loads((out / "predict.json").read_text())
    idx = ds.split("train")
    assert res["person"] == ds.person[idx].tolist()
    poses = torch.from_numpy(np.array(ds.poses[idx]))
    own = pred(poses, person=ds.person[idx])
    want = (own - torch.from_numpy(np.array(ds.verts[idx]))).norm(dim=-1).mean(1) * 100
    assert np.allclose(res["per_pose_vertex_error_cm"], want.numpy(), atol=1e-3)
    assert np.allclose(np.load(out / "vertices.npy"), own.numpy(), atol=1e-5)
    # --person K: every pose on person K, the body meshes too (not the base person's); no error against others
    k = int(np.argmax(np.abs(h - float(cfg.body.phenotype.height))))
    np.save(tmp_path / "poses.npy", poses.numpy())
    out_k = tmp_path / "pred_k"
    assert exit_code(predict_main, [str(run), "--poses", str(tmp_path / "poses.npy"), "--person", str(k), "--body",
                                    "--sheet", "0", "--out", str(out_k)]) == 0
    assert np.allclose(np.load(out_k / "vertices.npy"), pred(poses, person=k).numpy(), atol=1e-5)
    body_k = pose_body(ds.person_body(k), poses[:1])[0].numpy()
    name = json.loads((out_k / "predict.json").read_text())["names"][0]
    written = np.array([line.split()[1:4] for line in (out_k / "meshes" / f"{name}_body.obj").read_text().splitlines()
                        if line.startswith("v ")], float)
    assert np.abs(written - body_k).max() < 1e-4
    # a person the dataset does not have: one line, exit 2, nothing written
    capsys.readouterr()
    assert exit_code(predict_main, [str(run), "--poses", "train", "--person", "2", "--out", str(tmp_path / "no")]) == 2
    err = capsys.readouterr().err.strip()
    assert "outside 0..1, the 2 people" in err and len(err.splitlines()) == 1 and not (tmp_path / "no").exists()
