"""Evaluation, the predictor and patch-run selection, on a stand-in dataset and 29 cheap checkpoints.

The stand-in dataset is the real coarse T-shirt and its cage with a "body" that is the garment shrunk
10% (no draping, seconds to build). The checkpoints are untrained narrow decoders saved in the
checkpoint layout `pbc.train` writes (hparams + `net.*` state dict) with a run dir's metrics.json,
so 28 patch runs cost nothing to make.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.evaluate_world import GARMENT_HASH, IMAGE, N, _stitch_cfg, fake_dataset, save_run
from omegaconf import OmegaConf

import pbc.data.dataset as dsmod

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    ds = fake_dataset(root / "data" / "fake")
    whole = save_run(root / "runs" / "whole", ds.dir, "whole", None)
    for k in range(28):
        save_run(root / "runs" / "patches" / f"{k}_patch_{k:02d}", ds.dir, "patch", k, seed=k)
    return root, ds, whole


@pytest.fixture
def patched_load(world, monkeypatch):
    _, ds, _ = world
    monkeypatch.setattr(dsmod, "load_dataset", lambda d: ds)
    return ds


def test_select_patch_runs_reports_every_problem(world, tmp_path):
    from pbc.core.runs import select_patch_runs

    root, ds, whole = world
    runs = [root / "runs" / "patches" / f"{k}_patch_{k:02d}" for k in range(28)]
    assert [r.patch_id for r in select_patch_runs(runs, GARMENT_HASH, 28)] == list(range(28))
    # a sweep dir holding the whole run and an evaluate output too: only the patch runs are taken
    (root / "runs" / "evaluate").mkdir(exist_ok=True)
    (root / "runs" / "evaluate" / "metrics.json").write_text("{}")
    assert len(select_patch_runs(root / "runs", GARMENT_HASH, 28)) == 28
    dup = save_run(tmp_path / "dup", ds.dir, "patch", 3)
    other = save_run(tmp_path / "other", ds.dir, "patch", 4, garment_hash="another")
    bad_id = save_run(tmp_path / "bad", ds.dir, "patch", 31)
    with pytest.raises(ValueError) as e:
        select_patch_runs(runs[:4] + runs[5:] + [dup, other, bad_id, whole], GARMENT_HASH, 28)
    msg = str(e.value)
    for part in ("patch 3 is claimed by 2 runs", "another", "patch id 31", "not a patch run",
                 "missing patch runs for patch ids [4]"):
        assert part in msg, msg


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_predictor_on_the_gpu_matches_the_cpu(world, patched_load):
    from pbc.inference.predictor import ClothPredictor

    root, ds, whole = world
    cpu = ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("pca"))
    gpu = ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("pca"), device="cuda")
    from pbc.inference.predictor import fit_training_pca

    cpu.stitcher.pca = gpu.stitcher.pca = fit_training_pca(cpu, 16, 64)  # set after construction, as evaluate does
    pose = torch.from_numpy(ds.poses[:3]).float()
    for method in ("average", "pca", "hierarchy"):
        a, b = cpu(pose, method=method), gpu(pose, method=method)
        assert b.is_cuda and torch.allclose(a, b.cpu(), atol=1e-4), method


def test_evaluate_the_whole_model_alone(world, patched_load, tmp_path):
    """patch_runs=null: the whole model against the training mean shape and its image floor, no stitch."""

    from pbc.jobs.evaluate import evaluate

    root, ds, whole = world
    cfg = OmegaConf.create({"whole_run": str(whole), "patch_runs": None, "methods": ["average"], "split": "test",
                            "max_samples": None, "batch_size": 8, "num_previews": 1, "pca_path": None,
                            "pca_fit_max": 100, "stitch": _stitch_cfg("pca")})
    m = evaluate(cfg, tmp_path)
    assert set(m["entries"]) == {"floor_256", "train_mean", "whole"} and m["patch_runs"] is None
    e = m["entries"]
    assert e["floor_256"]["vertex_error_cm"] < e["train_mean"]["vertex_error_cm"]
    assert m["patch_disagreement_before_blend_cm"] is None and m["seam_edges"] > 0  # the cage's seams, scored
    assert json.loads((tmp_path / "metrics.json").read_text())["entries"]["whole"] == e["whole"]
    assert "The whole model" in (tmp_path / "metrics.md").read_text() and (tmp_path / "error_maps.png").is_file()
    cfg.whole_run = None
    with pytest.raises(ValueError, match="nothing to evaluate"):
        evaluate(cfg, tmp_path / "none")


def test_stacked_patch_net_carries_each_mean_image():
    """The stacked 28-model form adds every decoder's own output_mean, as the loop does."""
    from pbc.inference.predictor import LoopPatchNet, StackedPatchNet
    from pbc.models.decoder import ConvDecoder

    torch.manual_seed(0)
    nets = [ConvDecoder(90, 3, (40, 40), (5, 5), 32, first_layer="linear") for _ in range(3)]
    for net in nets:
        net.output_mean.normal_()
        net.output_scale.uniform_(0.5, 2.0)
        net.input_mean.normal_()
        net.input_scale.uniform_(0.5, 2.0)
        net.eval()
    pose = torch.randn(2, 90)
    with torch.inference_mode():
        ref, stacked = LoopPatchNet(nets)(pose), StackedPatchNet(nets)(pose)
    assert torch.allclose(stacked, ref, atol=1e-4)
    for net in nets:
        net.output_mean.zero_()
    with torch.inference_mode():
        assert not torch.allclose(LoopPatchNet(nets)(pose), ref, atol=0.1)  # the means do matter


