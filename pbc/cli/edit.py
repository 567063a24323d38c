"""`pbc edit [overrides] --sample N --normal 0.01 --patch 7 ...` (also `python -m pbc.edit`): edit a cloth
image and rebuild the garment (appendix B, Fig. 2; pbc.edit does the work and documents the edits)."""

from __future__ import annotations

import argparse
import json

from pbc.cli.errors import entry_point
from pbc.core.io import naming_full_disk
from pbc.edit import __doc__ as EDIT_DOC
from pbc.jobs.edit import run_edit

DESCRIPTION = EDIT_DOC.split("\n\n")[0]


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="pbc edit", description=DESCRIPTION)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of conf/config.yaml (data=..., image...)")
    ap.add_argument("--data-dir", default=None, help="dataset directory (default: the config's data.dir)")
    ap.add_argument("--sample", type=int, default=0, help="dataset sample whose pose (and cloth) is edited")
    ap.add_argument("--run", default=None, help="a whole-shirt run dir: edit its prediction instead of the data")
    ap.add_argument("--resolution", type=int, default=None,
                    help="image resolution (sets image.whole_resolution; a --run uses its own)")
    ap.add_argument("--shift-u", type=float, default=0.0, help="metres added to du")
    ap.add_argument("--shift-v", type=float, default=0.0, help="metres added to dv")
    ap.add_argument("--normal", type=float, default=0.0, help="metres added to dn (+ inflate, - shrink)")
    ap.add_argument("--normal-gain", type=float, default=0.0, help="dn *= 1 + gain")
    ap.add_argument("--patch", type=int, default=None, help="region: a cage patch id")
    ap.add_argument("--mask", default=None, help="region: a painted grayscale PNG (white = edit)")
    ap.add_argument("--mask-side", type=int, default=None, help="chart of a one-chart --mask PNG (0 front, 1 back)")
    ap.add_argument("--rect", type=float, nargs=5, default=None, metavar=("SIDE", "U0", "V0", "U1", "V1"),
                    help="region: a UV rectangle of one chart")
    ap.add_argument("--feature", default=None, help="grayscale PNG painted into the normal channel")
    ap.add_argument("--feature-rect", type=float, nargs=5, default=None, metavar=("SIDE", "U0", "V0", "U1", "V1"))
    ap.add_argument("--feature-amplitude", type=float, default=0.01, help="metres of dn where the feature is white")
    ap.add_argument("--gallery", action="store_true", help="figure: every kind of edit side by side (Fig. 2)")
    ap.add_argument("--out", default="outputs/edit", help="output directory")
    return ap.parse_args(argv)


def run(argv: list[str]) -> int:
    args = parse_args(argv)
    with naming_full_disk(args.out, "edit output directory", "free space there or give another --out; every file "
                          "written is whole (written, then renamed)"):
        record = run_edit(args)
    print(json.dumps(record, indent=1))
    return 0


main = entry_point("edit", run)

if __name__ == "__main__":
    main()
