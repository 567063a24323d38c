"""Refusals that leave other runs alone, atomic writes on a full disk, bounds on work, finite geometry, the
viewer's host and the messages of docs/reliability.md (the rows naming this file). Synthetic: no drape, no
training; `pbc train` goes through its real entry point (Hydra included) and is stopped at the data."""

from __future__ import annotations

import errno
import hashlib
import json
import os
from pathlib import Path
from types import SimpleNamespace

import lightning as L
import numpy as np
import pytest
import torch
import trimesh
from helpers.cli import exit_code
from helpers.train_runs import ScriptedModule
from hydra.utils import instantiate

import pbc.core.io as pbc_io
import pbc.jobs.train as pbc_train
from pbc.cli.train import main as train_main
from pbc.core.config import load_config
from pbc.core.io import DiskFull, dir_lock
from pbc.core.runs import load_run


def tree_hash(root: Path) -> dict[str, str]:
    """{relative path: sha256} of every file under `root` (the lock file of a running job aside)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != pbc_train.RUN_LOCK}


def finished_run(out: Path) -> Path:
    """A run dir as a finished `pbc train` leaves it: .hydra/, the log, checkpoints, metrics.json."""
    (out / ".hydra").mkdir(parents=True)
    (out / ".hydra" / "config.yaml").write_text("loss:\n  norm: l1\n")
    (out / ".hydra" / "hydra.yaml").write_text("hydra:\n  job:\n    name: pbc-train\n")
    (out / ".hydra" / "overrides.yaml").write_text("- loss=l1\n")
    (out / "train.log").write_text("[INFO] epoch 3\n")
    (out / "checkpoints").mkdir()
    (out / "checkpoints" / "epoch_003.ckpt").write_bytes(b"weights")
    (out / "checkpoints" / "last.ckpt").write_bytes(b"weights and optimizer")
    (out / "metrics.json").write_text(json.dumps({"status": "ok", "test": {"vertex_error_cm": 2.5}}))
    return out


def test_a_refused_training_changes_no_file_of_another_run(tmp_path, monkeypatch, capsys, stop_at_data):
    monkeypatch.chdir(tmp_path)
    run = finished_run(tmp_path / "runs" / "ref_whole")
    before = tree_hash(run)
    refused = {
        "a new training in a finished run dir": ["loss=l2"],
        "a bad config": ["loss=l2", "model.patch_id=3.0"],
    }
    for why, overrides in refused.items():
        assert exit_code(train_main, [*overrides, f"hydra.run.dir={run}"]) == 2, why
        assert "error:" in capsys.readouterr().err, why
        assert tree_hash(run) == before, why

    # resuming the run but refused at the data (made with other settings): its record and config stay
    def other_data(cfg):
        raise ValueError("dataset made with other settings: data.num_samples 9 vs 6")

    monkeypatch.setattr(pbc_train, "datamodule", lambda cfg: object())
    monkeypatch.setattr(pbc_train, "check_opened_data", lambda cfg, dm: other_data(cfg))
    assert exit_code(train_main, ["loss=l2", "ckpt_path=last", f"hydra.run.dir={run}"]) == 2
    assert "other settings" in capsys.readouterr().err
    after = tree_hash(run)
    # a job resuming this run logs into the run's log (appended: the old lines stay); nothing else changes
    assert (run / "train.log").read_text().startswith("[INFO] epoch 3\n")
    assert {k: v for k, v in after.items() if k != "train.log"} == {k: v for k, v in before.items() if k != "train.log"}


def test_a_training_refused_while_another_runs_in_the_dir_changes_none_of_its_files(tmp_path, monkeypatch, capsys,
                                                                                     stop_at_data):
    monkeypatch.chdir(tmp_path)
    running = tmp_path / "runs" / "running"
    (running / ".hydra").mkdir(parents=True)
    (running / ".hydra" / "config.yaml").write_text("loss:\n  norm: l1\n")
    (running / ".hydra" / "overrides.yaml").write_text("- loss=l1\n")
    (running / "train.log").write_text("[INFO] epoch 0\n")
    before = tree_hash(running)
    with dir_lock(running / pbc_train.RUN_LOCK, "the first job"):  # the first training holds its dir
        for overrides in (["loss=l2"], ["loss=l2", "model.patch_id=3.0"], ["loss=l2", "ckpt_path=last"]):
            assert exit_code(train_main, [*overrides, f"hydra.run.dir={running}"]) == 2
            assert "error:" in capsys.readouterr().err
            assert tree_hash(running) == before, overrides  # no .hydra/ of the refused job, no failed record


def test_a_training_past_the_door_writes_its_hydra_config(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    def fit_and_test(cfg, out, t0, past_the_door=None):
        past_the_door(out)
        return {"val_best": {"vertex_error_cm": 1.0}, "optimized_metric": "val/vertex_error_cm"}

    monkeypatch.setattr(pbc_train, "fit_and_test", fit_and_test)
    run = tmp_path / "runs" / "new"
    assert exit_code(train_main, ["loss=l2", f"hydra.run.dir={run}"]) == 0
    assert (run / ".hydra" / "overrides.yaml").read_text().splitlines()[0] == "- loss=l2"
    assert "norm: l2" in (run / ".hydra" / "config.yaml").read_text()
    read_back = load_run(run, events=False)  # what pbc.runs and the report read of a run
    assert read_back.job == "train" and read_back.overrides.get("loss") == "l2"


# ============================================================================ full disks
def _trainer(ckpt_dir: Path, epochs: int) -> L.Trainer:
    nodes = load_config([]).callbacks  # the shipped preset: the best epoch_NNN.ckpt and last.ckpt
    callbacks = [instantiate(nodes[n], dirpath=str(ckpt_dir)) for n in ("model_checkpoint", "last_checkpoint")]
    return L.Trainer(max_epochs=epochs, callbacks=callbacks, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, accelerator="cpu", num_sanity_val_steps=0,
                     plugins=[pbc_train.AtomicCheckpointIO()])


def test_a_full_disk_during_training_keeps_the_last_complete_checkpoint_and_names_the_file(tmp_path, monkeypatch):
    ckpts = tmp_path / "run" / "checkpoints"
    _trainer(ckpts, 2).fit(ScriptedModule())
    assert torch.load(ckpts / "last.ckpt", weights_only=False)["epoch"] == 1

    write_bytes = Path.write_bytes

    def full_disk(self, data):  # the disk fills half-way through the next checkpoint
        write_bytes(self, bytes(memoryview(data)[: len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(DiskFull, match=r"checkpoint .*checkpoints/\S+\.ckpt: \d+\.\d [KM]iB needed(.|\n)*"
                                       r"ckpt_path=last") as err:
        _trainer(ckpts, 4).fit(ScriptedModule(), ckpt_path=ckpts / "last.ckpt")
    assert "Errno" not in str(err.value)
    # the previous complete files stay, no temporary file is left beside them
    assert sorted(p.name for p in ckpts.iterdir()) == ["epoch_001.ckpt", "last.ckpt"]
    assert torch.load(ckpts / "last.ckpt", weights_only=False)["epoch"] == 1
    monkeypatch.setattr(Path, "write_bytes", write_bytes)  # space freed: the run resumes from it
    trainer = _trainer(ckpts, 4)
    trainer.fit(ScriptedModule(), ckpt_path=ckpts / "last.ckpt")
    assert trainer.current_epoch == 4 and torch.load(ckpts / "last.ckpt", weights_only=False)["epoch"] == 3


def test_predict_on_a_disk_too_small_names_the_folder_and_the_bytes_and_leaves_whole_files(tmp_path, monkeypatch):
    from test_view import tiny_predictor

    from pbc.jobs.predict import predict_to_dir

    predictor = tiny_predictor(tmp_path / "fake")
    poses = torch.from_numpy(np.asarray(predictor.dataset.poses[:6])).float()
    out = tmp_path / "pred"
    free = {"bytes": 10**12}
    monkeypatch.setattr(pbc_io.shutil, "disk_usage", lambda p: SimpleNamespace(free=free["bytes"]))
    first = predict_to_dir(predictor, poses, [f"p{k}" for k in range(6)], out, sheet=0)
    mesh = (out / "meshes" / "p0.obj").stat().st_size
    free["bytes"] = 2 * mesh + pbc_io.free_space_margin()  # room for the first mesh, not for six
    with pytest.raises(DiskFull, match=rf"prediction output directory {out / 'again'}: .+ needed \(\d+\.\d KiB of "
                                       r"files \+ a 1\.0 MiB margin for the file system's blocks, conf/io.yaml\), "
                                       r".+ free; free space there or give another output folder"):
        predict_to_dir(predictor, poses, [f"p{k}" for k in range(6)], out / "again", sheet=0)
    assert sorted(p.name for p in (out / "again" / "meshes").iterdir()) == ["p0.obj"]  # checked after the first
    assert first["num_poses"] == 6

    # the disk fills during a write (the size was not known): the same one error, no half file
    free["bytes"] = 10**12
    real = np.save

    def full(file, arr, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "save", full)
    with pytest.raises(DiskFull, match=rf"prediction output directory {out / 'third'}; free space"):
        predict_to_dir(predictor, poses, [f"p{k}" for k in range(6)], out / "third", sheet=0)
    monkeypatch.setattr(np, "save", real)
    assert not list((out / "third").glob("*.npy")) and not list((out / "third").glob(".*"))


def test_a_full_disk_no_writer_named_is_one_line_with_the_file_the_space_and_the_fix(tmp_path):
    from pbc.cli.errors import one_line

    try:
        try:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out.png"))
        except OSError as inner:
            raise RuntimeError("savefig failed") from inner  # a library's wrapper, the errno two links down
    except RuntimeError as err:
        line = one_line(err)
    assert line.startswith(f"no space left on the device holding {tmp_path / 'out.png'} (") and "MiB free" in line
    assert "write the output elsewhere (--out" in line and "Errno" not in line


def test_body_export_on_a_full_disk_names_the_file(tmp_path, monkeypatch, capsys):
    from pbc.cli.body import main as body_main

    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full)
    assert exit_code(body_main, ["export", "--out", str(tmp_path / "body.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pbc body: error: no space left on the device holding body mesh {tmp_path / 'body.obj'}")
    assert "give --out a file on another disk" in err and not (tmp_path / "body.obj").exists()


def test_a_mistyped_key_of_any_command_names_the_key_meant(capsys):
    from pbc.cli.body import main as body_main

    assert exit_code(body_main, ["show", "body=anny", "body.phenotype.hight=0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("pbc body: error: unknown key body.phenotype.hight; did you mean body.phenotype.height? "
                   "(body.phenotype.height=0.5)")
    with pytest.raises(ValueError, match=r"unknown key sim.substep; did you mean sim.substeps\?"):
        load_config(["sim.substep=3"])


def test_garment_fit_into_a_read_only_folder_names_it_and_the_flag(tmp_path, monkeypatch):
    from pbc.jobs.garment_fit import Fit

    garment = tmp_path / "shirt.obj"
    garment.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    locked = tmp_path / "locked"
    locked.mkdir()
    monkeypatch.setattr(pbc_io.os, "access", lambda p, mode: Path(p) != locked)  # root writes anywhere
    with pytest.raises(PermissionError, match=rf"garment fit folder {locked / 'fit'} is not writable; give the fit "
                                              r"a writable folder with --out DIR"):
        Fit(garment, [], locked / "fit").inspect_and_check()
    assert not (locked / "fit").exists()


# ============================================================================ finite geometry
SQUARE = """# exported by Blender 4.2
o Cloth
v 0.0 0.0 0.0
v 0.1 0.0 0.0
v 0.1 0.1 0.0
v 0.0 0.1 0.0
vt 0.0 0.0
vt 1.0 0.0
vt 1.0 1.0
vt 0.0 1.0
vn 0.0 0.0 1.0
s 0
f 1/1/1 2/2/1 3/3/1 4/4/1
"""


@pytest.mark.parametrize(("line", "bad", "what"), [(4, "v nan nan nan", "vertex"),
                                                   (8, "vt 1.0 inf", "texture coordinate"),
                                                   (11, "vn 0.0 -nan 1.0", "normal")])
def test_a_non_finite_vertex_uv_or_normal_is_refused_naming_the_line(tmp_path, line, bad, what, capsys):
    from pbc.cli.garment import main as garment_main
    from pbc.geometry.meshio import read_obj

    lines = SQUARE.splitlines()
    lines[line - 1] = bad
    path = tmp_path / "shirt.obj"
    path.write_text("\n".join(lines) + "\n")
    (tmp_path / "ok.obj").write_text(SQUARE)
    assert read_obj(tmp_path / "ok.obj").vertices.shape == (4, 3)
    with pytest.raises(ValueError, match=rf"{path}: line {line}: the {what} .* is not finite \(NaN or inf\)"):
        read_obj(path)
    assert exit_code(garment_main, ["inspect", str(path)]) == 2  # the door users meet: one line, no table
    err = capsys.readouterr()
    assert f"line {line}: the {what}" in err.err and "not finite" in err.err and not err.out


def test_a_body_file_with_a_nan_is_refused_naming_the_array_and_row(tmp_path, body):
    from pbc.geometry.body.base import load_body, save_body

    save_body(body, tmp_path / "ok.npz")
    assert load_body(tmp_path / "ok.npz").vertices.shape == body.vertices.shape
    broken = body.vertices.clone()
    broken[7, 1] = float("nan")
    save_body(type(body)(**{**body.__dict__, "vertices": broken}), tmp_path / "nan.npz")
    with pytest.raises(ValueError, match=r"nan.npz: array 'vertices' is not finite \(NaN or inf\) in row\(s\) 7;"):
        load_body(tmp_path / "nan.npz")


def test_a_binary_file_given_as_an_obj_names_the_file(tmp_path, capsys):
    from pbc.cli.garment import main as garment_main

    path = tmp_path / "shirt.obj"
    path.write_bytes(bytes(range(256)) * 4)  # random bytes: not UTF-8
    assert exit_code(garment_main, ["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "not a text OBJ file" in err


# ============================================================================ bounds on work
def test_work_past_the_limits_is_refused_saying_how_much_and_the_override(tmp_path, monkeypatch, capsys):
    from pbc.cli.generate import main as generate_main
    from pbc.core.validate import check_config

    monkeypatch.chdir(tmp_path)
    assert exit_code(generate_main, ["data=tshirt_tiny", "data.num_samples=2000000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("pbc generate: error: data.num_samples=2000000 would drape and store 2,000,000 samples (one file "
                   "each while generating), over limits.max_samples=100000: if you meant it, add "
                   "limits.max_samples=2000000")
    assert not (tmp_path / "data").exists()
    with pytest.raises(ValueError, match=r"image.patch_resolution=8192 would make images of 8192 x 8192 pixels "
                                         r"\(1.5 GiB .*add limits.max_image_resolution=8192"):
        check_config(load_config(["image.patch_resolution=8192"]))
    # the override given goes on; the shipped paper scale is inside the limits
    check_config(load_config(["image.patch_resolution=8192", "limits.max_image_resolution=8192"]))
    check_config(load_config(["data=tshirt_paper", "+scale=paper"]))
    with pytest.raises(Exception, match=r"\+scale=paper"):  # a group: Hydra's "+" advice is the right one
        load_config(["scale=paper"])


# ============================================================================ the viewer on the network
def test_a_viewer_serving_the_network_warns_in_one_line_and_gives_the_address_to_open(tmp_path):
    from test_view import tiny_predictor

    from pbc.jobs.view import machine_address, start_viewer, url

    predictor = tiny_predictor(tmp_path / "fake")
    for host, warned in (("0.0.0.0", True), ("127.0.0.1", False)):
        said: list[str] = []
        viewer = start_viewer(predictor, host, 0, log=said.append)
        try:
            link = url(viewer)
        finally:
            viewer.close()
            viewer.server.stop()
        warnings = [s for s in said if "reachable from the network" in s]
        assert len(warnings) == (1 if warned else 0), said
        assert "0.0.0.0" not in link
        if warned:
            assert "\n" not in warnings[0] and "no login" in warnings[0]
            assert warnings[0].endswith(f"open http://{machine_address()}:{viewer.server.get_port()}/")
            assert link == f"http://{machine_address()}:{viewer.server.get_port()}/"
        else:
            assert link.startswith("http://localhost:")


# ============================================================================ messages
def test_a_shipped_models_corrupt_weights_advise_reinstalling_not_an_epoch_it_lacks(tmp_path, monkeypatch):
    import pbc.pretrained
    from pbc.inference.predictor import load_decoder

    shipped = tmp_path / "pretrained"
    weights = shipped / "tshirt" / "checkpoints" / "weights_fp16.ckpt"
    weights.parent.mkdir(parents=True)
    (shipped / "tshirt" / "metrics.json").write_text("{}")
    weights.write_bytes(b"PK\x03\x04 truncated")
    monkeypatch.setattr(pbc.pretrained, "SHIPPED_DIR", shipped)
    with pytest.raises(ValueError, match=r"weights_fp16.ckpt is corrupt or truncated .* shipped with pbc, damaged on "
                                         r"disk: reinstall pbc .*pbc pretrained pack RUN --name tshirt") as err:
        load_decoder(weights)
    assert "epoch_" not in str(err.value)
    own = tmp_path / "run" / "checkpoints" / "last.ckpt"  # a trained run's: its other checkpoints are the fix
    own.parent.mkdir(parents=True)
    own.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match=r"resume from another checkpoint of the run \(checkpoints/epoch_\*.ckpt\)"):
        load_decoder(own)


def test_the_datasets_space_check_asks_for_what_the_merge_writes(tmp_path, monkeypatch):
    """A body of 20,000 vertices: its npz takes its arrays' bytes; the old guess counted every scene array x4
    (3.4x the real size) and refused disks with room ("3.1 MiB needed, 3.9 MiB free")."""
    from test_data_faults import _big_disk, _fake_run

    import pbc.data.generate as gen

    out, args = _fake_run(tmp_path, monkeypatch)
    scene = args[6]
    scene.body.vertices = np.ones((20000, 3), np.float32)
    scene.body.weights = np.ones((20000, 11), np.float32)

    def save_body(body, path):
        with pbc_io.atomic_path(path, suffix=".npz") as tmp:
            np.savez(tmp, vertices=body.vertices, weights=body.weights)

    monkeypatch.setattr(gen, "save_body", save_body)
    monkeypatch.setattr(pbc_io.shutil, "disk_usage", _big_disk())
    asked = []
    real_check = gen.require_free_space
    monkeypatch.setattr(gen, "require_free_space", lambda path, needed, *a: asked.append(needed) or
                        real_check(path, needed, *a))
    gen.merge(*args)
    written = sum(p.stat().st_size for p in out.iterdir() if p.is_file())
    assert written <= asked[0] <= 1.05 * written, (asked, written)
    assert not (out / "work" / ".size_probe").exists()


def test_evaluate_and_edit_on_a_full_disk_name_their_folder(tmp_path, monkeypatch, capsys):
    import pbc.cli.edit
    import pbc.cli.evaluate

    def full_disk(*args, **kwargs):
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError as err:
            raise RuntimeError("savefig failed") from err  # as matplotlib wraps it

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(pbc.cli.edit, "run_edit", full_disk)
    assert exit_code(pbc.cli.edit.main, ["--out", str(tmp_path / "e")]) == 2
    assert capsys.readouterr().err.startswith(f"pbc edit: error: no space left on the device holding edit output "
                                              f"directory {tmp_path / 'e'}")
    monkeypatch.setattr(pbc.cli.evaluate, "evaluate", full_disk)
    assert exit_code(pbc.cli.evaluate.main, ["whole_run=x", "patch_runs=null", f"hydra.run.dir={tmp_path / 'v'}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pbc evaluate: error: no space left on the device holding evaluation dir {tmp_path / 'v'}")
    assert "hydra.run.dir" in err


def test_a_run_stopped_by_a_full_disk_reports_that_not_its_failed_record(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)

    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    def fit_and_test(cfg, out, t0, past_the_door=None):
        past_the_door(out)
        monkeypatch.setattr(Path, "write_text", full)  # the disk is full: no room for metrics.json either
        raise DiskFull(f"no space left on the device holding checkpoint {out}/checkpoints/last.ckpt: 1.0 MiB "
                       "needed, 0 B free; free space there and run the same command with ckpt_path=last")

    monkeypatch.setattr(pbc_train, "fit_and_test", fit_and_test)
    assert exit_code(train_main, [f"hydra.run.dir={tmp_path / 'run'}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("pbc train: error: no space left on the device holding checkpoint ")
    assert err[-1].endswith("ckpt_path=last")


# ================================================================== the reliability battery's unclear cases
def _unwritable(tmp_path: Path) -> Path:
    """A folder no user can write in: read-only, or (root writes anywhere) one below a regular file."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.access(ro, os.W_OK):  # root
        (tmp_path / "file.txt").write_text("a file where a folder would be")
        return tmp_path / "file.txt" / "sub"
    return ro


