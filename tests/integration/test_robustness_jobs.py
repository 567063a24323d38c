"""The wrong-body study (pbc.geometry.sculpt, pbc.robustness): the sculpted bodies, the painted weights and
the whole chain at scale=smoke (one model per body, report, Figs. 9-10) on a stand-in dataset made in
seconds: the coarse body and shirt, the shirt embedded at its closest body points, smooth offsets."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
N = 12


def stand_in_dataset(d: Path, body) -> Path:
    """A dataset dir (the real file layout) of the coarse shirt on `body`: N poses, smooth offsets."""
    from pbc.data.dataset import save_embedding
    from pbc.geometry.body import save_body
    from pbc.geometry.cage import save_cage
    from pbc.geometry.garment import load_garment_config, make_tshirt, save_garment_obj
    from pbc.geometry.shrinkwrap import embed_points
    from pbc.pixels.reconstruct import Skinner

    garment, cage = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt_coarse.yaml"))
    V, J = garment.vertices.shape[0], len(body.skeleton.names)
    emb = embed_points(garment.vertices.numpy(), body, np.zeros(V, np.int64), 16)
    rng = np.random.default_rng(0)
    angles = rng.uniform(-0.4, 0.4, (N, J))
    c, s = np.cos(angles), np.sin(angles)
    poses = np.zeros((N, J, 3, 3), np.float32)
    poses[..., 0, 0], poses[..., 0, 2], poses[..., 2, 0], poses[..., 2, 2], poses[..., 1, 1] = c, s, -s, c, 1
    anchors, frames = Skinner(body, garment, emb)(torch.from_numpy(poses))
    rest = garment.vertices
    field = torch.einsum("nk,vk->nv", torch.from_numpy(angles[:, :6]).float(), torch.cat([rest, rest ** 2], 1))
    local = torch.stack([0.01 * field, -0.005 * field, 0.015 + 0.01 * field.tanh()], -1)
    verts = anchors + torch.einsum("nvij,nvi->nvj", frames, local)
    d.mkdir(parents=True, exist_ok=True)
    np.save(d / "poses.npy", poses)
    np.save(d / "verts.npy", verts.numpy().astype(np.float32))
    save_garment_obj(garment, d / "garment.obj")
    save_cage(cage, d / "cage.json", V)
    save_body(body, d / "body.npz")
    save_embedding(emb, d / "embedding.npz")
    manifest = {"format_version": 1, "garment_hash": "standin", "body_hash": "true", "counts": {"kept": N},
                "splits": {"train": list(range(8)), "val": [8, 9], "test": [10, 11]}}
    (d / "manifest.json").write_text(json.dumps(manifest))
    return d


def settings():
    from pbc.robustness import load_settings

    return load_settings()






def test_study_at_smoke_scale(body, tmp_path):
    """Bodies, one training per trial and the report, in-process on the stand-in data (a few trials)."""
    from pbc.robustness import main

    data = stand_in_dataset(tmp_path / "data" / "standin", body)
    sweep = tmp_path / "sweep"
    trials = ["shape_0.0", "shape_2.0"]  # the artifact bodies go through the same code (test above)
    # a narrow decoder and one epoch: this tests the chain, the numbers come from `scale=smoke|cpu` runs
    rc = main(["scale=smoke", f"data.dir={data}", f"paths.data_dir={tmp_path / 'data'}", "logger=csv",
               "model.net.start_channels=32", "trainer.max_epochs=1", "--dir", str(sweep),
               "--trials", ",".join(trials)])
    assert rc == 0
    res = json.loads((sweep / "robustness.json").read_text())
    rows = {r["trial"]: r for r in res["rows"]}
    assert set(rows) == set(trials)
    for r in rows.values():
        assert r["status"] == "ok" and np.isfinite(r["test_cm"]) and np.isfinite(r["train_cm"])
    # the cloth is the same in every trial, only body.npz differs
    for name in trials:
        assert (sweep / "bodies" / name / "verts.npy").resolve() == (data / "verts.npy").resolve()
    assert rows["shape_2.0"]["max_vertex_move_cm"] > 7.0 and rows["shape_0.0"]["max_vertex_move_cm"] == 0.0
    v = res["verdict"]
    assert v["trials_done"] == 2 and v["holds"] in (True, False)
    assert abs(v["ratios"]["shape_0.0"] - 1.0) < 1e-9
    # the too-thick body pokes through the simulated cloth: its offsets have dn < 0 somewhere
    pen = res["penetration"]["shape_2.0"]
    assert pen["ground_truth"]["fraction"] > 0.0
    assert (sweep / "fig9_error_vs_shape.png").stat().st_size > 0
    assert (sweep / "fig10_wrong_body.png").stat().st_size > 0
    md = (sweep / "robustness.md").read_text()
    assert "Verdict" in md and "shape_2.0" in md
