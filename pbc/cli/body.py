"""`pbc body show|export [body overrides]`: the body a config builds, for people.

    pbc body show                                   # the mannequin: joints, limits, height, girths
    pbc body show body=anny body.phenotype.weight=0.7
    pbc body export body=anny_tpose --out tpose.obj   # the rest body, to place a garment on it in Blender
    pbc body cache [--trim]                         # Anny's asset cache: folder, files, sizes; trim to the built models

`show` prints the joints (parent, rest head, limits), the phenotype (Anny), the height, the chest / waist /
hip girths (conf/measure.yaml) and how closely the inside test's primitives follow the mesh. `export`
writes the rest body (the rest pose and phenotype chosen) as OBJ or PLY, in pbc's frame: metres, y up,
z forward, the root joint (pelvis) at the origin. `cache` lists Anny's asset cache ($PBC_CACHE_DIR/anny,
else ~/.cache/pbc/anny); `--trim` keeps only the built models (~51 MB each) and frees the ~740 MB of
intermediates (building another rig, topology or phenotype set makes them again).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.core.config import load_config
from pbc.core.io import naming_full_disk, require_out_dir
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import anny_cache_dir, cache_files, trim_anny_cache
from pbc.geometry.body.measure import inside_test_gap, measurements
from pbc.geometry.body.skeleton import AXES
from pbc.geometry.meshio import write_mesh


def show(cfg, body) -> str:
    sk = body.skeleton
    lines = [f"body: {cfg.get('kind', 'mannequin')}, {body.vertices.shape[0]:,} vertices, {body.faces.shape[0]:,} "
             f"faces, {sk.num_joints} posable joints"]
    if "phenotype" in cfg:
        lines.append("phenotype: " + ", ".join(f"{k} {float(v):g}" for k, v in cfg.phenotype.items()))
    m = measurements(body)
    lines.append(f"height {100 * m['height']:.1f} cm; girths: chest {100 * m['chest']:.1f} cm, waist "
                 f"{100 * m['waist']:.1f} cm, hips {100 * m['hips']:.1f} cm (at {100 * m['chest_at']:.0f}, "
                 f"{100 * m['waist_at']:.0f}, {100 * m['hips_at']:.0f} cm above the root)")
    fit = inside_test_gap(body)
    lines.append(f"inside test vs mesh (|SDF| at the vertices): mean {100 * fit['mean']:.2f} cm, p95 "
                 f"{100 * fit['p95']:.2f} cm, max {100 * fit['max']:.2f} cm")
    lines.append(f"{'joint':<12}{'parent':<12}{'rest head (m)':<26}limits (deg, relative to rest)")
    for j, name in enumerate(sk.names):
        parent = "root" if sk.parents[j] < 0 else sk.names[sk.parents[j]]
        head = " ".join(f"{float(x):+.3f}" for x in sk.rest_heads[j])
        lim = "  ".join(f"{a} [{float(sk.limits_deg[j, i, 0]):g}, {float(sk.limits_deg[j, i, 1]):g}]"
                        for i, a in enumerate(AXES))
        lines.append(f"{name:<12}{parent:<12}{head:<26}{lim}")
    return "\n".join(lines)


def cache(trim: bool) -> int:
    if trim:
        removed, freed = trim_anny_cache()
        print(f"{anny_cache_dir()}: removed {len(removed)} files, freed {freed / 2**20:.0f} MB")
    files = cache_files()
    print(f"{anny_cache_dir()}: {len(files)} files, {sum(p.stat().st_size for p in files) / 2**20:.0f} MB")
    for p in files:
        print(f"  {p.stat().st_size / 2**20:8.1f} MB  {p.relative_to(anny_cache_dir())}")
    return 0


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc body", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=("show", "export", "cache"))
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. body=anny body.phenotype.age=0.8")
    ap.add_argument("--out", help="export: the file to write (.obj or .ply)")
    ap.add_argument("--trim", action="store_true", help="cache: delete all but the built models")
    args = ap.parse_args(argv)
    if args.action == "cache":
        return cache(args.trim)
    if args.action == "export" and not args.out:
        ap.error("export needs --out FILE.obj (or .ply)")
    if args.out and not args.out.lower().endswith((".obj", ".ply")):
        raise ValueError(f"--out {args.out}: give a .obj or .ply file name")
    if args.action == "export":
        require_out_dir(Path(args.out).parent, holds_file=True)  # before the body is built (seconds for Anny)
    cfg = load_config(args.overrides).body
    body = body_from_config(cfg)  # every check (phenotype, topology, joint table) runs before anything is written
    if args.action == "show":
        print(show(cfg, body))
        return 0
    header = [f"pbc body export: {cfg.get('kind', 'mannequin')} rest pose; metres, y up, z forward, root at origin"]
    with naming_full_disk(args.out, "body mesh", "free space there or give --out a file on another disk"):
        path = write_mesh(args.out, body.vertices, body.faces, header=header)
    print(f"wrote {path}: {body.vertices.shape[0]:,} vertices, {body.faces.shape[0]:,} faces")
    return 0


main = entry_point("body", run)

if __name__ == "__main__":
    main()