@pytest.mark.parametrize("command", ["motion", "garment", "body"])
def test_an_out_folder_that_cannot_be_written_is_named_up_front(tmp_path, capsys, command):
    from pbc.cli.body import main as body_main
    from pbc.cli.garment import main as garment_main
    from pbc.cli.motion import main as motion_main

    bad = _unwritable(tmp_path)
    garment = tmp_path / "shirt.obj"
    garment.write_text(SQUARE)
    clip = Path(__file__).resolve().parents[1] / "data" / "bvh" / "cmu_mb_02_01_walk.bvh"
    main, argv = {"motion": (motion_main, ["inspect", str(clip), "--out", str(bad / "x.png")]),
                  "garment": (garment_main, ["inspect", str(garment), "--out", str(bad)]),
                  "body": (body_main, ["export", "--out", str(bad / "body.obj")])}[command]
    assert exit_code(main, argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{bad}:" in err and "give --out a" in err
    assert ".part" not in err and "Errno" not in err and ".body.obj." not in err


def test_an_obj_with_a_latin1_comment_reads_other_formats_and_folders_are_named(tmp_path):
    from pbc.geometry.meshio import read_obj

    latin = tmp_path / "jacke.obj"
    latin.write_bytes(SQUARE.replace("# exported by Blender 4.2", "# Jacke f\xfcr Anny").encode("latin-1"))
    assert read_obj(latin).vertices.shape == (4, 3)
    mesh = trimesh.creation.box()
    mesh.export(tmp_path / "box.ply")
    ply = tmp_path / "box_ply.obj"
    ply.write_bytes((tmp_path / "box.ply").read_bytes())
    with pytest.raises(ValueError, match=r"box_ply.obj: this is a PLY file, not an OBJ: trimesh reads it: 8 vertices, "
                                         r"12 faces, so convert it with `python -c .*file_type='ply'"):
        read_obj(ply)
    stl = tmp_path / "box.stl"
    mesh.export(stl)
    with pytest.raises(ValueError, match=r"box.stl: this is an STL file, not an OBJ, and an STL holds no UVs"):
        read_obj(stl)
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "top.obj").write_text(SQUARE)
    with pytest.raises(ValueError, match=r"folder is a folder, not a file; it holds top.obj: give one of them"):
        read_obj(tmp_path / "folder")
    junk = tmp_path / "junk.obj"
    junk.write_text(SQUARE.replace("v 0.1 0.0 0.0", "v0.1 0.0 0.0"))
    with pytest.raises(ValueError, match=r"junk.obj: line 4: 'v0.1 0.0 0.0' is not an OBJ statement"):
        read_obj(junk)
    vendor = tmp_path / "vendor.obj"
    vendor.write_text(SQUARE.replace("s 0", "shadow_obj shadow.obj\nmytool_tag 7"))  # harmless keywords: ignored
    assert read_obj(vendor).faces.shape == (2, 3)


