"""`pbc sweeps NAME [overrides]` (also `python -m pbc.sweeps`): a named sweep of conf/sweep/ end to end
(data, training multirun, evaluation, report; pbc.sweeps is the one sweep runner)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.jobs.sweeps import SWEEP_NAMES, run_sweep


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        prog="pbc sweeps", description="Run a named sweep end to end (data, training multirun, evaluation, report).")
    ap.add_argument("name", choices=SWEEP_NAMES)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. scale=smoke hydra.launcher.n_jobs=2")
    ap.add_argument("--dir", type=Path, default=None, help="sweep dir (default runs/sweeps/NAME/SCALE_TIME)")
    ap.add_argument("--no-report", action="store_true")
    ap.add_argument("--report-dir", type=Path, default=None, help="write the report here (default: sweep dir)")
    args = ap.parse_args(argv)
    sweep_dir, rc = run_sweep(args.name, args.overrides, args.dir, report=not args.no_report,
                              report_dir=args.report_dir)
    print(f"[pbc sweeps] {sweep_dir} (exit {rc})")
    return rc


main = entry_point("sweeps", run)

if __name__ == "__main__":
    main()
