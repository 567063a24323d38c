"""The scale-out path run for real on one machine (each test: commands in subprocesses on tiny data).

- a joblib multirun of two patch trainings on a machine without the dataset: one job makes the data (its
  drape workers are processes started inside a loky worker), the other waits for it, both train;
- Hydra's submitit launcher in its local mode (the SLURM code path without the scheduler): a 2-shard
  pbc.generate with one shard SIGKILLed, reported by name, finished by a re-run, merged byte for byte
  equal to the session's unsharded run; and a 2-job smoke training sweep;
- `trainer=ddp` on 2 CPU processes (gloo): one metrics.json and one checkpoint set, from rank 0.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from conftest import tiny_overrides

from pbc.core.config import load_config
from pbc.data.generate import generate

ROOT = Path(__file__).resolve().parents[2]
SMOKE = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128"]


def _pbc(*args: str, timeout: float = 540) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _metrics(sweep: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(sweep.glob("*/metrics.json"))]


def test_joblib_multirun_from_nothing_makes_the_data_once_and_trains_every_job(tmp_path):
    """The issue's command: `pbc.train -m +experiment=patch_00,patch_01 hydra/launcher=joblib` with no dataset
    (data.workers=2, the default: the drape's worker processes start inside a loky worker)."""
    data, sweep = tmp_path / "data", tmp_path / "sweep"
    r = _pbc("pbc.train", "-m", "+experiment=patch_00,patch_01", "data=tshirt_tiny", "data.num_samples=5",
             "data.workers=2", *SMOKE, f"paths.data_dir={data}", f"hydra.sweep.dir={sweep}",
             "hydra/launcher=joblib", "hydra.launcher.n_jobs=2")
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-4000:]
    assert "cannot find context" not in out
    runs = _metrics(sweep)
    assert [m["status"] for m in runs] == ["ok", "ok"], out[-3000:]
    logs = "".join(p.read_text() for p in sweep.glob("*/train.log"))
    assert logs.count("drape (2 workers): 0/5") == 1  # the data was made once, by one job
    assert logs.count("waiting for it to finish") == 1  # the other job waited for it, then trained on it
    assert {m["data"]["dir"] for m in runs} == {str((data / "tshirt_tiny_seed0").resolve())}
    assert len({m["data"]["fingerprint"]["manifest_hash"] for m in runs}) == 1


def test_submitit_local_shards_survive_a_sigkill_and_merge_byte_for_byte(tiny_dataset, tmp_path):
    """`pbc.generate -m ... data.num_shards=2 'data.shard=range(0,2)' hydra/launcher=submitit_local`; shard 1
    is SIGKILLed mid-drape: the sweep fails (submitit names the job), the same sweep again finishes it (shard 1
    says by name that it resumes; shard 0 has nothing to redo), and the merge's arrays and manifest equal the
    session's unsharded run byte for byte."""
    over = tiny_overrides(tmp_path / "data", "data.workers=1", "data.num_shards=2")
    sweep = [*over, "data.shard=range(0,2)", "hydra/launcher=submitit_local", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    out = Path(load_config(over).data.dir)
    lock, first = out / ".generate-shard1.lock", out / "work" / "samples" / "000001.npz"
    proc = subprocess.Popen([sys.executable, "-m", "pbc.generate", "-m", *sweep], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    deadline, pid = time.time() + 300, None
    while time.time() < deadline and proc.poll() is None and pid is None:
        if first.is_file() and lock.is_file() and lock.read_text().startswith("pid "):
            pid = int(lock.read_text().split()[1])  # shard 1's job, once it has made one sample
        time.sleep(0.1)
    assert pid is not None, "shard 1 finished (or never started) before it could be killed"
    os.kill(pid, signal.SIGKILL)
    log, _ = proc.communicate(timeout=300)
    assert proc.returncode != 0, log[-3000:]
    assert "UncompletedJobError" in log  # submitit reports the killed job

    r = _pbc("pbc.generate", "-m", *sweep)  # the same sweep again: shard 1 resumes, shard 0 has nothing to do
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    logs = "".join(p.read_text(errors="replace") for p in (tmp_path / "sweep").rglob("*.log"))
    assert re.search(r"shard 1 of 2: resuming, [1-4] of its 5 batches already made", logs), logs[-3000:]
    assert "shard 0 of 2: resuming" not in logs
    generate(load_config(over))  # merge
    for name in ("poses.npy", "verts.npy", "manifest.json", "embedding.npz", "garment.obj", "cage.json"):
        assert (out / name).read_bytes() == (tiny_dataset / name).read_bytes(), name
    assert not (out / "work").exists()


def test_submitit_local_runs_a_two_job_smoke_training_sweep(tiny_dataset, tmp_path):
    sweep = tmp_path / "sweep"
    r = _pbc("pbc.train", "-m", "+experiment=patch_00,patch_01", *tiny_overrides(tiny_dataset.parent), *SMOKE,
             f"hydra.sweep.dir={sweep}", "hydra/launcher=submitit_local")
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    runs = _metrics(sweep)
    assert [m["status"] for m in runs] == ["ok", "ok"]
    assert sorted(m["summary"]["patch_id"] for m in runs) == [0, 1]
    assert len(list((sweep / ".submitit").glob("*/*_result.pkl"))) == 2  # both went through submitit


def test_ddp_on_two_cpu_processes_writes_one_record_from_rank_zero(tiny_dataset, tmp_path):
    """`trainer=ddp trainer.accelerator=cpu trainer.devices=2 trainer.sync_batchnorm=false` (SyncBatchNorm is
    GPU-only): Lightning starts rank 1 as a second
    `python -m pbc.train` in the same run dir, the ranks talk over gloo; checkpoints and metrics.json come
    from rank 0 only."""
    run = tmp_path / "run"
    r = _pbc("pbc.train", "+experiment=whole", *tiny_overrides(tiny_dataset.parent), "trainer=ddp",
             "trainer.accelerator=cpu", "trainer.devices=2", "trainer.sync_batchnorm=false", "trainer.max_epochs=2",
             "+trainer.limit_train_batches=2",
             "+trainer.limit_val_batches=1", "+trainer.limit_test_batches=1", "trainer.enable_progress_bar=false",
             "image.whole_resolution=64", f"hydra.run.dir={run}")
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-4000:]
    assert "MEMBER: 2/2" in out  # rank 1 joined: a real two-process run
    assert [p.relative_to(run) for p in run.rglob("metrics.json")] == [Path("metrics.json")]
    m = json.loads((run / "metrics.json").read_text())
    assert m["status"] == "ok" and m["epochs"] == 2
    ckpts = sorted(p.name for p in run.rglob("*.ckpt"))
    assert ckpts.count("last.ckpt") == 1 and len([c for c in ckpts if c.startswith("epoch_")]) == 1, ckpts
    assert {p.parent for p in run.rglob("*.ckpt")} == {run / "checkpoints"}
