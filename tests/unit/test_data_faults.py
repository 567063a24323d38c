"""The data side of scale-out: the drape's worker processes inside a launcher's worker, training
that waits for the job making its data, a full disk during the merge, and the operator cache when the
dataset's disk is full. Synthetic: no drape, no command in a subprocess (the integration twins are in
tests/integration/test_scaleout.py)."""

from __future__ import annotations

import errno
import json
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pbc.core.io
from pbc.core.config import load_config
from pbc.core.io import DiskFull, LockHeld, dir_lock, write_text


# ============================================================================ drape workers
def _abs_in_two_workers(values: list[int]) -> list[int]:
    from pbc.data.generate import map_in_workers

    return sorted(map_in_workers(abs, values, 2))


def test_drape_workers_start_inside_a_joblib_worker():
    """A Hydra joblib launcher runs each job in a loky worker, whose global start method is 'loky': drape
    workers spawned there died with "cannot find context for 'loky'" (and multiprocessing.Pool respawned
    them forever). map_in_workers starts them with an explicit context that works there."""
    from joblib import Parallel, delayed

    # two jobs: with n_jobs=1 joblib runs in this process, not in a loky worker
    out = Parallel(n_jobs=2, backend="loky", timeout=120)(delayed(_abs_in_two_workers)([-3, 1, -j]) for j in (2, 4))
    assert out == [[1, 2, 3], [1, 3, 4]]


def test_a_drape_worker_that_cannot_start_fails_fast_with_its_error():
    """A worker whose scene cannot be built (here: an empty config) raises that error in the parent at
    once, instead of being restarted forever."""
    from omegaconf.errors import ConfigAttributeError

    from pbc.data.generate import _init_worker, _work, map_in_workers

    jobs = [(i, np.eye(3, dtype=np.float32)[None].repeat(10, 0), "/nonexistent/x.npz") for i in range(6)]
    t0 = time.monotonic()
    with pytest.raises(ConfigAttributeError, match="body"):
        list(map_in_workers(_work, jobs, 2, _init_worker, ("{}", 1)))
    assert time.monotonic() - t0 < 120  # not an endless respawn; the bound is only a hang guard


# ============================================================================ training waits for the data
def _hold_then_finish(out: Path, seconds: float, held: threading.Event, finish: bool = True) -> None:
    """Another generator: holds the dataset's lock for `seconds`, then (finish) leaves a finished manifest."""
    with dir_lock(out / ".generate.lock", f"dataset {out}"):
        held.set()
        time.sleep(seconds)
        if finish:
            write_text(out / "manifest.json", "{}")


def test_training_waits_for_the_job_making_its_data(tmp_path, monkeypatch, caplog):
    import pbc.data.generate as gen
    from pbc.jobs.train import ensure_dataset

    cfg = load_config(["data=tshirt_tiny", f"paths.data_dir={tmp_path}", "data.lock_wait_s=60"])
    out = Path(cfg.data.dir)
    seen = []  # what _generate found when ensure_dataset went on: the other job's finished data
    monkeypatch.setattr(gen, "_generate", lambda c: seen.append((out / "manifest.json").is_file()) or out)
    held = threading.Event()
    t = threading.Thread(target=_hold_then_finish, args=(out, 1.0, held))
    t.start()
    held.wait()
    with caplog.at_level("INFO"):
        assert ensure_dataset(cfg) == out
    t.join()
    assert seen == [True]
    assert "waiting for it to finish (at most 60 s, data.lock_wait_s)" in caplog.text


def test_training_stops_waiting_after_lock_wait_s_naming_the_setting(tmp_path, monkeypatch):
    import pbc.data.generate as gen
    from pbc.jobs.train import ensure_dataset

    cfg = load_config(["data=tshirt_tiny", f"paths.data_dir={tmp_path}", "data.lock_wait_s=0.5"])
    out = Path(cfg.data.dir)
    monkeypatch.setattr(gen, "_generate", lambda c: pytest.fail("went on while the lock was held"))
    held = threading.Event()
    t = threading.Thread(target=_hold_then_finish, args=(out, 3.0, held, False))
    t.start()
    held.wait()
    try:
        with pytest.raises(LockHeld, match=r"still after waiting 0 s \(data.lock_wait_s\).*raise data.lock_wait_s"):
            ensure_dataset(cfg)
    finally:
        t.join()


# ============================================================================ full disk during the merge
NAMES = [f"j{i}" for i in range(10)]


def _fake_run(tmp_path: Path, monkeypatch, n: int = 4, missing: tuple[int, ...] = ()):
    """A dataset dir whose work/ holds `n` drape results (but `missing`), and what merge() reads of a scene;
    the scene's writers are stubbed with small text files (their formats are tested elsewhere)."""
    import pbc.data.generate as gen

    out = tmp_path / "ds"
    rng = np.random.default_rng(0)
    for i in range(n):
        if i in missing:
            continue
        meta = {"ok": True, "reason": "", "residual": 0.01, "t_skin": 0.1, "t_drape": 1.0}
        p = out / "work" / "samples" / f"{i:06d}.npz"
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez(p, positions=rng.normal(size=(50, 3)).astype(np.float32), meta=np.array(json.dumps(meta)))
    for name in ("save_garment_obj", "save_cage", "save_body", "save_embedding"):
        monkeypatch.setattr(gen, name, lambda obj, path: write_text(path, "stub\n"))
    arr = np.zeros((5, 3), np.float32)
    scene = SimpleNamespace(garment=SimpleNamespace(vertices=arr, faces=arr, uv=arr), cage=None,
                            body=SimpleNamespace(vertices=arr, faces=arr, weights=arr,
                                                 skeleton=SimpleNamespace(names=NAMES)),
                            embedding=SimpleNamespace(face=arr, bary=arr))
    poses = np.tile(np.eye(3, dtype=np.float32), (n, 10, 1, 1))
    args = (out, poses, np.zeros((n, 10, 3), np.float32), {"seed": 0, "num_samples": n}, {}, {}, scene, {})
    return out, args


