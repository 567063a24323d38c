"""Cost of the reliability checks at the doors, on this machine (CPU).

    python bench/checks.py [samples=4000] [vertices=3153]

1. `pbc.core.validate.as_poses` per call, with and without the rotation test, at batch 1 / 64 / 1024 (the
   predictor's and the module's first line; compare with a forward pass of milliseconds).
2. `pbc.data.dataset.bad_samples` over memory-mapped (N, V, 3) vertices and (N, 10, 3, 3) poses: what
   opening a dataset costs once per process (the tshirt_small shirt has 3153 vertices).
Prints a table and, as the last line, one JSON object of the figures.
"""

from __future__ import annotations

import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from pbc.core.io import load_npy, save_npy
from pbc.core.validate import as_poses
from pbc.data.dataset import bad_samples

J = 10


def rotations(n: int, rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(n * J, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1
    return q.reshape(n, J, 3, 3).astype(np.float32)


def per_call(fn, reps: int) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def main(argv: list[str]) -> dict:
    args = dict(a.split("=", 1) for a in argv)
    n, v = int(args.get("samples", 4000)), int(args.get("vertices", 3153))
    rng = np.random.default_rng(0)
    torch.set_num_threads(1)
    device = f"{cpu_name()}, 1 torch thread"
    print(f"device: {device}")
    out: dict = {"device": device, "as_poses_us": {}}
    print(f"{'as_poses':<12}{'batch':>8}{'rotation test us':>18}{'no rotation test us':>22}")
    for b in (1, 64, 1024):
        x = torch.from_numpy(rotations(b, rng)).reshape(b, -1)
        full = per_call(lambda x=x: as_poses(x, J), 200 if b < 1024 else 30) * 1e6
        light = per_call(lambda x=x: as_poses(x, J, check_rotation=False), 200 if b < 1024 else 30) * 1e6
        out["as_poses_us"][str(b)] = {"rotation": round(full, 1), "no_rotation": round(light, 1)}
        print(f"{'':<12}{b:>8}{full:>18.1f}{light:>22.1f}")
    with tempfile.TemporaryDirectory() as d:
        save_npy(Path(d) / "p.npy", rotations(n, rng))
        verts = np.empty((n, v, 3), np.float32)
        for a in range(0, n, 500):  # chunked: a few hundred MB without a float64 intermediate
            verts[a : a + 500] = rng.uniform(-0.5, 0.5, size=(min(500, n - a), v, 3))
        save_npy(Path(d) / "v.npy", verts)
        del verts
        p, vv = load_npy(Path(d) / "p.npy"), load_npy(Path(d) / "v.npy")
        bad_samples(p, vv, 1.3)  # warm the page cache: the figure is compute, not the disk
        t0 = time.perf_counter()
        bad = bad_samples(p, vv, 1.3)
        dt = time.perf_counter() - t0
        mb = (vv.nbytes + p.nbytes) / 1e6
    assert not bad
    out["dataset_check"] = {"samples": n, "vertices": v, "MB": round(mb, 1), "seconds": round(dt, 3),
                            "MB_per_s": round(mb / dt, 1)}
    print(f"\n{'dataset check':<16}{'samples':>9}{'vertices':>10}{'MB':>9}{'seconds':>10}{'MB/s':>9}")
    print(f"{'':<16}{n:>9}{v:>10}{mb:>9.1f}{dt:>10.3f}{mb / dt:>9.1f}")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
