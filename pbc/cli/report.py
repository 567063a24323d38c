"""`pbc report SWEEP_DIR [--out DIR]` (also `python -m pbc.report`): the paper's comparison report of a
sweep dir (pbc.report: report.md, report.json and the figures)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.report import __doc__ as REPORT_DOC
from pbc.report import build_report


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc report", description=REPORT_DOC.splitlines()[0])
    ap.add_argument("sweep_dir", type=Path, help="a Hydra multirun dir (or a folder of them, or one run dir)")
    ap.add_argument("--out", type=Path, default=None, help="where to write report.md and PNGs (default: sweep_dir)")
    args = ap.parse_args(argv)
    print(build_report(args.sweep_dir, args.out))
    return 0


main = entry_point("report", run)

if __name__ == "__main__":
    main()
