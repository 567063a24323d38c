"""Stops that stop (pbc.core.stops): SIGTERM or SIGINT to a pbc command stops every process it started, says in one
line which step it stopped in and the command that continues, and exits 143 or 130.

The case: `pbc garment fit` of the coarse shirt (425 vertices on the coarse mannequin, 4 drapes, two drape workers),
SIGTERMed while its `pbc.generate` child drapes in two worker processes; then the command its stop line gives,
SIGINTed in the same step. Processes are followed through /proc (psutil is not installed)."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.a_pose import outfit_obj  # noqa: E402
from helpers.processes import alive, cmdline, descendants  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TINY = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128", "datamodule.batch_size=4",
        "data.workers=2", "sim.discard.max_area_compression=1.0", "sim.fold_frames=0", "body.mesh.voxel_size=0.03"]


def _env(root: Path) -> dict:
    return dict(os.environ, PBC_ROOT=str(root), PBC_WARP_CACHE=str(ROOT / ".cache" / "warp"),
                PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")


def _stop_when(proc: subprocess.Popen, ready, signum: int, timeout: float = 300) -> dict[int, str]:
    """Follow `proc`'s descendants until `ready(cmdlines)`; then send `signum` to `proc` alone (as `kill` does)
    and return every descendant seen, with its command line."""
    seen: set[int] = set()
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        seen |= descendants(proc.pid)
        if ready([cmdline(p) for p in seen if alive(p)]):
            break
        time.sleep(0.2)
    assert proc.poll() is None, f"the command ended before it was stopped: {proc.communicate()}"
    seen |= descendants(proc.pid)
    kinds = {p: cmdline(p) for p in seen}
    proc.send_signal(signum)
    return kinds


def _drape_workers(cmds: list[str]) -> int:
    return sum("multiprocessing.spawn" in c for c in cmds)


@pytest.fixture(scope="module")
def stopped_fit(tmp_path_factory):
    """A fit SIGTERMed while its generate child drapes with two workers: (folder, out dir, result, pids seen)."""
    root = tmp_path_factory.mktemp("stops")
    (root / "shirt.obj").write_text(outfit_obj(0.0, trousers=False, garment="tshirt_coarse"))
    out = root / "fit"
    argv = ["pbc", "garment", "fit", "shirt.obj", "garment.position_unit=dm", *TINY, "--samples", "4",
            "--epochs", "2", "--out", str(out)]
    proc = subprocess.Popen(argv, cwd=root, env=_env(root), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    seen = _stop_when(proc, lambda cmds: _drape_workers(cmds) >= 2, signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    return root, out, subprocess.CompletedProcess(argv, proc.returncode, stdout, stderr), seen


def test_sigterm_stops_a_garment_fit_with_its_generate_and_drape_workers(stopped_fit):
    # SIGTERM to `pbc garment fit` exited 143 without a word while its generate child draped on, orphaned
    root, out, res, seen = stopped_fit
    assert res.returncode == 143, res.stderr[-3000:]
    assert any("pbc.generate" in c for c in seen.values()) and _drape_workers(list(seen.values())) >= 2, seen
    assert not [p for p in seen if alive(p)], "processes outlived their stopped fit"
    line = res.stderr.strip().splitlines()[-1]
    assert line.startswith("pbc garment: stopped by SIGTERM in step 4/6 data (python -m pbc.generate, its log: "), line
    asked = f"--samples 4 --epochs 2 --out {out}"
    assert f"to continue: pbc garment fit shirt.obj garment.position_unit=dm {' '.join(TINY)} {asked}" in line
    # the generate child stopped the same way, its workers with it, and said so in its log
    log = (out / "logs" / "data.log").read_text().strip().splitlines()
    assert log[-1].startswith("pbc generate: stopped by SIGTERM in the drapes ("), log[-1]
    assert "the same command resumes" in log[-1]
    # nothing half-written: no dataset yet, and every drape written is whole
    assert not (out / "data" / "manifest.json").exists()
    for sample in (out / "data" / "work" / "samples").glob("*.npz"):
        with np.load(sample) as z:
            assert np.isfinite(z["positions"]).all()


def test_sigint_to_the_command_that_continues_it_stops_it_again_in_its_step(stopped_fit):
    root, out, res, _ = stopped_fit
    again = shlex.split(res.stderr.strip().splitlines()[-1].split("to continue: ", 1)[1].rsplit(" (", 1)[0])
    proc = subprocess.Popen(again, cwd=root, env=_env(root), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    # the data step's generate child running (it continues there: inspect and checks are done)
    seen = _stop_when(proc, lambda cmds: any("pbc.generate" in c for c in cmds), signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr[-3000:]
    assert "[fit 1/6] inspect: skipped (done: " in stdout and "[fit 2/6] checks: skipped (done: " in stdout
    line = stderr.strip().splitlines()[-1]
    assert line.startswith("pbc garment: stopped by SIGINT in step 4/6 data (python -m pbc.generate"), line
    assert f"to continue: {shlex.join(again)} (" in line
    assert not [p for p in seen if alive(p)], "processes outlived their interrupted fit"
    assert not (out / "data" / "manifest.json").exists()
