"""Pack a mirrored dataset for a GPU machine that takes at most 64 MiB a call (run on the CPU side).

    python docs/results/converged_gpu/pack.py POOL_DIR MOCAP_NPZ OUT_DIR

A mirrored dataset's mirror rows are a fixed linear map of its training rows (pbc.data.mirror), so only the
drapes travel (POOL/verts.npy's first `kept` rows) with the map that makes the rest (`mirror_map.npz`: the
triangle and barycentric weights of each vertex's mirror point); run.py rebuilds verts.npy there and checks it
against the sha256 recorded here. Also packed: the 256-px image operators (they take minutes to build on a
CPU) and the motion-capture drapes the models are scored on.
"""

from __future__ import annotations

import hashlib
import shutil
import sys
from pathlib import Path

import numpy as np

from pbc.core.config import load_config
from pbc.core.io import read_json, write_json
from pbc.data.generate import build_scene, scene_mirror_map
from pbc.data.mirror import mirror_verts


def main(pool: Path, mocap: Path, out: Path) -> None:
    man = read_json(pool / "manifest.json")
    kept, rows, of = man["counts"]["kept"], man["mirrored"]["rows"], man["mirrored"]["of"]
    verts = np.load(pool / "verts.npy")
    cfg = load_config([f"data={man.get('data_name', 'tshirt_small')}", f"data.num_samples={man['counts']['requested']}",
                       "data.mirror=true"])
    scene, _ = build_scene(cfg)
    mm = scene_mirror_map(cfg, scene, np.load(pool / "poses.npy")[:kept])
    rebuilt = np.concatenate([verts[:kept], mirror_verts(verts[of], mm)])
    if rows != list(range(kept, len(verts))) or not np.array_equal(rebuilt, verts):
        raise SystemExit(f"{pool}: its mirror rows are not mirror_verts of its training rows: cannot pack it this way")
    if out.exists():
        shutil.rmtree(out)
    (out / "pool").mkdir(parents=True)
    for f in pool.iterdir():
        if f.is_file() and f.name != "verts.npy":
            shutil.copy2(f, out / "pool" / f.name)
    np.save(out / "pool" / "verts_kept.npy", verts[:kept])
    np.savez(out / "mirror_map.npz", tri=mm.tri, bary=mm.bary)
    write_json(out / "pack.json", {"kept": kept, "verts_sha256": hashlib.sha256(verts.tobytes()).hexdigest(),
                                   "verts_shape": list(verts.shape)})
    shutil.copy2(mocap, out / "mocap.npz")
    ops = sorted((pool.parent.parent / "subsets").glob("*/operators/operators_*.npz"))
    if ops:
        (out / "operators").mkdir()
        shutil.copy2(ops[0], out / "operators" / ops[0].name)
    print(f"packed {pool} ({kept} drapes + {len(rows)} mirror rows rebuilt there) into {out}")


if __name__ == "__main__":
    main(*(Path(a) for a in sys.argv[1:4]))