def test_a_dataset_of_other_settings_names_the_setting_and_an_empty_refused_one_is_removed(tmp_path, monkeypatch):
    import pbc.data.generate as pbc_generate
    from pbc.cli.generate import generate_job
    from pbc.data.generate import _cheap_fingerprint, garment_from_config, generate

    data = tmp_path / "ds"
    (data / "work").mkdir(parents=True)
    cfg = load_config(["data=tshirt_tiny", f"data.dir={data}"])
    (data / "work" / "fingerprint.json").write_text(json.dumps(_cheap_fingerprint(
        cfg, garment_from_config(cfg.garment, None)[0])))
    other = load_config(["data=tshirt_tiny", f"data.dir={data}", "sim.reuse_model=false"])
    with pytest.raises(ValueError) as err:  # the library's own refusal, as every caller (training's too) gets it
        generate(other)
    assert str(err.value) == (
        f"{data} holds a dataset made with other settings (sim.reuse_model true there, false here): give "
        f"sim.reuse_model=true to go on with it, make a new dataset elsewhere (data.name=NAME or data.dir=DIR), or "
        f"delete {data} to make it again")
    def refused(cfg):  # refused inside the dataset's lock (which made the folder), before any drape
        (data_dir := Path(cfg.data.dir) / "work" / "samples").mkdir(parents=True, exist_ok=True)
        assert data_dir.is_dir()
        raise ValueError("the clips of data.poses are refused")

    monkeypatch.setattr(pbc_generate, "_generate", refused)
    fresh = tmp_path / "fresh"
    with pytest.raises(ValueError, match="refused"):
        generate_job(load_config(["data=tshirt_tiny", f"data.dir={fresh}"]))
    assert not fresh.exists()
    with pytest.raises(ValueError, match="refused"):  # a folder it did not create stays
        generate_job(load_config(["data=tshirt_tiny", f"data.dir={data}"]))
    assert (data / "work" / "fingerprint.json").is_file()


