"""Dataset generation: a finished tiny dataset, resume after a kill, shards, refusals of bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_SAMPLES as N
from conftest import tiny_overrides
from helpers.generate_runs import tiny_cfg
from helpers.processes import alive, descendants

from pbc.core.config import load_config
from pbc.data.dataset import load_dataset
from pbc.data.generate import generate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def reference(tiny_dataset: Path) -> Path:
    """The session's uninterrupted run (2 workers), the yardstick for the resumed and sharded ones."""
    return tiny_dataset


def test_finished_dataset_is_complete(reference: Path):
    ds = load_dataset(reference)
    m = ds.manifest
    assert m["counts"]["requested"] == N
    assert m["counts"]["kept"] + sum(m["counts"]["discarded"].values()) == N
    assert len(ds) == m["counts"]["kept"] > 0
    assert ds.poses.shape == (len(ds), 10, 3, 3)
    assert ds.verts.shape == (len(ds), ds.garment.vertices.shape[0], 3)
    assert np.isfinite(ds.verts).all()
    splits = [set(ds.split(s).tolist()) for s in ("train", "val", "test")]
    assert set().union(*splits) == set(range(len(ds))) and sum(map(len, splits)) == len(ds)
    assert not (reference / "work").exists()
    # every kept sample reached static equilibrium
    assert m["drape_residual"]["max"] < float(load_config(["data=tshirt_tiny"]).sim.tolerance)


def test_resume_after_sigkill_is_byte_identical(reference: Path, tmp_path: Path):
    cfg_args = tiny_overrides(tmp_path, "data.workers=1")
    proc = subprocess.Popen([sys.executable, "-m", "pbc.generate", *cfg_args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    out = Path(load_config(cfg_args).data.dir)
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if len(list((out / "work" / "samples").glob("[0-9]*.npz"))) >= 2:
            break
        time.sleep(0.2)
    assert proc.poll() is None, "generation finished before it could be killed; raise N"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "manifest.json").exists()
    done_before = len(list((out / "work" / "samples").glob("[0-9]*.npz")))
    assert 2 <= done_before < N

    generate(load_config(cfg_args))
    for name in ("poses.npy", "verts.npy", "manifest.json", "embedding.npz", "garment.obj", "cage.json"):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name


def test_sigterm_stops_the_drape_workers_with_their_job(tmp_path: Path):
    # a killed job (kill, a scheduler's cancel) left its two drape workers draping on as orphans for half an hour
    cfg_args = tiny_overrides(tmp_path, "data.workers=2")
    proc = subprocess.Popen([sys.executable, "-m", "pbc.generate", *cfg_args], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    out = Path(load_config(cfg_args).data.dir)
    deadline, workers = time.time() + 240, set()
    # both workers started and one drape written: the next drapes are under way, as when a job is cancelled
    while time.time() < deadline and proc.poll() is None and (
            len(workers) < 2 or not list((out / "work" / "samples").glob("[0-9]*.npz"))):
        workers = {p for p in descendants(proc.pid)
                   if "multiprocessing.spawn" in Path(f"/proc/{p}/cmdline").read_text()}
        time.sleep(0.2)
    assert proc.poll() is None and len(workers) >= 2, "the drape workers never started"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    deadline = time.time() + 15
    while time.time() < deadline and any(alive(p) for p in workers):
        time.sleep(0.2)
    assert not [p for p in workers if alive(p)], "drape workers outlived their killed job"


def test_shards_then_merge_equal_single_run(reference: Path, tmp_path: Path):
    args = ["data.num_shards=2", "data.workers=1"]
    for shard in (0, 1):
        generate(tiny_cfg(tmp_path, *args, f"data.shard={shard}"))
    out = Path(tiny_cfg(tmp_path).data.dir)
    assert not (out / "manifest.json").exists()  # shards never merge on their own
    generate(tiny_cfg(tmp_path, *args))
    for name in ("poses.npy", "verts.npy"):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name


def test_existing_dir_with_other_seed_is_refused(reference: Path):
    cfg = tiny_cfg(reference.parent, f"data.dir={reference}", "data.seed=1")
    with pytest.raises(ValueError, match=r"other settings \(data.seed \d+ there, \d+ here\)"):
        generate(cfg)


def test_corrupt_array_gets_clear_error(reference: Path, tmp_path: Path):
    broken = tmp_path / "broken"
    broken.mkdir()
    for f in reference.iterdir():
        if f.is_file():
            (broken / f.name).write_bytes(f.read_bytes())
    data = (broken / "verts.npy").read_bytes()
    (broken / "verts.npy").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="verts.npy.*(corrupt|truncated)"):
        load_dataset(broken)
    (broken / "manifest.json").write_text("{not json")
    with pytest.raises(ValueError, match="manifest.*corrupt"):
        load_dataset(broken)


def test_manifest_records_provenance(reference: Path):
    m = json.loads((reference / "manifest.json").read_text())
    for key in ("format_version", "seed", "garment_hash", "body_hash", "splits", "counts", "shrinkwrap"):
        assert key in m
    assert json.loads((reference / "timings.json").read_text())["drape_wall"] > 0
    # single-world datasets (sim.batch_size=1) keep the fingerprint they had before batching existed
    assert not any(k.startswith("batch_") for k in m["sim"])




def _running(pid: int) -> bool:
    """Whether process pid exists and is not a zombie (Linux: /proc/<pid>/stat's state)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


def test_stop_terminates_a_worker_in_the_middle_of_a_job():
    # ProcessPoolExecutor.shutdown empties `_processes` (Python 3.11): _stop read them after it and terminated none
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from pbc.data.generate import _stop

    ex = ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"))
    fut = ex.submit(time.sleep, 120)
    deadline = time.time() + 60
    while time.time() < deadline and not fut.running():
        time.sleep(0.1)
    procs = list(ex._processes.values())
    assert fut.running() and procs
    pids = [p.pid for p in procs]
    _stop(ex)
    for p in procs:
        p.join(10)
    # asked of the OS, not of the Process objects: the pool's own thread may reap a worker first, and then
    # `is_alive` (waitpid failing with ECHILD) says True of a process that is gone
    assert not any(_running(pid) for pid in pids), "a worker in the middle of a job outlived _stop"
