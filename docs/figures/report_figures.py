"""Redraw a saved report's bar figures (table1.png, table2.png, hierarchy.png) from its report.json alone.

    python docs/figures/report_figures.py docs/results/hierarchy_cpu [docs/results/losses_cpu ...]

`python -m pbc.report <sweep dir>` draws them from the sweep's run dirs; the docs/results folders keep only
the report, so this rebuilds the table rows from report.json and calls the same `pbc.report.figures`. The
learning curves need the runs' TensorBoard events, which report.json does not hold: learning_curves.png is
left as it is (redraw it with `python -m pbc.report <sweep dir> --out <folder>` where the runs still exist).
"""

import json
import sys
from pathlib import Path

from pbc.jobs.report import Row, figures
from pbc.core.runs import PATCH_PREFIX


def redraw(folder: Path) -> dict[str, str]:
    data = json.loads((folder / "report.json").read_text())
    rows = {k: [Row(**r) for r in data.get(k, [])] for k in ("table1", "table2", "patches", "hierarchy")}
    for row in rows["patches"]:
        # reports made before the scoped names (pbc.core.runs.scoped_name) hold a patch run's own-vertex error
        # under the plain name; the figure reads the scoped one
        for key in list(row.values):
            split, _, name = key.partition("/")
            if name and not name.startswith(PATCH_PREFIX):
                row.values.setdefault(f"{split}/{PATCH_PREFIX}{name}", row.values[key])
    return figures(folder, [], rows["table1"], rows["table2"], rows["patches"], rows["hierarchy"])


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(arg, redraw(Path(arg)))