def test_a_fit_refused_before_a_drape_lets_a_corrected_retry_in_and_one_with_drapes_is_kept(tmp_path):
    from pbc.jobs.garment_fit import RECORD, Fit

    garment = tmp_path / "shirt.obj"
    garment.write_text(SQUARE)
    out = tmp_path / "fit"
    refused = Fit(garment, ["sim.fps=10"], out)
    out.mkdir()
    (out / RECORD).write_text(json.dumps({"asked": refused.asked, "overrides": []}))
    assert Fit(garment, ["sim.fps=20"], out)._recorded() is None  # no drape made: the corrected retry goes on
    (out / "data" / "work" / "samples").mkdir(parents=True)
    (out / "data" / "work" / "samples" / "000000.npz").write_bytes(b"a drape")
    with pytest.raises(ValueError, match=r"holds the fit of another garment or other settings \(overrides"):
        Fit(garment, ["sim.fps=20"], out)._recorded()


def test_made_on_rest_keys_are_named_under_the_garment_with_the_key_meant():
    from pbc.core.validate import check_config

    with pytest.raises(ValueError, match=r"garment.made_on_rest.arm_angel_deg: unknown key; did you mean "
                                         r"garment.made_on_rest.arm_angle_deg\?"):
        check_config(load_config(["body=anny", "garment.made_on_rest={arm_angel_deg:0}"]))
    with pytest.raises(ValueError, match=r"garment.made_on_rest.arm_angle_deg='abc' \(str\): expected a number"):
        check_config(load_config(["body=anny", "garment.made_on_rest={arm_angle_deg:abc}"]))
    check_config(load_config(["body=anny", "garment.made_on_rest={arm_angle_deg:10}"]))


def test_the_stop_grace_and_the_free_space_margin_are_read_from_conf(tmp_path, monkeypatch):
    from pbc.core import stops

    assert stops.stop_settings() == {"grace_s": 10.0, "kill_wait_s": 5.0}
    bad = tmp_path / "stops.yaml"
    bad.write_text("grace_s: -1\nkill_wait_s: 5\n")
    monkeypatch.setattr(stops, "STOPS_FILE", bad)
    stops.stop_settings.cache_clear()
    try:
        with pytest.raises(ValueError, match=r"stops.yaml: grace_s=-1 \(int\): expected a number in \(0, 600\]"):
            stops.stop_settings()
    finally:
        stops.stop_settings.cache_clear()
    monkeypatch.setattr(pbc_io.shutil, "disk_usage", lambda p: SimpleNamespace(free=2_000_000))
    # 1.9 MiB asked for and 1.9 MiB free when rounded: the bytes say which is more
    with pytest.raises(DiskFull, match=r": 2,005,299 B needed \(934\.3 KiB of files \+ a 1\.0 MiB margin for the "
                                       r"file system's blocks, conf/io.yaml\), 2,000,000 B free; free space there"):
        pbc_io.require_free_space(tmp_path, 956_723, "dataset")
