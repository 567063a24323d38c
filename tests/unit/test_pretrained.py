"""Shipped models (pbc.pretrained): packing a run, loading it by name, what it predicts, and the model that
ships with pbc.

The stand-in is test_evaluate's synthetic dataset written out as a full dataset dir (real coarse shirt and
cage, the shrunk-garment "body") and an untrained whole run on it; packing it exercises the same code as the
real model (fp16 weights, the trimmed data, the record, the card).
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.evaluate_world import _rotations, _stitch_cfg, fake_dataset, save_run
from omegaconf import OmegaConf

import pbc.pretrained
import pbc.pretrained.pack as pack
from pbc.cli import predict as predict_cli
from pbc.cli import pretrained as pretrained_cli
from pbc.core.runs import RunRecord
from pbc.data.dataset import load_dataset, save_embedding
from pbc.data.trimmed import recorded_mean_offsets
from pbc.geometry.body.base import save_body
from pbc.geometry.cage.base import save_cage
from pbc.geometry.garment.base import save_garment_obj
from pbc.inference.poses import run_known, run_known_poses, run_pose_range, training_pose_range
from pbc.inference.predictor import ClothPredictor, pretrained_run
from pbc.motion.ranges import range_from_record

# fp16 weights against the fp32 checkpoint they came from, positions in cm: half precision keeps ~3 digits
# of each weight, so a prediction moves by ~1e-3 of its offsets (a few mm here, a few cm on the shirt)
FP16_TOL_CM = 0.05
HEAD_STD = 0.02  # the stand-in's head weights: offsets of about a centimetre


def exit_code(main, argv) -> int:
    with pytest.raises(SystemExit) as e:
        main(argv)
    return int(e.value.code or 0)


@pytest.fixture(scope="module")
def standin(tmp_path_factory, body):
    """(shipped dir holding the packed stand-in, the source run, its full dataset, pack's numbers)."""
    root = tmp_path_factory.mktemp("pretrained")
    ds = fake_dataset(root / "data" / "fake")
    V = len(ds.garment.vertices)
    save_garment_obj(ds.garment, ds.dir / "garment.obj")
    save_cage(ds.cage, ds.dir / "cage.json", V)
    # the body file carries collision primitives: the mannequin's (same skeleton), unused by prediction
    save_body(dataclasses.replace(ds.body, primitives=body.primitives), ds.dir / "body.npz")
    save_embedding(ds.embedding, ds.dir / "embedding.npz")
    manifest = dict(ds.manifest, seed=0)
    (ds.dir / "manifest.json").write_text(json.dumps(manifest))
    full = load_dataset(ds.dir)
    whole = save_run(root / "runs" / "whole", ds.dir, "whole", None)
    with torch.no_grad():  # offsets of centimetres, as a trained model's: the fp16 rounding is then visible
        ck = torch.load(whole / "checkpoints" / "epoch_000.ckpt", weights_only=False)
        # an untrained decoder outputs its mean image (dead ReLUs, a tiny head): BatchNorm shifts that keep
        # the ReLUs alive and a random head, as if trained
        sd = ck["state_dict"]
        for k in [k for k in sd if k.endswith(".bias") and k.replace(".bias", ".running_mean") in sd]:
            sd[k] = torch.full_like(sd[k], 0.5)
        g = torch.Generator().manual_seed(0)
        sd["net.head.weight"] = torch.randn(sd["net.head.weight"].shape, generator=g) * HEAD_STD
        torch.save(ck, whole / "checkpoints" / "epoch_000.ckpt")
    shipped = root / "shipped"
    mp = pytest.MonkeyPatch()
    mp.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    mp.setenv("PBC_CACHE_DIR", str(root / "cache"))
    try:
        info = pack.pack_run(whole, "standin", shipped / "standin", command="(test stand-in)")
    finally:
        mp.undo()
    return shipped, whole, full, info


@pytest.fixture
def shipped(standin, monkeypatch, tmp_path):
    """pbc.pretrained looking in the stand-in's shipped dir (the real one holds the real model)."""
    monkeypatch.setattr(pbc.pretrained, "SHIPPED_DIR", standin[0])
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("PBC_MODELS", str(tmp_path / "models"))  # the user's models folder: empty
    return standin


def tree(folder: Path) -> dict[str, bytes | None]:
    """Every path under `folder`, with each file's bytes (None for a folder): equal trees are byte-identical."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


def test_packed_model_predicts_what_its_fp32_checkpoint_does(shipped):
    _, whole, full, info = shipped
    ck = torch.load(pretrained_run("standin") / "checkpoints" / pack.WEIGHTS, weights_only=False)
    assert ck["state_dict"]["net.head.weight"].dtype == torch.float16
    assert all(v.dtype == torch.float16 for v in ck["state_dict"].values() if v.is_floating_point())
    packed = ClothPredictor.from_pretrained("standin")
    fp32 = ClothPredictor.from_runs(whole)
    poses = torch.from_numpy(_rotations(5, full.poses.shape[1], seed=7))
    a, b = packed(poses, model="whole"), fp32(poses, model="whole")
    assert a.shape == (5, len(full.garment.vertices), 3) and torch.isfinite(a).all()
    offsets = (b - fp32.skinner(poses)[0]).norm(dim=-1)
    assert float(offsets.mean()) > 0.005  # the comparison means something: offsets of centimetres
    diff_cm = float((a - b).norm(dim=-1).max()) * 100
    assert 0 < diff_cm < FP16_TOL_CM
    assert info["fp16_vs_fp32_max_vertex_cm"] == pytest.approx(round(diff_cm, 4), abs=2e-3)


def test_packed_data_is_the_test_split_with_the_training_summary(shipped):
    _, _, full, info = shipped
    ds = ClothPredictor.from_pretrained("standin").dataset
    test = full.split("test")
    assert len(ds) == len(test) and list(ds.split("test")) == list(range(len(test)))
    assert len(ds.split("train")) == 0 and ds.manifest["trimmed_from"]["splits"]["train"] == 7
    np.testing.assert_array_equal(ds.verts, full.verts[test])
    # the training range and mean shape of the full data, though its training poses are not shipped
    np.testing.assert_allclose(training_pose_range(ds).deg, training_pose_range(full).deg, atol=1e-9)
    assert training_pose_range(ds).chart == training_pose_range(full).chart == "swing_twist"
    mean, space = recorded_mean_offsets(ds)
    pred = ClothPredictor.from_runs(shipped[1])
    idx = full.split("train")
    want = pred.offsets_of(torch.from_numpy(np.asarray(full.poses[idx])), torch.from_numpy(np.asarray(full.verts[idx])))
    assert space == "local" and torch.allclose(mean, want[0].mean(0), atol=1e-6)
    assert info["test_poses"] == len(test) and info["dataset"]["splits"] == {"train": 7, "val": 1, "test": 2}
    # the training poses ship (float16): what the model knows, for the flags and the guard (pbc.motion.known)
    shipped_pred = ClothPredictor.from_pretrained("standin")
    known = run_known_poses(shipped_pred)
    np.testing.assert_allclose(known, np.asarray(full.poses[idx]), atol=2e-3)
    assert run_known(shipped_pred, 0.99).limit_deg == pytest.approx(run_known(pred, 0.99).limit_deg, abs=0.2)


def test_the_record_and_card_carry_the_measured_numbers(shipped):
    d = pretrained_run("standin")
    rec = json.loads((d / "metrics.json").read_text())
    info = rec["pretrained"]
    assert rec["kind"] == "whole" and rec["data"]["dir"] == "data"
    assert rec["test"]["vertex_error_cm"] == info["test_vertex_error_cm"]
    card = (d / "MODEL_CARD.md").read_text()
    for text in (f"{info['test_vertex_error_cm']:.3f} cm", f"{info['mean_shape_test_vertex_error_cm']:.3f} cm",
                 "0123abc", "(test stand-in)", "train 7 / val 1 / test 2"):
        assert text in card, text
    assert info["bytes"]["weights"] < 0.6 * (shipped[1] / "checkpoints" / "epoch_000.ckpt").stat().st_size


def test_the_training_range_ships_in_the_record_and_card(shipped):
    """The stand-in run predates the recorded range: pack measures it from the run's dataset and says so; the
    packed record carries it (predict reads it from there, no data needed) and the card prints it."""
    _, _, full, info = shipped
    d = pretrained_run("standin")
    names = list(full.body.skeleton.names)
    rec = RunRecord.read(d).pose_range
    np.testing.assert_allclose(range_from_record(rec, names).deg, training_pose_range(full).deg, atol=1e-9)
    assert rec["poses"] == 7 and info["pose_range_source"].startswith("measured by pbc pretrained pack")
    pred = ClothPredictor.from_pretrained("standin")
    assert run_pose_range(pred)[1] == f"recorded in the run {d}"
    card = (d / "MODEL_CARD.md").read_text()
    lo, hi = rec["deg"]["l_arm"]["z"]
    assert "## Training poses' joint angles" in card and "over the 7 poses of the train split" in card
    assert "| l_arm | " in card and f"{lo:.1f} to {hi:.1f} |" in card


def test_joints_the_model_does_not_read_are_never_flagged(shipped):
    """A model reading some joints (a shirt on a body with legs): the others get the full circle, so a walk's
    legs neither flag frames nor get clamped; the joints it reads keep the training range."""
    _, _, full, _ = shipped
    pred = ClothPredictor.from_pretrained("standin")
    J = len(full.body.skeleton.names)
    assert pred.read_joints() == list(range(J))
    trained = training_pose_range(full).deg
    np.testing.assert_allclose(run_pose_range(pred)[0].deg, trained, atol=1e-9)
    pred.whole_net.input_joints = (0, 2)
    assert pred.read_joints() == [0, 2]
    rng = run_pose_range(pred)[0].deg
    np.testing.assert_allclose(rng[[0, 2]], trained[[0, 2]], atol=1e-9)
    others = [j for j in range(J) if j not in (0, 2)]
    assert (rng[others, :, 0] == -180).all() and (rng[others, :, 1] == 180).all()


def test_unknown_names_are_refused_listing_the_shipped_models_and_yours(shipped, tmp_path, capsys):
    (tmp_path / "models" / "mine").mkdir(parents=True)
    (tmp_path / "models" / "mine" / "metrics.json").write_text("{}")
    (tmp_path / "models" / "mine.previous-20250101-000000").mkdir()  # a kept copy is no model
    (tmp_path / "models" / "mine.previous-20250101-000000" / "metrics.json").write_text("{}")
    want = re.escape(f"no pretrained model named 'shirt': pbc ships standin; your models folder "
                     f"({tmp_path / 'models'}) holds mine (give one of those, or a trained run dir instead)")
    with pytest.raises(ValueError, match=want):
        pretrained_run("shirt")
    with pytest.raises(ValueError, match=want):
        ClothPredictor.from_runs("pretrained:shirt")
    with pytest.raises(ValueError, match=want.replace("'shirt'", "'mine.previous-20250101-000000'")):
        pretrained_run("mine.previous-20250101-000000")
    assert exit_code(predict_cli.main, ["--pretrained", "shirt", "--poses", "test"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pbc predict: error: no pretrained model named 'shirt': pbc ships standin; your models")
    assert "holds mine" in err and err.count("\n") == 1


def test_predict_and_evaluate_take_a_shipped_model(shipped, tmp_path, capsys):
    out = tmp_path / "pred"
    assert exit_code(predict_cli.main, ["--pretrained", "standin", "--poses", "test", "--out", str(out),
                                        "--sheet", "0"]) == 0
    res = json.loads((out / "predict.json").read_text())
    assert res["num_poses"] == 2 and res["pretrained"] == "standin"
    assert res["vertex_error_cm"] == pytest.approx(shipped[3]["test_vertex_error_cm"], abs=1e-3)
    assert exit_code(predict_cli.main, [str(shipped[1]), "--pretrained", "standin", "--poses", "test"]) == 2
    assert exit_code(predict_cli.main, ["--pretrained", "standin", "--poses", "train"]) == 2
    assert "carries only its test split; use --poses test" in capsys.readouterr().err
    from pbc.jobs.evaluate import evaluate

    cfg = OmegaConf.create({"whole_run": "pretrained:standin", "patch_runs": None, "methods": ["average"],
                            "split": "test", "max_samples": None, "batch_size": 8, "num_previews": 1,
                            "pca_path": None, "pca_fit_max": 100, "stitch": _stitch_cfg("pca")})
    m = evaluate(cfg, tmp_path / "eval")
    e = m["entries"]
    assert e["whole"]["vertex_error_cm"] == pytest.approx(shipped[3]["test_vertex_error_cm"], abs=1e-3)
    assert e["train_mean"]["vertex_error_cm"] == pytest.approx(shipped[3]["mean_shape_test_vertex_error_cm"],
                                                               abs=1e-3)
    assert exit_code(pretrained_cli.main, ["list"]) == 0
    assert "standin (shipped): test vertex error" in capsys.readouterr().out


def test_pack_refuses_a_patch_run_and_a_bad_name(shipped, tmp_path):
    full = shipped[2]
    patch = save_run(tmp_path / "patch", full.dir, "patch", 3)
    with pytest.raises(ValueError, match="only a whole-garment run"):
        pack.pack_run(patch, "p", tmp_path / "out")
    with pytest.raises(ValueError, match="plain name"):
        pack.pack_run(shipped[1], "../x", tmp_path / "out")
    with pytest.raises(ValueError, match="--test-poses 0: give the number of test poses to ship"):
        pack.pack_run(shipped[1], "x", tmp_path / "out", test_poses=0)
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_pack_ships_the_first_test_poses_asked_for(shipped, tmp_path, monkeypatch):
    """--test-poses N: the first N rows of the test split ship, the card scores them and says of how many."""
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    full = shipped[2]
    test = full.split("test")
    assert len(test) >= 2
    info = pack.pack_run(shipped[1], "few", tmp_path / "few", test_poses=1)
    ds = load_dataset(tmp_path / "few" / "data")
    assert info["test_poses"] == 1 == len(ds.split("test")) and info["test_split_poses"] == len(test)
    np.testing.assert_array_equal(np.asarray(ds.verts), np.asarray(full.verts)[test[:1]])
    assert ds.manifest["trimmed_from"]["rows"] == [int(test[0])]
    card = (tmp_path / "few" / "MODEL_CARD.md").read_text()
    assert f"over the first 1 of the {len(test)} test poses, fp16 weights" in card


def test_a_fully_connected_run_predicts_and_packs(shipped, tmp_path, monkeypatch):
    """A `model.kind=fc` run is a whole-garment model too: the predictor turns its per-vertex offsets into the
    garment by the same skinning (checked against the net's own output), and it packs as a shipped model whose
    fp16 weights (the PCA basis among them) predict what the fp32 run does."""
    full = shipped[2]
    V = len(full.garment.vertices)
    fc = save_run(tmp_path / "fc", full.dir, "fc", None, num_vertices=V)
    pred = ClothPredictor.from_runs(fc)
    assert pred.whole_kind == "fc"
    pred.mend = None  # the net's own output skinned, unmended (tests/unit/test_mend.py covers the mend)
    poses = torch.from_numpy(_rotations(4, full.poses.shape[1], seed=3))
    x = pred(poses, model="whole")
    net = pack.load_checkpoint(fc / "checkpoints" / "epoch_000.ckpt")
    with torch.no_grad():
        offsets = pred.whole_net(poses.reshape(4, -1))  # (B, V, 3) local offsets
    anchors, frames = pred.skinner(poses)
    want = anchors + torch.einsum("bvij,bvi->bvj", frames, offsets)
    assert x.shape == (4, V, 3) and float(offsets.norm(dim=-1).mean()) > 1e-3 and "state_dict" in net
    torch.testing.assert_close(x, want, atol=1e-6, rtol=0)
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    with pytest.raises(ValueError, match="--notes .*cannot read it"):
        pack.pack_run(fc, "fcstandin", tmp_path / "shipped" / "fcstandin", notes=tmp_path / "missing.md")
    assert not (tmp_path / "shipped").exists()  # refused before anything was written
    (tmp_path / "notes.md").write_text("## Licence\n\nFree for any use (a test's words).\n")
    info = pack.pack_run(fc, "fcstandin", tmp_path / "shipped" / "fcstandin", command="(fc stand-in)",
                         notes=tmp_path / "notes.md")
    assert info["kind"] == "fc" and "fully connected" in info["network"] and "8 PCA coefficients" in info["network"]
    rec = json.loads((tmp_path / "shipped" / "fcstandin" / "metrics.json").read_text())
    assert rec["kind"] == "fc"
    card = (tmp_path / "shipped" / "fcstandin" / "MODEL_CARD.md").read_text()
    assert card.startswith("# Shipped model `fcstandin`: a fully connected net (hidden 32 x 32)")
    assert "## Licence\n\nFree for any use (a test's words)." in card
    packed = ClothPredictor.from_runs(tmp_path / "shipped" / "fcstandin")
    packed.mend = None
    diff_cm = float((packed(poses, model="whole") - x).norm(dim=-1).max()) * 100
    assert packed.whole_kind == "fc" and 0 < diff_cm < FP16_TOL_CM
    # pbc evaluate scores it as the whole model, beside the image representation's floor it has no image of
    from pbc.jobs.evaluate import evaluate  # noqa: PLC0415 - as the shipped model's evaluate test imports it

    cfg = OmegaConf.create({"whole_run": str(tmp_path / "shipped" / "fcstandin"), "patch_runs": None,
                            "methods": ["average"], "split": "test", "max_samples": None, "batch_size": 8,
                            "num_previews": 1, "pca_path": None, "pca_fit_max": 100, "stitch": _stitch_cfg("pca")})
    e = evaluate(cfg, tmp_path / "eval")["entries"]
    assert e["whole"]["vertex_error_cm"] == pytest.approx(info["test_vertex_error_cm"], abs=1e-3)
    assert e["floor_256"]["vertex_error_cm"] < e["whole"]["vertex_error_cm"]


def test_pack_onto_a_shipped_name_is_refused_in_one_line_and_the_shipped_files_stay(shipped, tmp_path, capsys):
    """The shipped models are read-only to pack: their name (it would shadow them) or their folder (--out) is
    refused before anything is read or written, naming the model and the fix."""
    before = tree(shipped[0])
    with pytest.raises(ValueError, match=r"^'standin' is a model shipped with pbc \(.*\): give yours another "
                                         r"--name, or add --force to pack it as your own 'standin' in ") as err:
        pack.pack_run(shipped[1], "standin")
    assert str(shipped[0] / "standin") in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ValueError, match=r"--out .* is inside pbc/pretrained, the models shipped with pbc, .* or "
                                         r"add --force"):
        pack.pack_run(shipped[1], "other", shipped[0] / "other")
    assert exit_code(pretrained_cli.main, ["pack", str(shipped[1]), "--name", "standin"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pbc pretrained: error: 'standin' is a model shipped with pbc") and err.count("\n") == 1
    assert tree(shipped[0]) == before and not (tmp_path / "models").exists()


def test_force_packs_yours_where_it_shadows_the_shipped_model_and_pretrained_loads_it(shipped, tmp_path, capsys,
                                                                                     monkeypatch):
    """--force onto a shipped name: yours goes to your models folder (the package's files stay byte for byte),
    and every door of --pretrained NAME then opens yours; `list` shows both and which shadows which."""
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    before = tree(shipped[0])
    mine = tmp_path / "models" / "standin"
    assert exit_code(pretrained_cli.main, ["pack", str(shipped[1]), "--name", "standin", "--force",
                                           "--test-poses", "1"]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"standin -> {mine}: ")
    assert f"it shadows the shipped standin ({shipped[0] / 'standin'}, unchanged)" in said
    assert tree(shipped[0]) == before
    assert pretrained_run("standin") == mine
    # yours ships one test pose, the shipped one two
    assert len(ClothPredictor.from_pretrained("standin").dataset) == 1
    assert len(ClothPredictor.from_runs("pretrained:standin").dataset) == 1
    out = tmp_path / "pred"
    assert exit_code(predict_cli.main, ["--pretrained", "standin", "--poses", "test", "--out", str(out),
                                        "--sheet", "0"]) == 0
    res = json.loads((out / "predict.json").read_text())
    assert res["num_poses"] == 1 and res["whole_run"] == str(mine)
    capsys.readouterr()
    assert exit_code(pretrained_cli.main, ["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("standin (yours, shadows the shipped standin): test vertex error ")
    assert lines[0].endswith(str(mine / "MODEL_CARD.md"))
    assert lines[1].startswith("standin (shipped, shadowed by yours): test vertex error ")
    assert lines[1].endswith(str(shipped[0] / "standin" / "MODEL_CARD.md"))
    assert lines[2] == f"your models folder: {tmp_path / 'models'} ($PBC_MODELS sets it)"
    assert tree(shipped[0]) == before


def test_force_with_out_in_the_package_remakes_a_shipped_model(shipped, tmp_path, monkeypatch):
    """Re-making a shipped model in a checkout: --out at its folder with --force replaces it (no copy is kept
    inside the package, where it would ship), and its card says how to make it again."""
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    package = tmp_path / "package"
    shutil.copytree(shipped[0], package)
    monkeypatch.setattr(pbc.pretrained, "SHIPPED_DIR", package)
    info = pack.pack_run(shipped[1], "standin", package / "standin", force=True, test_poses=1)
    assert info["dir"] == package / "standin" and info["previous"] is None
    assert sorted(p.name for p in package.iterdir()) == ["standin"]
    assert pretrained_run("standin") == package / "standin" and len(load_dataset(package / "standin" / "data")) == 1
    card = (package / "standin" / "MODEL_CARD.md").read_text()
    assert "pbc pretrained pack runs/main/latest/whole --name standin --out pbc/pretrained/standin --force" in card


def test_packing_over_your_model_keeps_the_old_one_and_says_where(shipped, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier
    models = tmp_path / "models"
    first = pack.pack_run(shipped[1], "mine", test_poses=1)
    assert first["dir"] == models / "mine" and first["previous"] is None
    old = tree(models / "mine")
    assert exit_code(pretrained_cli.main, ["pack", str(shipped[1]), "--name", "mine"]) == 0
    kept = sorted(p for p in models.iterdir() if p.name != "mine")
    assert [p.name[:len("mine.previous-")] for p in kept] == ["mine.previous-"]
    assert tree(kept[0]) == old  # the first model, byte for byte
    assert f"; the model there before is kept as {kept[0]}" in capsys.readouterr().out
    assert len(ClothPredictor.from_pretrained("mine").dataset) == 2  # the new one: both test poses
    assert pbc.pretrained.user_models() == ["mine"]  # the kept copy is no model --pretrained finds


def test_a_failed_pack_leaves_nothing_half_written(shipped, tmp_path, monkeypatch):
    """The model is written beside its folder and renamed onto it whole: a pack failing half-way (here the
    trimmed data, after the weights) leaves no part of it, and a model that was there stays as it was."""
    monkeypatch.setattr(pack, "git_commit", lambda where: "0123abc")  # no subprocess in the unit tier

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pack, "trim_dataset", full_disk)
    models = tmp_path / "models"
    with pytest.raises(OSError, match="No space left"):
        pack.pack_run(shipped[1], "mine")
    assert list(models.iterdir()) == []
    (models / "mine" / "checkpoints").mkdir(parents=True)
    (models / "mine" / "metrics.json").write_text('{"kind": "whole"}')
    (models / "mine" / "checkpoints" / pack.WEIGHTS).write_bytes(b"the weights before")
    before = tree(models)
    with pytest.raises(OSError, match="No space left"):
        pack.pack_run(shipped[1], "mine")
    assert tree(models) == before


@pytest.mark.parametrize("name", pbc.pretrained.shipped_models())
def test_each_shipped_model_loads_and_predicts(name, tmp_path, monkeypatch):
    """The models in the repository (pbc/pretrained/<name>): fp16 weights within budget, finite garments near its
    shipped test drapes."""
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "cache"))
    d = pretrained_run(name)
    assert (d / "checkpoints" / pack.WEIGHTS).stat().st_size <= 8e6
    pred = ClothPredictor.from_pretrained(name)
    poses = torch.from_numpy(np.asarray(pred.dataset.poses[:3]))
    x = pred(poses)
    assert x.shape == (3, len(pred.dataset.garment.vertices), 3) and torch.isfinite(x).all()
    err = float((x - torch.from_numpy(np.asarray(pred.dataset.verts[:3]))).norm(dim=-1).mean()) * 100
    assert err < 10.0  # metres-scale nonsense (a wrong space, a lost mean image) is far above this


def test_the_starters_ship():
    """`--pretrained tshirt` (the shirt) and `--pretrained trousers` (the legs) are there for a walking clip."""
    assert {"tshirt", "trousers"} <= set(pbc.pretrained.shipped_models())
