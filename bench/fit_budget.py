"""`pbc garment fit` at a budget, on three corpus garments (a T-shirt, a long-sleeved top, trousers) on Anny, as a
user types it: wall time, drapes, the models trained and the one kept, and the errors on held-out sampled poses and on
held-out motion-capture frames beside the training mean shape's (the fit's own scores.json).

    python bench/fit_budget.py --budget 15m --out docs/results/fit_budget   # results_15m.json, a table
    python bench/fit_budget.py --budget 60m --out docs/results/fit_budget --only tshirt

Each fit works under --work (default ~/.cache/pbc/fit_budget/<budget>/<garment>) and is resumable: a run stopped
and started again goes on where its fit stopped (its wall time is then the sum of the calls', as measured here).
Targets (the fit-budget issue): done within the budget, at most 0.5x the mean shape on held-out sampled poses and
0.6x on real motion frames.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.drape import device_name  # noqa: E402
from pbc.core.paths import corpus_dir  # noqa: E402
from pbc.jobs.fit_plan import parse_budget  # noqa: E402

GARMENTS = {  # name: (the corpus file, the overrides a user gives)
    "tshirt": ("garments/diffavatar/tshirt.obj", ["body=anny"]),
    "longsleeve": ("garments/makehuman/male_casualsuit02/male_casualsuit02.mhclo", ["garment.piece=top"]),
    "trousers": ("garments/makehuman/male_casualsuit02/male_casualsuit02.mhclo", ["garment.piece=bottom"]),
}
TARGETS = {"test_over_mean": 0.5, "motion_over_mean": 0.6}


def fit(name: str, budget: str, work: Path) -> dict:
    """One fit (resumed when its folder holds one), its wall time added to what earlier calls measured."""
    path, overrides = GARMENTS[name]
    out = work / name
    out.parent.mkdir(parents=True, exist_ok=True)
    times = out.parent / f"{name}.seconds.json"
    spent = json.loads(times.read_text())["seconds"] if times.is_file() else 0.0
    log = out.parent / f"{name}.log"
    t0 = time.time()
    with log.open("a") as f:
        rc = subprocess.run([sys.executable, "-m", "pbc", "garment", "fit", str(corpus_dir() / path), *overrides,
                             "--budget", budget, "--out", str(out)], stdout=f, stderr=subprocess.STDOUT,
                            env=dict(os.environ, PBC_WARP_CACHE=str(ROOT / ".cache" / "warp"))).returncode
    seconds = spent + time.time() - t0
    times.write_text(json.dumps({"seconds": seconds}))
    row = {"garment": name, "file": path, "overrides": overrides, "rc": rc, "wall_s": round(seconds, 1)}
    if rc:
        row["error"] = log.read_text().strip().splitlines()[-1][:400]
        return row
    scores = json.loads((out / "scores.json").read_text())
    plan = json.loads((out / "fit.json").read_text())["plan"]
    kept = scores["models"][scores["kept"]]
    mean = scores["mean_shape"]
    counts = json.loads((out / "data" / "manifest.json").read_text())["counts"]
    row.update(drapes_asked=plan["samples"], drapes_kept=counts["kept"], kept_model=scores["kept"],
               models={k: {kk: v[kk] for kk in ("epochs", "seconds", "val_cm", "test_cm", "motion_cm") if kk in v}
                       for k, v in scores["models"].items()},
               left_out=plan.get("left_out", {}), test_cm=kept["test_cm"], test_mean_cm=mean["test_cm"],
               test_ratio=kept["test_cm"] / mean["test_cm"], test_poses=scores["test_poses"])
    if "motion_cm" in kept:
        row.update(motion_cm=kept["motion_cm"], motion_mean_cm=mean["motion_cm"],
                   motion_ratio=kept["motion_cm"] / mean["motion_cm"], motion_frames=scores["motion_frames"])
    return row


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--budget", default="60m")
    ap.add_argument("--out", type=Path, default=None, help="write results_<budget>.json here")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--only", nargs="*", choices=sorted(GARMENTS), default=sorted(GARMENTS))
    args = ap.parse_args(argv)
    budget_s = parse_budget(args.budget)
    work = args.work or Path.home() / ".cache" / "pbc" / "fit_budget" / args.budget
    rows = [fit(name, args.budget, work) for name in args.only]
    print(f"pbc garment fit --budget {args.budget} on Anny; device: {device_name()}")
    print(f"{'garment':<11} {'rc':>2} {'wall min':>8} {'drapes':>9} {'kept model':>10} {'test / mean cm':>16} "
          f"{'ratio':>5} {'motion / mean cm':>17} {'ratio':>5}")
    for r in rows:
        if r["rc"]:
            print(f"{r['garment']:<11} {r['rc']:>2} {r['wall_s'] / 60:>8.1f}  {r['error']}")
            continue
        motion = (f"{r['motion_cm']:.2f} / {r['motion_mean_cm']:.2f}", f"{r['motion_ratio']:.2f}") \
            if "motion_cm" in r else ("-", "-")
        print(f"{r['garment']:<11} {r['rc']:>2} {r['wall_s'] / 60:>8.1f} {r['drapes_kept']:>4}/{r['drapes_asked']:<4} "
              f"{r['kept_model']:>10} {r['test_cm']:>7.2f} / {r['test_mean_cm']:<6.2f} {r['test_ratio']:>5.2f} "
              f"{motion[0]:>17} {motion[1]:>5}")
    ok = [r for r in rows if not r["rc"]]
    figures = {"budget_s": budget_s, "device": device_name(), "fits": len(rows), "done": len(ok),
               "within_budget": sum(r["wall_s"] <= budget_s for r in ok),
               "test_ratio_max": max((r["test_ratio"] for r in ok), default=None),
               "motion_ratio_max": max((r["motion_ratio"] for r in ok if "motion_ratio" in r), default=None),
               "targets": TARGETS}
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / f"results_{args.budget}.json").write_text(json.dumps({"rows": rows, "figures": figures},
                                                                         indent=1) + "\n")
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
