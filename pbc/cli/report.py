"""`pbc report SWEEP_DIR [--out DIR]` (also `python -m pbc.report`): the paper's comparison report of a
sweep dir (pbc.report: report.md, report.json and the figures), or the wrong-body study's (robustness.md,
Figs. 9-10) for a `pbc sweeps robustness` dir."""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.core.io import read_json
from pbc.core.runs import SWEEP_RECORD
from pbc.jobs.sweeps import build_sweep_report
from pbc.report import __doc__ as REPORT_DOC


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc report", description=REPORT_DOC.splitlines()[0])
    ap.add_argument("sweep_dir", type=Path, help="a Hydra multirun dir (or a folder of them, or one run dir)")
    ap.add_argument("--out", type=Path, default=None, help="where to write report.md and PNGs (default: sweep_dir)")
    args = ap.parse_args(argv)
    record = args.sweep_dir / SWEEP_RECORD  # a sweep of the runner names itself (the wrong-body study's report)
    name = read_json(record, "sweep record").get("name", "") if record.is_file() else ""
    print(build_sweep_report(name, args.sweep_dir, args.out))
    return 0


main = entry_point("report", run)

if __name__ == "__main__":
    main()