@pytest.mark.parametrize("batch", [1, 6])  # 6 > bmm_max_batch: the all-grouped path
def test_stacked_patch_net_bfloat16_close_to_float32(batch):
    """The bf16 fast path returns float32 crops within bf16 rounding of the exact loop."""
    from pbc.inference.predictor import LoopPatchNet, StackedPatchNet
    from pbc.models.decoder import ConvDecoder

    torch.manual_seed(1)
    nets = [ConvDecoder(90, 3, (40, 40), (5, 5), 32, first_layer="linear") for _ in range(3)]
    for net in nets:
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.normal_(0, 0.1)
                m.running_var.uniform_(0.5, 2.0)
        net.output_mean.normal_()
        net.output_scale.uniform_(0.5, 2.0)
        net.input_mean.normal_()
        net.input_scale.uniform_(0.5, 2.0)
        net.eval()
    pose = torch.randn(batch, 90)
    with torch.inference_mode():
        ref = LoopPatchNet(nets)(pose)
        fast = StackedPatchNet(nets, dtype=torch.bfloat16)(pose)
    assert fast.dtype == torch.float32 and fast.shape == ref.shape
    err = (fast - ref).abs().max().item()
    spread = (ref - torch.stack([n.output_mean[0] for n in nets])).abs().max().item()  # the net's own part
    assert 0 < err < 0.02 * spread  # rounded (not exact), yet within bf16's ~3 significant digits


def test_predictor_rejects_unknown_precision(tmp_path):
    from pbc.inference.predictor import ClothPredictor

    with pytest.raises(ValueError, match="precision must be one of"):
        ClothPredictor(fake_dataset(tmp_path / "fake"), IMAGE, None, [], OmegaConf.load(
            ROOT / "conf/stitch/average.yaml"), precision="fp16")


@pytest.fixture(scope="module")
def predictor(world):
    """One predictor for the door tests (building one costs seconds)."""
    from pbc.inference.predictor import ClothPredictor

    root, ds, whole = world
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dsmod, "load_dataset", lambda d: ds)
        return ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("average"))


def test_predictor_checks_its_poses_first(world, predictor):
    _, ds, _ = world
    pred = predictor
    pose = np.asarray(ds.poses[:2])
    ref = pred(torch.from_numpy(pose))
    assert torch.allclose(pred(pose), ref, atol=1e-6)  # numpy accepted (was an AttributeError)
    one = pred(pose[0].reshape(-1))  # (J*9,) is one pose: one result
    assert one.shape == ref.shape[1:] and torch.allclose(one, ref[0], atol=1e-5)
    with pytest.raises(ValueError, match=r"that is 9 joints; this model takes 10"):
        pred(pose[:, :9])  # was "mat1 and mat2 shapes cannot be multiplied"
    bad = pose.copy()
    bad[1, 2, 0, 0] = np.inf
    with pytest.raises(ValueError, match=r"NaN or infinite values in batch rows \[1\]"):
        pred(bad)
    scaled = pose.copy()
    scaled[0, 3] *= 2.0  # a scaled matrix used to give a mesh metres away
    name = ds.body.skeleton.names[3]
    with pytest.raises(ValueError, match=rf"pose\[0, 3\] \({name}\) is not a rotation"):
        pred(scaled)
    with pytest.raises(TypeError, match="pass a torch tensor or a numpy array"):
        pred(pose.tolist())


