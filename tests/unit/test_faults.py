"""One test per reliability finding (docs/reliability.md maps each fault to its test).

Everything here is synthetic and seconds-long: a tiny LightningModule for the resume tests, a dataset
directory written from the coarse shirt with identity poses instead of a real drape.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.train_runs import ScriptedModule
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.core.io import LockHeld, dir_lock, load_checkpoint, load_npz, read_json, write_json
from pbc.core.validate import as_poses, check_config, check_resume, identity_diff, rotation_errors, training_identity

J = 10


def rotations(n: int, seed: int = 0) -> np.ndarray:
    """(n, J, 3, 3) random proper rotations (QR of Gaussian matrices, det fixed to +1)."""
    g = np.random.default_rng(seed).normal(size=(n * J, 3, 3))
    q, r = np.linalg.qr(g)
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1
    return q.reshape(n, J, 3, 3).astype(np.float32)


# ============================================================================ poses at the door
@pytest.mark.parametrize("shape", [(J, 3, 3), (4, J, 3, 3), (J * 9,), (4, J * 9)])
def test_pose_shapes_numpy_and_torch_become_batched_float32(shape):
    n = 4 if len(shape) in (2, 4) else 1
    r = rotations(n).reshape(shape)
    for x in (r, torch.from_numpy(r), r.astype(np.float64)):
        rot, batched = as_poses(x, J)
        assert rot.dtype == torch.float32 and rot.shape == (n, J, 3, 3)
        assert batched == (len(shape) in (2, 4))
        assert torch.allclose(rot, torch.from_numpy(r.reshape(n, J, 3, 3)))


def test_pose_wrong_joint_count_names_expected_shape():
    with pytest.raises(ValueError, match=r"shape \(4, 72\).*8 joints.*takes 10.*\(B, 90\)"):
        as_poses(rotations(4)[:, :8].reshape(4, 72), J)
    with pytest.raises(ValueError, match=r"shape \(10, 9\) \(one row of 9 per joint: reshape it to \(10, 3, 3\)\)"):
        as_poses(rotations(1).reshape(J, 9), J)
    with pytest.raises(ValueError, match=r"shape \(11, 3, 3\).*11 joints"):
        as_poses(np.concatenate([rotations(1)[0], np.eye(3, dtype=np.float32)[None]]), J)


def test_pose_flat_vector_is_one_pose_not_a_batch_of_90():
    rot, batched = as_poses(torch.from_numpy(rotations(1).reshape(-1)), J)
    assert rot.shape == (1, J, 3, 3) and not batched


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_pose_non_finite_is_refused_naming_the_batch_row(bad):
    r = rotations(5)
    r[3, 2, 1, 1] = float(bad)
    with pytest.raises(ValueError, match=r"NaN or infinite.*rows \[3\]"):
        as_poses(r, J)


@pytest.mark.parametrize("make", [lambda r: 2.0 * r, lambda r: 0.0 * r, lambda r: -r,
                                  lambda r: r + 0.05])
def test_pose_non_rotation_is_refused(make):
    r = rotations(2)
    r[1, 4] = make(r[1, 4])
    with pytest.raises(ValueError, match=r"pose\[1, 4\] \(spine\) is not a rotation.*1 of 20"):
        as_poses(r, J, joint_names=["j0", "j1", "j2", "j3", "spine"] + ["x"] * 5)


def test_pose_wrong_container_or_dtype():
    with pytest.raises(TypeError, match="got a list.*torch tensor or a numpy array"):
        as_poses(rotations(1)[0].tolist(), J)
    with pytest.raises(TypeError, match="dtype bool"):
        as_poses(np.ones((J, 3, 3), bool), J)


def test_rotation_errors_are_tiny_for_float32_rotations():
    ortho, det = rotation_errors(torch.from_numpy(rotations(100)))
    assert float(ortho.max()) < 1e-5 and float(det.max()) < 1e-5


# ============================================================================ config values by type
@pytest.mark.parametrize("override, needle", [
    ("model.patch_id=3.0", r"model.patch_id=3.0 \(float\)"),
    ("model.patch_id=true", r"model.patch_id=True \(bool\)"),
    ("model.patch_id=28", r"model.patch_id=28 .*0\.\.27"),
    ("model.patch_id=-1", r"model.patch_id=-1"),
])
def test_config_patch_id_must_be_an_integer_patch(override, needle):
    cfg = load_config(["model=patch", override])
    with pytest.raises(ValueError, match=needle):
        check_config(cfg, num_patches=28)


@pytest.fixture(scope="module")
def root_cfg():
    return load_config([])


@pytest.mark.parametrize("key, value, needle", [
    ("datamodule.batch_size", 0, "datamodule.batch_size=0"),
    ("datamodule.batch_size", 8.5, r"datamodule.batch_size=8.5 \(float\)"),
    ("model.kind", "wole", "model.kind='wole'.*one of"),
    ("model.space", "world", "model.space='world'"),
    ("loss.norm", "l3", "loss.norm='l3'"),
    ("model.lr", -1, "model.lr=-1"),
    ("data.num_samples", 0, "data.num_samples=0"),
    ("data.shard", 2, r"data.shard=2 .*0\.\.0"),
    ("sim.reuse_model", "yes", r"sim.reuse_model='yes' \(str\): expected true"),
    ("sim.batch_size", 0, "sim.batch_size=0"),
])
def test_config_values_checked_by_type(root_cfg, key, value, needle):
    cfg = root_cfg.copy()
    OmegaConf.update(cfg, key, value)
    with pytest.raises(ValueError, match=needle):
        check_config(cfg)


def test_config_lists_every_problem_at_once(root_cfg):
    cfg = root_cfg.copy()
    OmegaConf.update(cfg, "datamodule.batch_size", 0)
    OmegaConf.update(cfg, "model.lr", 0)
    with pytest.raises(ValueError) as err:
        check_config(cfg)
    assert "batch_size" in str(err.value) and "model.lr" in str(err.value)


@pytest.mark.parametrize("exp", ["whole", "patch_05", "fc_pca_local", "patch_27"])
def test_shipped_configs_pass(exp):
    check_config(load_config([f"+experiment={exp}"]), num_patches=28)


# ============================================================================ resume: last.ckpt every epoch
NB = 3  # training batches per epoch
VAL = [1.0, 0.5, 0.7, 0.9, 1.1, 1.2, 1.3, 1.4]  # improves once (epoch 1), then never


def shipped_checkpoints(dirpath: Path) -> list:
    """The checkpoint callbacks of conf/callbacks (the default preset), writing to `dirpath`."""
    from hydra.utils import instantiate

    cfg = load_config([]).callbacks
    out = []
    for name in ("model_checkpoint", "last_checkpoint"):
        node = OmegaConf.to_container(cfg[name], resolve=False)
        node["dirpath"], node["monitor"] = str(dirpath), cfg[name].monitor  # the monitor follows model.kind
        out.append(instantiate(node))
    return out


def trainer(callbacks, max_epochs):
    import lightning as L

    return L.Trainer(max_epochs=max_epochs, callbacks=callbacks, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, accelerator="cpu", num_sanity_val_steps=0)


class Record(__import__("lightning").Callback):
    def __init__(self):
        self.starts = []

    def on_train_epoch_start(self, trainer, pl_module):
        self.starts.append((trainer.current_epoch, trainer.global_step))


class Killed(Exception):
    pass


class Kill(__import__("lightning").Callback):
    """At the start of epoch `at`, copy what is on disk (what a SIGKILL would leave) and stop."""

    def __init__(self, at: int, src: Path, dst: Path):
        self.at, self.src, self.dst = at, src, dst

    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == self.at:
            shutil.copytree(self.src, self.dst)
            raise Killed


def test_resume_after_kill_continues_where_it_stopped_not_from_the_best_epoch(tmp_path):
    ck, killed = tmp_path / "ck", tmp_path / "killed"
    torch.manual_seed(0)
    with pytest.raises(Killed):
        trainer([Kill(4, ck, killed), *shipped_checkpoints(ck)], 8).fit(ScriptedModule(VAL, NB))
    # killed during epoch 4: epochs 0..3 done, the best was epoch 1, epochs 2 and 3 did not improve
    assert sorted(p.name for p in killed.glob("*.ckpt")) == ["epoch_001.ckpt", "last.ckpt"]
    last = load_checkpoint(killed / "last.ckpt")
    assert (last["epoch"], last["global_step"]) == (3, 4 * NB)
    rec = Record()
    trainer([rec, *shipped_checkpoints(tmp_path / "ck2")], 6).fit(ScriptedModule(VAL, NB),
                                                                  ckpt_path=killed / "last.ckpt")
    assert rec.starts[0] == (4, 4 * NB)  # resumed epoch and step are the killed ones
    assert [e for e, _ in rec.starts] == [4, 5]


class Sigterm(__import__("lightning").Callback):
    def __init__(self, epoch: int, batch: int):
        self.epoch, self.batch = epoch, batch

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if trainer.current_epoch == self.epoch and batch_idx == self.batch:
            os.kill(os.getpid(), signal.SIGTERM)  # what a cluster scheduler sends before it kills


def test_sigterm_writes_last_checkpoint_at_the_step_reached(tmp_path):
    ck = tmp_path / "ck"
    previous = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit):  # Lightning's SIGTERMException
            trainer([Sigterm(2, 1), *shipped_checkpoints(ck)], 8).fit(ScriptedModule(VAL, NB))
    finally:
        signal.signal(signal.SIGTERM, previous)
    last = load_checkpoint(ck / "last.ckpt")
    assert (last["epoch"], last["global_step"]) == (2, 2 * NB + 2)


@pytest.mark.parametrize("preset", ["default", "minimal"])
def test_best_checkpoint_callback_comes_first(preset, tmp_path):
    """pbc.train tests and reports trainer.checkpoint_callback: it must be the monitored one, not last."""
    import lightning as L
    from hydra.utils import instantiate

    cfg = load_config([f"callbacks={preset}", f"paths.output_dir={tmp_path}"])
    t = L.Trainer(callbacks=[instantiate(c) for c in cfg.callbacks.values()], logger=False)
    assert t.checkpoint_callback.monitor == "val/vertex_error_cm" and t.checkpoint_callback.save_top_k == 1
    assert [c.monitor for c in t.checkpoint_callbacks] == ["val/vertex_error_cm", None]


def test_training_identity_names_every_difference():
    a = load_config(["+experiment=whole"])
    b = load_config(["+experiment=whole", "loss=l2", "model.lr=0.01", "datamodule.batch_size=8"])
    fp = {"seed": 0, "garment_hash": "abc"}
    assert identity_diff(training_identity(a, fp), training_identity(a, dict(fp))) == []
    diff = identity_diff(training_identity(a, fp), training_identity(b, {**fp, "garment_hash": "xyz"}))
    keys = {line.split(":")[0] for line in diff}
    assert {"loss.norm", "model.lr", "optimizer.lr", "batch_size", "data.garment_hash"} <= keys
    assert any("'l1' vs this run 'l2'" in line for line in diff)
    with pytest.raises(ValueError, match=r"refusing to resume from r/last.ckpt(.|\n)*loss.norm: checkpoint 'l1'"
                                         r" vs this run 'l2'(.|\n)*ckpt_path=null"):
        check_resume(training_identity(a, fp), training_identity(b, fp), "r/last.ckpt")
    with pytest.raises(ValueError, match="records no training identity"):
        check_resume(None, training_identity(a, fp), "old.ckpt")
    check_resume(training_identity(a, fp), training_identity(a, fp), "r/last.ckpt")
    # a longer schedule is what resuming is for: not part of the identity
    c = load_config(["+experiment=whole", "trainer.max_epochs=500"])
    assert identity_diff(training_identity(a, fp), training_identity(c, fp)) == []
    # the square two-sided image is what runs made before image.whole_sides/whole_rows existed had: such a
    # checkpoint (no window keys) still resumes; another window does not
    old = training_identity(a, fp)
    assert "whole_rows" not in old["image"] and "whole_sides" not in old["image"]
    d = load_config(["+experiment=whole", "image.whole_rows=[0.25,0.75]"])
    assert any(line.startswith("image.whole_rows") for line in identity_diff(old, training_identity(d, fp)))


# ============================================================================ corrupt files are named
def test_truncated_npz_names_the_file_and_the_fix(tmp_path):
    p = tmp_path / "sample.npz"
    np.savez(p, a=np.arange(1000.0))
    p.write_bytes(p.read_bytes()[:300])
    with pytest.raises(ValueError, match=rf"{p.name} is corrupt.*BadZipFile.*regenerate"):
        load_npz(p, fix="regenerate")
    np.savez(p, a=np.arange(3))
    with pytest.raises(ValueError, match=r"missing arrays \['b'\]"):
        load_npz(p, ("a", "b"))


def test_corrupt_checkpoint_and_json_name_the_file(tmp_path):
    ck = tmp_path / "last.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(100)}, "epoch": 1}, ck)
    ck.write_bytes(ck.read_bytes()[:200])
    with pytest.raises(ValueError, match=rf"checkpoint {ck} is corrupt.*epoch_\*\.ckpt"):
        load_checkpoint(ck)
    m = tmp_path / "metrics.json"
    m.write_text('{"status": "ok", "test": {')
    with pytest.raises(ValueError, match=rf"metrics {m} is corrupt"):
        read_json(m, "metrics")


def test_read_only_output_dir_is_named(tmp_path):
    from pbc.core.io import require_writable_dir

    blocker = tmp_path / "runs"
    blocker.write_text("a file where the runs dir would be")
    with pytest.raises(PermissionError, match=rf"run dir {blocker}/r1 is not writable; set paths.log_dir"):
        require_writable_dir(blocker / "r1", "run dir", "set paths.log_dir")
    assert require_writable_dir(tmp_path / "ok" / "r1").is_dir()


# ============================================================================ operator cache
@pytest.fixture(scope="module")
def coarse_garment():
    from pbc.geometry.garment.tshirt import make_tshirt

    return make_tshirt(load_config(["data=tshirt_tiny"]).garment)[0]


def test_truncated_operator_cache_is_rebuilt(coarse_garment, tmp_path):
    from pbc.pixels.operators import load_or_build

    a = load_or_build(coarse_garment, 32, 2, True, tmp_path)
    (f,) = tmp_path.glob("operators_*.npz")
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])  # numpy: BadZipFile
    b = load_or_build(coarse_garment, 32, 2, True, tmp_path)
    assert np.array_equal(a["R_data"], b["R_data"])
    assert np.array_equal(np.load(f)["R_data"], a["R_data"])  # and the cache file is whole again


def test_operator_cache_moves_to_user_cache_when_dataset_is_read_only(coarse_garment, tmp_path, monkeypatch):
    from pbc.pixels.operators import load_or_build

    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "user"))
    blocker = tmp_path / "readonly"
    blocker.write_text("a file where a directory would be: not writable, even for root")
    a = load_or_build(coarse_garment, 32, 2, True, blocker / "operators")
    (f,) = (tmp_path / "user" / "operators").glob("operators_*.npz")
    built = f.stat().st_mtime_ns
    b = load_or_build(coarse_garment, 32, 2, True, blocker / "operators")
    assert f.stat().st_mtime_ns == built and np.array_equal(a["R_data"], b["R_data"])  # read, not rebuilt


# ============================================================================ data checked whole
class FakeData:
    """What check_dataset reads of a ClothDataset: arrays memory-mapped from `dir`, a body, the manifest."""

    def __init__(self, d: Path, poses: np.ndarray, verts: np.ndarray):
        from types import SimpleNamespace

        from pbc.core.io import load_npy, save_npy

        save_npy(d / "poses.npy", poses)
        save_npy(d / "verts.npy", verts)
        write_json(d / "manifest.json", {"source_index": list(range(100, 100 + len(poses)))})
        self.dir, self.manifest = d, read_json(d / "manifest.json")
        self.poses, self.verts = load_npy(d / "poses.npy"), load_npy(d / "verts.npy")
        # farthest rest-body point 0.8 m from the root: reach limit 1.2 m
        self.body = SimpleNamespace(vertices=torch.tensor([[0.0, 0.8, 0.0], [0.5, 0.0, 0.0]]))

    def __len__(self) -> int:
        return len(self.poses)


def test_every_bad_sample_is_named_when_the_dataset_opens(tmp_path):
    from pbc.data.dataset import bad_samples, check_dataset

    poses = rotations(12)
    verts = np.random.default_rng(1).uniform(-0.4, 0.4, size=(12, 50, 3)).astype(np.float32)
    check_dataset(FakeData(tmp_path, poses, verts))  # clean data passes
    verts[5, 17, 1] = np.nan  # a middle row: the old first/last spot check never saw it
    verts[7] *= 100.0  # centimetres written as metres: 40 m from the root
    poses[9, 3] *= 1.5  # a scaled matrix
    poses[10, 0, 0, 0] = np.inf
    bad = bad_samples(poses, verts, radius=1.2, chunk_bytes=1000)  # tiny chunks: ids must survive chunking
    assert {k: v.tolist() for k, v in bad.items()} == {
        "vertices not finite": [5], "vertices beyond reach": [7], "pose not a rotation": [9], "pose not finite": [10]}
    with pytest.raises(ValueError, match=r"vertices not finite: rows \[5\] \(generation samples \[105\]\)"
                                         r"(.|\n)*regenerate"):
        check_dataset(FakeData(tmp_path, poses, verts))


def _tiny_dataset_dir(root: Path, n: int = 6) -> Path:
    """A loadable dataset dir of the coarse shirt: identity-ish poses, rest-shape vertices, no drape."""
    from pbc.core.io import save_npy
    from pbc.data.dataset import save_embedding
    from pbc.data.generate import _cheap_fingerprint, garment_from_config
    from pbc.geometry.body.base import save_body
    from pbc.geometry.body.mannequin import build_mannequin
    from pbc.geometry.cage.base import save_cage
    from pbc.geometry.garment.base import save_garment_obj
    from pbc.geometry.shrinkwrap import Embedding

    cfg = load_config(["data=tshirt_tiny", f"data.num_samples={n}"])
    bcfg = cfg.body.copy()
    bcfg.mesh.voxel_size = 0.03
    body = build_mannequin(bcfg)
    garment, cage = garment_from_config(cfg.garment)
    V = garment.vertices.shape[0]
    d = root / "ds"
    save_garment_obj(garment, d / "garment.obj")
    save_cage(cage, d / "cage.json")
    save_body(body, d / "body.npz")
    save_embedding(Embedding(face=torch.zeros(V, dtype=torch.long), bary=torch.full((V, 3), 1 / 3),
                             part=torch.zeros(V, dtype=torch.long)), d / "embedding.npz")
    save_npy(d / "poses.npy", np.broadcast_to(np.eye(3, dtype=np.float32), (n, len(body.skeleton.names), 3, 3)))
    save_npy(d / "verts.npy", np.broadcast_to(garment.vertices.numpy(), (n, V, 3)).astype(np.float32))
    # the generation settings exactly as pbc.generate records them (seed, num_samples, sim, garment hash)
    write_json(d / "manifest.json", {
        **_cheap_fingerprint(cfg, garment), "body_hash": "b",
        "embedding_hash": "e", "counts": {"requested": n, "kept": n}, "source_index": list(range(n)),
        "splits": {"train": [0, 1, 2, 3], "val": [4], "test": [5]}})
    return d


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    return _tiny_dataset_dir(tmp_path_factory.mktemp("faults"))


def test_load_dataset_refuses_a_nan_in_the_middle(tiny_dir, tmp_path):
    from pbc.data.dataset import load_dataset

    d = tmp_path / "copy"
    shutil.copytree(tiny_dir, d)
    assert len(load_dataset(d)) == 6
    v = np.load(d / "verts.npy")
    v[3, 10] = np.nan
    np.save(d / "verts.npy", v)
    with pytest.raises(ValueError, match=r"bad samples(.|\n)*vertices not finite: rows \[3\]"):
        load_dataset(d)


def _copy_with_seed(src: Path, dst: Path, seed: int) -> Path:
    """A copy of a dataset whose manifest claims another seed: other data, same arrays."""
    shutil.copytree(src, dst)
    m = read_json(dst / "manifest.json")
    m["seed"] = seed
    write_json(dst / "manifest.json", m)
    return dst


def test_run_records_resolved_dir_and_fingerprint_and_refuses_other_data(tiny_dir, tmp_path, monkeypatch):
    from pbc.data.dataset import load_dataset, open_recorded_dataset, run_data_record

    monkeypatch.chdir(tiny_dir.parent)
    rec = run_data_record(load_dataset(Path(tiny_dir.name)))  # opened by a relative path...
    assert rec["dir"] == str(tiny_dir.resolve())  # ...recorded absolute
    monkeypatch.chdir(tmp_path)  # another shell, another cwd: the run still finds its data
    assert len(open_recorded_dataset(rec)) == 6
    other = _copy_with_seed(tiny_dir, tmp_path / "other", 7)
    with pytest.raises(ValueError, match=r"not the data the run was trained on(.|\n)*seed: recorded 0 vs found 7"):
        open_recorded_dataset(rec, other)
    with pytest.raises(FileNotFoundError, match="the run's dataset is not at"):
        open_recorded_dataset({**rec, "dir": str(tmp_path / "gone")})


def test_training_refuses_a_dataset_made_with_other_settings(tiny_dir):
    from pbc.data.dataset import load_dataset
    from pbc.data.generate import check_matches_config, config_mismatch

    data = load_dataset(tiny_dir)
    same = load_config(["data=tshirt_tiny", "data.num_samples=6"])
    assert config_mismatch(same, data.manifest) == []
    other = load_config(["data=tshirt_tiny", "data.num_samples=9", "sim.friction=0.3", "garment=tshirt"])
    diff = config_mismatch(other, data.manifest)
    assert {line.split(":")[0] for line in diff} == {"num_samples", "sim.friction", "garment_hash"}
    with pytest.raises(ValueError, match=r"other settings(.|\n)*num_samples: dataset 6 vs config 9(.|\n)*data.dir"):
        check_matches_config(other, data)


# ============================================================================ concurrency
def test_second_holder_of_a_lock_is_refused_naming_the_first(tmp_path):
    lock = tmp_path / "ds" / ".generate.lock"
    with dir_lock(lock, "dataset ds"):
        with pytest.raises(LockHeld, match=rf"dataset ds is in use by another process \(pid {os.getpid()} on"):
            with dir_lock(lock, "dataset ds"):
                pass
    assert not lock.exists()  # released and removed: a finished dataset keeps no lock file
    with dir_lock(lock, shared=True), dir_lock(lock, shared=True):  # shards run side by side
        with pytest.raises(LockHeld):
            with dir_lock(lock):  # but no merge beside them
                pass


def test_a_waiting_lock_gets_it_when_the_holder_finishes(tmp_path):
    lock = tmp_path / ".lock"
    held = threading.Event()

    def hold():
        with dir_lock(lock):
            held.set()
            time.sleep(0.5)

    t = threading.Thread(target=hold)
    t.start()
    held.wait()
    t0 = time.monotonic()
    with dir_lock(lock, timeout=10):
        assert time.monotonic() - t0 > 0.2
    t.join()


def test_second_generator_on_one_dir_is_refused_before_touching_it(tmp_path):
    from pbc.data.generate import generate

    cfg = load_config(["data=tshirt_tiny", f"paths.data_dir={tmp_path}"])
    out = Path(cfg.data.dir)
    with dir_lock(out / ".generate.lock", "first generator"):
        with pytest.raises(LockHeld, match="in use by another process"):
            generate(cfg)
    assert sorted(p.name for p in out.iterdir()) == []  # no work/ left behind by the refused one


def test_generator_checks_config_types_first(tmp_path):
    from pbc.data.generate import generate

    cfg = load_config(["data=tshirt_tiny", f"paths.data_dir={tmp_path}", "data.num_shards=2", "data.shard=1.0"])
    with pytest.raises(ValueError, match=r"data.shard=1.0 \(float\)"):
        generate(cfg)


# ============================================================================ the doors, wired in
# One real (seconds-long) training run on the stand-in dataset: a fully connected model (no image operators),
# two epochs of two batches; the tests below resume from it, reopen its data and feed its module bad poses.
FC = ["data=tshirt_tiny", "data.num_samples=6", "+experiment=fc_direct_local", "trainer=smoke",
      "callbacks=minimal", "logger=csv"]


def _cfg(data_dir: Path, out: Path, *extra: str):
    return load_config([*FC, f"data.dir={data_dir}", f"paths.output_dir={out}", *extra])


@pytest.fixture(scope="module")
def trained(tiny_dir, tmp_path_factory):
    from pbc.jobs.train import train

    runs = tmp_path_factory.mktemp("runs")
    metrics = train(_cfg(tiny_dir, runs / "a"))
    assert metrics["status"] == "ok" and (runs / "a" / "checkpoints" / "last.ckpt").is_file()
    return runs, metrics


def test_resume_last_adopts_only_a_run_of_the_same_training(trained, tiny_dir):
    from pbc.jobs.train import resolve_ckpt_path, train

    runs, metrics = trained
    ident, training = metrics["identity"], metrics["training_identity"]
    assert training["loss"]["norm"] == "l1" and training["data"]["seed"] == 0
    # the same training, asked in a sibling run dir: adopts run a's last.ckpt
    assert resolve_ckpt_path("last", runs / "b", ident, training) == str(runs / "a" / "checkpoints" / "last.ckpt")
    # another loss and learning rate in a sibling dir: not adopted (it used to resume the L1 / 1e-3 run)
    with pytest.raises(FileNotFoundError, match="no last.ckpt of this setup"):
        train(_cfg(tiny_dir, runs / "c", "loss=l2", "model.lr=0.01", "ckpt_path=last"))
    assert not (runs / "c" / "checkpoints").exists()
    # ...and in run a's own dir (or naming its checkpoint): refused, listing every difference
    for spec in ("last", str(runs / "a")):
        with pytest.raises(ValueError, match=r"refusing to resume(.|\n)*loss.norm: checkpoint 'l1' vs this run 'l2'"
                                             r"(.|\n)*optimizer.lr: checkpoint 0.001 vs this run 0.01"):
            train(_cfg(tiny_dir, runs / "a", "loss=l2", "model.lr=0.01", f"ckpt_path={spec}"))
    # the checkpoint itself carries the identity it was trained with
    hp = load_checkpoint(runs / "a" / "checkpoints" / "last.ckpt")["hyper_parameters"]
    assert identity_diff(hp["training_identity"], training) == []


def test_train_refuses_a_dataset_made_with_other_settings(tiny_dir, tmp_path):
    from pbc.jobs.train import train

    with pytest.raises(ValueError, match=r"other settings(.|\n)*num_samples: dataset 6 vs config 9"):
        train(_cfg(tiny_dir, tmp_path / "r", "data.num_samples=9"))
    assert not (tmp_path / "r" / "checkpoints").exists()  # refused before training, nothing recorded


@pytest.mark.parametrize("value, needle", [("3.0", r"model.patch_id=3.0 \(float\)"),
                                           ("true", r"model.patch_id=True \(bool\)"),
                                           ("99", r"(unknown patch_id 99|patch_id=99).*0..27")])
def test_train_checks_config_types_at_the_door(tiny_dir, tmp_path, value, needle):
    from pbc.jobs.train import train

    cfg = load_config(["data=tshirt_tiny", "data.num_samples=6", "+experiment=patch_03", f"model.patch_id={value}",
                       f"data.dir={tiny_dir}", f"paths.output_dir={tmp_path / 'r'}"])
    with pytest.raises(ValueError, match=needle):
        train(cfg)
    assert not (tmp_path / "r" / "checkpoints").exists()


def test_train_names_a_read_only_run_dir_first(tiny_dir, tmp_path):
    from pbc.jobs.train import train

    blocker = tmp_path / "runs"
    blocker.write_text("a file where the runs dir would be")  # read-only for root too
    with pytest.raises(PermissionError, match=rf"run dir {blocker}/r is not writable; set hydra.run.dir"):
        train(_cfg(tiny_dir, blocker / "r"))


def test_run_remembers_its_data_from_any_shell(trained, tiny_dir, tmp_path, monkeypatch):
    from pbc.core.runs import read_run
    from pbc.inference.predictor import open_run_dataset

    runs, metrics = trained
    assert metrics["data"]["dir"] == str(tiny_dir.resolve())
    assert metrics["config"]["data"]["dir"] == str(tiny_dir.resolve())  # no ${oc.env:PBC_ROOT,.} left
    info = read_run(runs / "a")
    assert info.data == metrics["data"]
    monkeypatch.chdir(tmp_path)  # another shell: other cwd, other PBC_ROOT
    monkeypatch.setenv("PBC_ROOT", str(tmp_path))
    assert len(open_run_dataset(info)) == 6
    other = _copy_with_seed(tiny_dir, tmp_path / "other", 7)
    with pytest.raises(ValueError, match=r"not the data the run was trained on(.|\n)*seed: recorded 0 vs found 7"):
        open_run_dataset(info, other)
    # a run written before the record existed still opens its config's data.dir
    old = dataclasses.replace(info, record=dataclasses.replace(info.record, data=None,
                                                               config={"data": {"dir": str(tiny_dir)}}))
    assert len(open_run_dataset(old)) == 6


def test_module_forward_checks_its_poses(trained):
    from pbc.models.module import ClothModule

    runs, _ = trained
    m = ClothModule.load_from_checkpoint(runs / "a" / "checkpoints" / "last.ckpt", map_location="cpu").eval()
    r = rotations(2)
    with torch.no_grad():
        ref = m(torch.from_numpy(r))
        assert torch.allclose(m(r), ref) and torch.allclose(m(torch.from_numpy(r).reshape(2, -1)), ref)  # numpy too
        with pytest.raises(ValueError, match=r"one pose of shape \(90,\).*pose\[None\]"):
            m(torch.from_numpy(r[0]).reshape(-1))  # used to broadcast into a batch of 90
        bad = r.copy()
        bad[1, 4, 0, 0] = np.nan
        with pytest.raises(ValueError, match=r"NaN or infinite values in batch rows \[1\]"):
            m(bad)
        with pytest.raises(ValueError, match=r"not a rotation"):
            m(2.0 * r)
        with pytest.raises(ValueError, match=r"that is 9 joints; this model takes 10"):
            m(r[:, :9])


def test_corrupt_run_files_are_named(trained, tmp_path):
    from pbc.core.runs import read_run
    from pbc.data.generate import _read_sample
    from pbc.inference.predictor import load_decoder

    runs, _ = trained
    run = tmp_path / "run"
    shutil.copytree(runs / "a", run)
    (run / "metrics.json").write_text('{"status": "ok", "test": {')
    with pytest.raises(ValueError, match=rf"run metrics {run}/metrics.json is corrupt"):
        read_run(run)
    ck = run / "checkpoints" / "last.ckpt"
    ck.write_bytes(ck.read_bytes()[:1000])
    with pytest.raises(ValueError, match=rf"checkpoint {ck} is corrupt or truncated"):
        load_decoder(ck)
    sample = tmp_path / "000003.npz"
    np.savez(sample, positions=np.zeros((4, 3), np.float32), meta=np.array('{"ok": true}'))
    assert _read_sample(sample)[1] == {"ok": True}
    sample.write_bytes(sample.read_bytes()[:100])
    with pytest.raises(ValueError, match=rf"sample file {sample} is corrupt or truncated.*delete it and re-run"):
        _read_sample(sample)


def test_datamodule_finds_a_nan_anywhere_when_it_opens(tiny_dir, tmp_path):
    from pbc.data.datamodule import ClothDataModule

    d = tmp_path / "copy"
    shutil.copytree(tiny_dir, d)
    p = np.load(d / "poses.npy")
    p[2, 5, 1, 1] = np.nan  # a middle row: the old first/last-row spot check never saw it
    np.save(d / "poses.npy", p)
    dm = ClothDataModule(str(d), load_config(["data=tshirt_tiny"]).image, target="fc")
    with pytest.raises(ValueError, match=r"pose not finite: rows \[2\]"):
        dm.setup("fit")


def test_rotation_check_is_float32_exact_under_bf16_autocast():
    """Validation under trainer.precision=bf16-mixed: proper rotations pass (a bf16 product would not)."""
    from scipy.spatial.transform import Rotation

    from pbc.core.validate import ROTATION_TOL, rotation_errors

    rot = torch.from_numpy(Rotation.random(70, random_state=0).as_matrix()).float()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        ortho, det = rotation_errors(rot)
    assert ortho.dtype == torch.float32 and ortho.max() < 1e-5 < ROTATION_TOL and det.max() < 1e-5