def _big_disk(total=10**12, used=0, free=10**12):
    return lambda path: SimpleNamespace(total=total, used=used, free=free)


def test_merge_refuses_a_disk_too_small_before_writing_anything(tmp_path, monkeypatch):
    from pbc.data.generate import merge

    out, args = _fake_run(tmp_path, monkeypatch)
    full = SimpleNamespace(total=10**9, used=10**9, free=1000)
    monkeypatch.setattr(pbc.core.io.shutil, "disk_usage", lambda path: full)
    with pytest.raises(DiskFull, match=rf"no space left on the device holding dataset {out}: .* needed .*, 1000 B "
                                       "free; free space there .*paths.data_dir.* the drapes in work/ are kept"):
        merge(*args)
    assert sorted(p.name for p in out.iterdir()) == ["work"]  # nothing written, the drapes kept


def test_disk_full_during_the_merge_is_one_named_error_and_no_half_dataset(tmp_path, monkeypatch):
    """The disk fills up while verts.npy is written: numpy's OSError (chained inside its writer) becomes one
    DiskFull naming the dataset and the bytes; the files already merged are removed, no temp file is left,
    and work/ stays, so the same command merges again once there is room."""
    from pbc.data.generate import merge

    out, args = _fake_run(tmp_path, monkeypatch)
    monkeypatch.setattr(pbc.core.io.shutil, "disk_usage", _big_disk())
    real_save = np.save

    def fail_verts(file, arr, *a, **k):
        if ".verts.npy." in str(file):
            real_save(file, arr[:1])  # part of it reached the disk
            try:
                raise OSError(errno.ENOSPC, "No space left on device")
            except OSError as e:
                raise RuntimeError("np.save failed") from e  # the OSError arrives chained, one link down
        return real_save(file, arr, *a, **k)

    monkeypatch.setattr(pbc.core.io.np, "save", fail_verts)
    with pytest.raises(DiskFull) as exc:
        merge(*args)
    msg = str(exc.value)
    assert msg.startswith(f"no space left on the device holding dataset {out}: ") and " needed" in msg
    assert exc.value.__cause__ is None and exc.value.__suppress_context__  # one error, not three tracebacks
    assert sorted(p.name for p in out.iterdir()) == ["work"]  # garment.obj ... poses.npy removed, no temp file
    assert len(list((out / "work" / "samples").glob("*.npz"))) == 4

    monkeypatch.setattr(pbc.core.io.np, "save", real_save)  # room again: the same merge finishes
    merge(*args)
    assert (out / "manifest.json").is_file() and np.load(out / "verts.npy").shape == (4, 50, 3)


def test_merge_names_the_unfinished_shard(tmp_path, monkeypatch):
    from pbc.data.generate import merge

    out, args = _fake_run(tmp_path, monkeypatch, n=6, missing=(3, 5))
    with pytest.raises(RuntimeError, match=r"2 of 6 samples are missing \(shard 1 of 2: 2 missing "
                       r"\(first \[3, 5\]\)\); run the unfinished shard\(s\) again \(data.shard=1 "):
        merge(*args, batch=1, num_shards=2)
    assert not (out / "manifest.json").exists()


# ============================================================================ operator cache on a full disk
@pytest.fixture(scope="module")
def coarse_garment():
    from pbc.geometry.garment.tshirt import make_tshirt

    return make_tshirt(load_config(["data=tshirt_tiny"]).garment)[0]


def _dataset_disk_full(monkeypatch, dataset: Path) -> None:
    """The dataset's disk is full but writable (os.access says yes): every write under it fails."""
    import pbc.pixels.operators as ops

    real = ops.atomic_path

    def atomic_path(path, suffix=""):
        if Path(path).is_relative_to(dataset):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, suffix)

    monkeypatch.setattr(ops, "atomic_path", atomic_path)


def test_operator_cache_goes_to_pbc_cache_dir_when_the_dataset_disk_is_full(coarse_garment, tmp_path, monkeypatch,
                                                                             recwarn):
    from pbc.pixels.operators import load_or_build

    dataset = tmp_path / "dataset"
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "user"))
    _dataset_disk_full(monkeypatch, dataset)
    a = load_or_build(coarse_garment, 32, 2, True, dataset / "operators")
    (f,) = (tmp_path / "user" / "operators").glob("operators_*.npz")  # cached where PBC_CACHE_DIR says
    built = f.stat().st_mtime_ns
    b = load_or_build(coarse_garment, 32, 2, True, dataset / "operators")
    assert f.stat().st_mtime_ns == built and np.array_equal(a["R_data"], b["R_data"])  # read back, not rebuilt
    assert not [w for w in recwarn if "cannot cache operators" in str(w.message)]  # nothing to warn about


def test_operator_cache_warns_once_when_no_place_has_room(coarse_garment, tmp_path, monkeypatch, recwarn):
    from pbc.pixels.operators import load_or_build

    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "user"))
    _dataset_disk_full(monkeypatch, tmp_path)  # the user cache is on the same full disk
    for _ in range(3):
        load_or_build(coarse_garment, 32, 2, True, tmp_path / "dataset" / "operators")
    warned = [str(w.message) for w in recwarn if "cannot cache operators" in str(w.message)]
    assert len(warned) == 1 and str(tmp_path / "user" / "operators") in warned[0] and "PBC_CACHE_DIR" in warned[0]