def test_predictor_refuses_a_pca_basis_of_another_dataset(predictor, tmp_path):
    from pbc.inference.predictor import fit_training_pca
    from pbc.stitch.pca import load_pca, save_pca

    pred = predictor
    basis = fit_training_pca(pred, 4, 100)
    assert basis.fingerprint is not None and basis.fingerprint["kept"] == N
    save_pca(basis, tmp_path / "pca.pt")
    again = load_pca(tmp_path / "pca.pt")
    assert again.fingerprint == basis.fingerprint
    pred.use_pca(again)
    assert pred.stitcher.pca is again
    other = type(basis)(basis.mean, basis.components, basis.singular_values, basis.dataset_hash,
                        dict(basis.fingerprint, seed=7, kept=N + 5))
    with pytest.raises(ValueError, match=r"another dataset(.|\n)*kept: recorded 15 vs found 10(.|\n)*seed: recorded 7"):
        pred.use_pca(other)
    assert pred.stitcher.pca is again  # the refused basis was not taken


def test_stacked_patch_net_matches_loop(world, patched_load):
    from pbc.inference.predictor import ClothPredictor, LoopPatchNet

    root, ds, whole = world
    pred = ClothPredictor.from_runs(whole, root / "runs" / "patches", _stitch_cfg("average"))
    pose = torch.from_numpy(ds.poses[:3]).float()
    ref = LoopPatchNet(pred.patch_nets).eval()
    with torch.inference_mode():
        assert torch.allclose(pred.patch_crops(pose), ref(pose.reshape(3, -1)), atol=1e-5)
        x1 = pred(pose[0])
        xb = pred(pose)
    assert x1.shape == (ds.verts.shape[1], 3) and torch.allclose(x1, xb[0], atol=1e-5)
    # untrained heads give mm-size offsets: the garment sits on its skinned cloth pixels
    assert (xb - pred(pose, model="whole")).norm(dim=-1).max() < 0.05


def test_evaluate_writes_all_outputs(world, patched_load, tmp_path):
    from pbc.jobs.evaluate import evaluate

    root, ds, whole = world
    cfg = OmegaConf.create({"whole_run": str(whole), "patch_runs": str(root / "runs" / "patches"),
                            "methods": ["average", "pca", "inpaint", "hierarchy", "hierarchy_detail"], "split": "test",
                            "max_samples": None, "batch_size": 8, "num_previews": 2, "pca_path": None,
                            "pca_fit_max": 100, "stitch": _stitch_cfg("pca")})
    m = evaluate(cfg, tmp_path)
    for f in ("metrics.json", "metrics.md", "error_maps.png", "preview_0.png", "preview_1.png", "pca.pt"):
        assert (tmp_path / f).is_file(), f
    assert len(list((tmp_path / "meshes").glob("*.obj"))) == 6
    e = m["entries"]
    for name in ("whole", "train_mean", "floor_256", "floor_512", "patches_average", "patches_pca", "patches_inpaint",
                 "patches_hierarchy", "gt_crops_average", "gt_crops_inpaint"):
        assert np.isfinite(e[name]["vertex_error_cm"]), name
    # ground-truth crops through every seam method land on the representation floor
    floor = e["floor_512"]["vertex_error_cm"]
    assert e["train_mean"]["vertex_error_cm"] > floor + 0.1  # the no-model baseline is a real error
    for meth in ("average", "pca", "hierarchy", "hierarchy_detail"):
        assert e[f"gt_crops_{meth}"]["vertex_error_cm"] <= floor + 1e-3, meth
    assert e["gt_crops_inpaint"]["vertex_error_cm"] <= floor + 0.05
    assert m["patch_disagreement_before_blend_cm"] > 0
    # a basis from another dataset is refused
    torch.save({**torch.load(tmp_path / "pca.pt"), "dataset_hash": "x"}, tmp_path / "bad_pca.pt")
    cfg.pca_path = str(tmp_path / "bad_pca.pt")
    with pytest.raises(ValueError, match="fitted on dataset"):
        evaluate(cfg, tmp_path / "again")
