"""`python -m pbc.predict` and ClothPredictor.from_runs on a synthetic run: a stand-in dataset (the real file
layout, no drape) and a small whole-shirt decoder saved as a pbc.train checkpoint would be (seconds)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from helpers.cli import exit_code
from omegaconf import OmegaConf
from test_robustness import stand_in_dataset

from pbc import cli
from pbc.cli.predict import main
from pbc.core.runs import RunRecord, monitor
from pbc.inference.predictor import ClothPredictor, load_decoder, stitch_config

ROOT = Path(__file__).resolve().parents[2]
IMAGE = {"whole_resolution": 32, "patch_resolution": 64, "reference_resolution": 512, "crop_size": 160,
         "margin": 16, "pad": 8, "exact_sample": True, "method": "sparse"}


def _net(out_channels, size, start, first, channels, reads=None):
    joints = {} if reads is None else {"input_joints": list(reads), "num_joints": 10}
    return {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 9 * len(reads or range(10)),
            "out_channels": out_channels, "output_size": [size, size], "start_size": [start, start],
            "start_channels": channels, "first_layer": first, **joints}


def fake_run(d: Path, data_dir: Path, kind: str = "whole", patch_id: int | None = None, seed: int = 0,
             space: str = "local", reads=None) -> Path:
    """A finished training run dir: metrics.json (identity, config) and checkpoints/epoch_000.ckpt; its net
    reads the joints `reads` (None: all)."""
    from hydra.utils import instantiate

    torch.manual_seed(seed)
    net_cfg = (_net(6, 32, 8, "conv_transpose", 16, reads) if kind == "whole"
               else _net(3, 20, 5, "linear", 16, reads))
    net = instantiate(net_cfg)
    with torch.no_grad():  # small non-zero outputs: the prediction is the skinned rest plus a few mm
        net.output_scale.fill_(1e-3)
    identity = {"garment_hash": "standin", "kind": kind, "patch_id": patch_id, "space": space}
    ck = d / "checkpoints" / "epoch_000.ckpt"
    ck.parent.mkdir(parents=True)
    torch.save({"hyper_parameters": {"net": net_cfg, "identity": identity, "space": space, "kind": kind},
                "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ck)
    cfg = {"data": {"dir": str(data_dir)}, "image": IMAGE, "model": {"kind": kind, "patch_id": patch_id}}
    RunRecord(kind=kind, optimized_metric=monitor(kind), identity=identity, config=cfg,
              best_checkpoint=str(ck)).write(d)
    return d


@pytest.fixture(scope="module")
def setup(tmp_path_factory, body):
    root = tmp_path_factory.mktemp("predict")
    data = stand_in_dataset(root / "data", body)
    return data, fake_run(root / "whole", data)


def test_whole_model_alone_is_a_predictor(setup):
    data, whole = setup
    for patches in (None, []):
        pred = ClothPredictor.from_runs(whole, patches)
        assert pred.patch_net is None and pred.stitcher is None and pred.method == "whole"
    pose = torch.from_numpy(np.load(data / "poses.npy")[:3]).float()
    x = pred(pose)  # model defaults to the whole model when there are no patch models
    assert x.shape == (3, pred.dataset.garment.num_vertices, 3) and torch.isfinite(x).all()
    assert torch.equal(x, pred(pose, model="whole")) and pred(pose[0]).shape == x.shape[1:]
    # the same as the decoder's own image sampled and turned back by hand
    net, _ = load_decoder(whole / "checkpoints" / "epoch_000.ckpt")
    with torch.no_grad():
        off = pred.whole_target.values(net(pose.reshape(3, -1)))
    anchors, frames = pred.skinner(pose)
    from pbc.pixels.frames import from_offsets

    torch.testing.assert_close(x, from_offsets(off, anchors, frames, "local"))
    with pytest.raises(ValueError, match="no patch models"):
        pred(pose, model="patches")
    with pytest.raises(ValueError, match="needs a whole-shirt run"):
        ClothPredictor.from_runs(None, None)


def test_a_joint_the_data_kept_at_rest_and_no_model_reads_never_moves_the_garment(body, tmp_path):
    """A shirt learnt with the legs at rest, on a walk: its garment is skinned with the legs at rest, so the
    hem follows the trunk and not the thighs; a joint the data moved, or the model reads, moves it as posed."""
    data = stand_in_dataset(tmp_path / "data", body)
    pred = ClothPredictor.from_runs(fake_run(tmp_path / "all", data))
    names = list(body.skeleton.names)
    weights = body.weights.numpy()[body.faces.numpy()[pred.dataset.embedding.face]].sum((0, 1))[1:]
    joint = int(np.argmax(weights))  # the joint the garment's body triangles follow most
    poses = np.load(data / "poses.npy")
    turned = torch.tensor(poses[:2])
    assert pred.held_joints() == []  # every joint moves in its data, and its model reads every joint
    poses[:, joint] = np.eye(3)
    np.save(data / "poses.npy", poses)
    reads = [j for j in range(len(names)) if j != joint]
    pred = ClothPredictor.from_runs(fake_run(tmp_path / "some", data, reads=reads))
    assert pred.held_joints() == [joint], names[joint]
    at_rest = turned.clone()
    at_rest[:, joint] = torch.eye(3)
    torch.testing.assert_close(pred(turned), pred(at_rest), rtol=0, atol=0)
    pred.hold_unread = False  # skinned through every joint as posed: the garment follows the joint
    assert (pred(turned) - pred(at_rest)).abs().max() > 1e-3
    pred = ClothPredictor.from_runs(fake_run(tmp_path / "reads", data))
    assert pred.held_joints() == []  # the model reads it: it moves the garment
    assert (pred(turned) - pred(at_rest)).abs().max() > 1e-3


def test_cli_writes_meshes_sheet_and_metrics(setup, tmp_path, capsys):
    data, whole = setup
    out = tmp_path / "out"
    assert exit_code(main, [str(whole), "--poses", "test", "--out", str(out), "--body"]) == 0
    res = json.loads((out / "predict.json").read_text())
    test_ids = json.loads((data / "manifest.json").read_text())["splits"]["test"]
    assert res["names"] == [f"test_{i:05d}" for i in test_ids] and res["model"] == "whole"
    verts = np.load(out / "vertices.npy")
    V = res["num_vertices"]
    assert verts.shape == (len(test_ids), V, 3) and np.load(out / "poses.npy").shape == (len(test_ids), 10, 3, 3)
    # the error against the split's simulated cloth, recomputed from the files
    gt = np.load(data / "verts.npy")[test_ids]
    assert res["vertex_error_cm"] == pytest.approx(float(np.linalg.norm(verts - gt, axis=-1).mean() * 100), rel=1e-5)
    for name in res["names"]:
        g = trimesh.load(out / "meshes" / f"{name}.obj", process=False, maintain_order=True)
        assert g.vertices.shape == (V, 3) and g.visual.uv.shape == (V, 2)
        np.testing.assert_allclose(g.vertices, verts[res["names"].index(name)], atol=1e-5)
        b = trimesh.load(out / "meshes" / f"{name}_body.obj", process=False)
        assert len(b.vertices) > 100 and len(b.faces) > 100
    text = (out / "meshes" / f"{res['names'][0]}.obj").read_text()
    assert text.count("\nvt ") > V and text.count("\nvn ") == V  # the garment's UV corners and normals
    assert (out / "contact_sheet.png").stat().st_size > 5000
    assert str(out) in capsys.readouterr().out


def test_cli_pose_file_ply_and_bad_input(setup, tmp_path, capsys):
    data, whole = setup
    poses = np.load(data / "poses.npy")[:5]
    np.save(tmp_path / "flat.npy", poses.reshape(5, 90))  # (N, 90) rows accepted as (N, 10, 3, 3)
    out = tmp_path / "ply"
    assert exit_code(main, [str(whole), "--poses", str(tmp_path / "flat.npy"), "--out", str(out), "--format", "ply",
                 "--sheet", "0", "--batch-size", "2", "--body"]) == 0
    res = json.loads((out / "predict.json").read_text())
    assert res["names"] == [f"pose_{k:05d}" for k in range(5)] and not (out / "contact_sheet.png").exists()
    m = trimesh.load(out / "meshes" / "pose_00003.ply", process=False)
    np.testing.assert_allclose(m.vertices, np.load(out / "vertices.npy")[3], atol=1e-6)
    body = out / "meshes" / "pose_00003_body.ply"  # the body in the asked format too
    assert body.read_bytes().startswith(b"ply") and len(trimesh.load(body, process=False).faces) > 0
    # one clear error, exit status 2, nothing written: wrong shape, non-rotations, unknown split, no file
    np.save(tmp_path / "shape.npy", np.zeros((5, 9, 3, 3), np.float32))
    scaled = poses * 2
    np.save(tmp_path / "scaled.npy", scaled)
    for bad, msg in ((tmp_path / "shape.npy", "(N|B), 90"), (tmp_path / "scaled.npy", "rotation"),
                     ("tset", "neither an .npy file nor a split"), (tmp_path / "missing.npy", "does not exist")):
        capsys.readouterr()
        assert exit_code(main, [str(whole), "--poses", str(bad), "--out", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("pbc predict: error:") and len(err.strip().splitlines()) == 1, err
        assert re.search(msg, err), err
        assert not (tmp_path / "bad" / "predict.json").exists()


def test_dispatcher_runs_predict(setup, tmp_path):
    _, whole = setup
    with pytest.raises(SystemExit) as e:
        cli.main(["predict", str(whole), "--poses", "val", "--out", str(tmp_path / "o"), "--sheet", "0"])
    assert e.value.code == 0 and (tmp_path / "o" / "predict.json").is_file()


def test_stitch_config_follows_defaults():
    cfg = stitch_config("pca")  # conf/stitch/pca.yaml inherits average.yaml's keys
    assert cfg.method == "pca" and OmegaConf.select(cfg, "feather_ramp") is not None
    with pytest.raises(ValueError, match="unknown seam method"):
        stitch_config("glue")


@pytest.fixture(scope="module")
def patch_sweep(setup):
    data, whole = setup
    sweep = whole.parent / "patches"
    for k in range(28):
        fake_run(sweep / f"{k}_experiment=patch_{k:02d}", data, "patch", k, seed=k + 1)
    return sweep


def test_cli_with_patch_models_and_a_seam_method(setup, patch_sweep, tmp_path):
    data, whole = setup
    out = tmp_path / "pca"
    assert exit_code(main, [str(whole), "--patches", str(patch_sweep), "--method", "pca", "--poses", "test",
                 "--out", str(out), "--sheet", "2"]) == 0
    res = json.loads((out / "predict.json").read_text())
    assert res["model"] == "patches" and res["method"] == "pca"
    # the files hold what the predictor answers for these poses: the stitched patches, not the whole model
    from pbc.inference.predictor import fit_training_pca

    pred = ClothPredictor.from_runs(whole, patch_sweep, stitch_config("pca"))
    pred.stitcher.pca = fit_training_pca(pred, 128, 4096)
    poses = torch.from_numpy(np.load(out / "poses.npy"))
    np.testing.assert_allclose(np.load(out / "vertices.npy"), pred(poses).numpy(), atol=1e-5)
    assert not torch.allclose(pred(poses), pred(poses, model="whole"))


@pytest.mark.parametrize("method", ["average", "pca", "cage"])
def test_stitch_config_equals_hydras(method):
    from pbc.core.config import load_config

    assert stitch_config(method) == load_config([f"stitch={method}"], config_name="evaluate").stitch


def test_dataset_preview_meshes_carry_uvs_and_normals(setup, tmp_path):
    """The previews' draped-sample OBJs go through the same writer as predictions (pbc.geometry.meshio)."""
    from pbc.data.dataset import load_dataset
    from pbc.data.preview import export_objs

    ds = load_dataset(setup[0])
    garment_obj, body_obj = export_objs(ds, [2], tmp_path)
    g = trimesh.load(garment_obj, process=False, maintain_order=True)
    np.testing.assert_allclose(g.vertices, np.asarray(ds.verts[2]), atol=1e-6)
    text = garment_obj.read_text()
    assert text.count("\nvt ") == len(ds.garment.uv) and text.count("\nvn ") == ds.garment.num_vertices
    assert "f " in text and all(len(c.split("/")) == 3 for c in text.split("\nf ", 1)[1].split()[:3])
    assert trimesh.load(body_obj, process=False).vertices.shape == tuple(ds.body.vertices.shape)


def test_dataset_cloth_image_preview_shows_the_served_image(setup, tmp_path):
    """`python -m pbc.data.preview`: the whole model's target as training serves it, per chart side."""
    from PIL import Image

    from pbc.data.dataset import load_dataset
    from pbc.pixels.preview import preview

    ds = load_dataset(setup[0])
    paths = preview(ds, tmp_path / "both", IMAGE, samples=2)
    assert [p.name for p in paths] == ["cloth_images.png", "crop_windows.png", "round_trip_error.png"]
    assert Image.open(paths[0]).size[1] > Image.open(paths[0]).size[0]  # 2 samples x front/back rows
    # the shirt has charts on both sides: a front-only image would lose the back's vertices
    with pytest.raises(ValueError, match="vertices sample outside it .* add the side to image.whole_sides"):
        preview(ds, tmp_path / "one", dict(IMAGE, whole_sides=[0], whole_rows=[0.0, 1.0]), samples=2)
