"""All patch models in one job (pbc.models.stacked, PatchesTarget) on a synthetic two-chart garment with
three patches and tiny decoders: the shared render equals each patch's own, one optimiser step of the
stacked job equals the single-patch steps, and the export loads as single-patch runs."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers.synthetic import FakeSkinner, batch_for, two_chart_garment

from pbc.core.runs import ModelKind, RunRecord, find_runs, monitor, select_patch_runs
from pbc.models.module import ClothModule
from pbc.models.stacked import StackedDecoder, StackedPatchModule, export_patch_runs
from pbc.pixels.target import PatchesTarget, PatchTarget, make_target

IMAGE = {"whole_resolution": 32, "patch_resolution": 64, "reference_resolution": 512, "crop_size": 256,
         "margin": 16, "pad": 16, "exact_sample": True, "method": "sparse"}
NET = {"in_features": 90, "out_channels": 3, "output_size": [32, 32], "start_size": [4, 4],
       "start_channels": 16, "first_layer": "linear"}
LOSS = {"norm": "l1", "normal_weight": 0.01, "edge_weight": 0.1}


@pytest.fixture
def world(tmp_path):
    g = two_chart_garment(8)

    def block(rows, cols, side):
        return np.array([64 * side + 8 * i + j for i in rows for j in cols])

    # a front corner, the same corner on the back, and a front centre block (boxes in 512 px)
    patches = [SimpleNamespace(id=0, side=0, box_512=(51, 51, 170, 170), vertices=block(range(3), range(3), 0)),
               SimpleNamespace(id=1, side=1, box_512=(51, 51, 170, 170), vertices=block(range(3), range(3), 1)),
               SimpleNamespace(id=2, side=0, box_512=(227, 227, 285, 285), vertices=block(range(3, 5), range(3, 5), 0))]
    ds = SimpleNamespace(garment=g, cage=SimpleNamespace(patches=patches), dir=tmp_path / "data",
                         manifest={"garment_hash": "h"}, verts=np.zeros((1, len(g.vertices), 3), np.float32))
    return ds, FakeSkinner(g.vertices)


def test_patches_target_renders_once_and_cuts_every_crop(world):
    ds, sk = world
    allp = make_target(ds, IMAGE, "patches", skinner=sk)
    assert isinstance(allp, PatchesTarget) and allp.num_patches == 3 and allp.image_size == (32, 32)
    batch = batch_for(ds.garment, b=2)
    out = allp.render(batch)
    assert out["image"].shape == (2, 9, 32, 32) and out["mask"].shape == (1, 9, 32, 32)
    for p in range(3):
        single = make_target(ds, IMAGE, "patch", patch_id=p, skinner=sk)
        ref = single.render(batch)
        assert torch.allclose(out["image"][:, 3 * p:3 * p + 3], ref["image"], atol=1e-7), p
        assert torch.equal(out["mask"][:, 3 * p:3 * p + 3], ref["mask"]), p
        assert allp.patch_identity(ds, p) == single.identity(ds)
    ident = allp.identity(ds)
    assert ident["kind"] == "patches" and ident["num_patches"] == 3 and ident["crop_size"] == 32
    # the ground-truth crops map back to the draped garment
    assert torch.allclose(allp.positions(out["image"], out), batch["verts"], atol=1e-5)


def test_stacked_decoder_equals_its_decoders_in_train_and_eval():
    torch.manual_seed(0)
    net = StackedDecoder(3, **NET)
    with torch.no_grad():
        net.input_mean.normal_()
        net.input_scale.uniform_(0.5, 2)
        net.output_mean.normal_(std=0.01)
        net.output_scale.uniform_(0.5, 2)
    singles = [net.decoder(p) for p in range(3)]
    pose = torch.randn(4, 90)
    for mode in (True, False):
        net.train(mode)
        ref = torch.cat([d.train(mode)(pose) for d in singles], 1)
        assert torch.allclose(net(pose), ref, atol=1e-5), mode
    # round trip: stacking the decoders back gives the same network
    again = StackedDecoder.from_decoders(singles)
    for (k, a), b in zip(again.state_dict().items(), net.state_dict().values(), strict=True):
        assert torch.allclose(a.float(), b.float(), atol=1e-6), k
    with pytest.raises(ValueError, match="first_layer must be 'linear'"):
        StackedDecoder(3, **dict(NET, first_layer="conv_transpose"))


def _modules(world):
    ds, sk = world
    torch.manual_seed(0)
    allp = make_target(ds, IMAGE, "patches", skinner=sk)
    stacked = StackedPatchModule({"_target_": "pbc.models.stacked.StackedDecoder", "num_patches": 3, **NET},
                                 "patches", "local", LOSS, 1e-3, allp.identity(ds)).attach(allp)
    with torch.no_grad():
        stacked.net.input_mean.normal_()
        stacked.net.input_scale.uniform_(0.5, 2)
        stacked.net.output_scale.uniform_(0.5, 2)
    singles = []
    for p in range(3):
        sub = make_target(ds, IMAGE, "patch", patch_id=p, skinner=sk)
        m = ClothModule({"_target_": "pbc.models.decoder.ConvDecoder", **NET}, "patch", "local", LOSS, 1e-3,
                        sub.identity(ds), patch_id=p).attach(sub)
        m.net.load_state_dict(stacked.net.patch_state(p))
        singles.append(m)
    return stacked, singles


def test_one_step_of_the_stacked_job_equals_the_single_patch_steps(world):
    ds, _ = world
    stacked, singles = _modules(world)
    batch = batch_for(ds.garment, b=4)
    # the stacked job's mean-image fit equals each single run's
    stacked.fit_output_mean([batch])
    for m in singles:
        m.fit_output_mean([batch])
    for p, m in enumerate(singles):
        assert torch.allclose(stacked.net.patch_state(p)["output_mean"], m.net.output_mean, atol=1e-7)
        assert torch.allclose(stacked.net.patch_state(p)["output_scale"], m.net.output_scale, rtol=1e-5)

    opts = [m.configure_optimizers() for m in [stacked, *singles]]
    for m in [stacked, *singles]:
        m.train()
    loss, _ = stacked.step(batch, "train", 0)
    single_losses = [m.step(batch, "train", 0)[0] for m in singles]
    assert loss.item() == pytest.approx(sum(v.item() for v in single_losses), rel=1e-5)
    for v, opt in zip([loss, *single_losses], opts, strict=True):
        opt.zero_grad()
        v.backward()
    net = stacked.net
    # a transpose conv's bias feeding BatchNorm has gradient exactly 0 in exact arithmetic (BN subtracts
    # the batch mean): both jobs see rounding noise there, which Adam's first step scales to +-lr
    noise = {f"groups.{i}.bias" for i, mod in enumerate(net.groups) if isinstance(mod, torch.nn.ConvTranspose2d)}
    for p, m in enumerate(singles):
        mine = m.net.state_dict(keep_vars=True)
        for t, key, dim, size in net._slices():
            if t.grad is not None:
                g = net._block(t.grad, p, dim, size)
                assert torch.allclose(g, mine[key].grad, rtol=1e-4, atol=1e-8), (p, key)
                if key in noise:
                    assert g.abs().max() < 1e-6 and mine[key].grad.abs().max() < 1e-6, (p, key)
    before = [net.patch_state(p) for p in range(3)]
    for opt in opts:
        opt.step()
    for p, m in enumerate(singles):
        after = net.patch_state(p)
        for key, v in m.net.state_dict().items():
            if key in noise:
                assert (after[key] - before[p][key]).abs().max() <= 1.001e-3 >= (v - before[p][key]).abs().max()
            else:
                assert torch.allclose(after[key].float(), v.float(), rtol=1e-5, atol=1e-6), (p, key)
        assert not torch.equal(after["head.weight"], before[p]["head.weight"])  # the step did move them
    # validation: the mean of the per-patch errors is what the checkpoint monitor sees
    stacked.eval()
    for m in singles:
        m.eval()
    with torch.no_grad():
        _, out = stacked.step(batch, "val", 0)
    assert out["pred"].shape == (4, 9, 32, 32)


def test_export_loads_as_single_patch_runs(world, tmp_path):
    from pbc.inference.predictor import load_decoder

    ds, _ = world
    stacked, _ = _modules(world)
    run = tmp_path / "run"
    ck = run / "checkpoints" / "epoch_004.ckpt"
    ck.parent.mkdir(parents=True)
    torch.save({"hyper_parameters": dict(stacked.hparams), "state_dict": stacked.state_dict(), "epoch": 4}, ck)
    record = RunRecord(kind="patches", optimized_metric=monitor("patches"), identity=stacked.hparams.identity,
                       test={"vertex_error_cm": 1.0, "patch_01/vertex_error_cm": 0.5}, config={"model": {}},
                       data={"dir": str(ds.dir)})
    record.write(run)
    dirs = export_patch_runs(ck, run, record, stacked.target, ds)
    assert len(dirs) == 3
    # the stacked run dir stands for its exported runs, alone or inside a sweep dir
    for where in (run, tmp_path):
        runs = select_patch_runs(where, "h", num_patches=3)
        assert [r.patch_id for r in runs] == [0, 1, 2] and all(r.kind == "patch" for r in runs)
    assert find_runs(run) == [run / "patches" / f"patch_{k:02d}" for k in range(3)]
    pose = torch.randn(2, 90)
    stacked.net.eval()
    for p, r in enumerate(select_patch_runs(run, "h", num_patches=3)):
        net, hp = load_decoder(r.checkpoint)
        assert hp["identity"] == make_target(ds, IMAGE, "patch", patch_id=p, skinner=stacked.target.skinner
                                             ).identity(ds)
        assert torch.allclose(net(pose), stacked.net(pose)[:, 3 * p:3 * p + 3], atol=1e-6)
        m = RunRecord.read(r.path)
        assert m.kind is ModelKind.PATCH and m.config["model"]["kind"] == "patch" and m.config["model"]["patch_id"] == p
        # the patch's own metric under its scoped name; the checkpoint was chosen by the stacked run's mean
        assert m.test == ({"patch_vertex_error_cm": 0.5} if p == 1 else {})
        assert m.optimized_metric is None and m.exported_from == str(run) and m.data == record.data
        # a single-patch module accepts the exported checkpoint (identity check included)
        single = ClothModule(**{k: v for k, v in hp.items() if k != "summary"})
        single.on_load_checkpoint(torch.load(r.checkpoint, weights_only=False))
    assert isinstance(stacked.target.patches[0], PatchTarget)


def test_one_training_pose_scales_the_output_by_its_own_size(world):
    # one pose has no spread over poses: the scale comes from the pose's own offsets, not the 1 m default
    # (with which a 3-drape smoke fit read 1e18 cm on validation)
    ds, _ = world
    _, singles = _modules(world)
    m = singles[0]
    batch = batch_for(ds.garment, b=1)
    m.fit_output_mean([batch])
    image = m.targets(batch)["image"][0].double()  # (C, H, W)
    want = torch.stack([image[c][image[c] != 0].pow(2).mean().sqrt() for c in range(image.shape[0])])
    assert torch.allclose(m.net.output_scale.flatten().double(), want, rtol=1e-5)
    assert float(m.net.output_scale.max()) < 0.5  # offsets of centimetres, not the metre default
