"""Turn a sweep dir into the paper's comparison report: `python -m pbc.report <sweep dir> [--out DIR]`.

Reads the run dirs below the sweep dir (`pbc.core.runs.load_runs`: metrics.json, Hydra configs, TensorBoard
events) and writes `report.md`, `report.json` (every table value, exactly as read) and PNGs: Table 1
(losses), Table 2 (FC spaces x direct/PCA, and the CNN), the hierarchy (whole vs. stitched per seam
method, per-patch errors), learning curves, and the paper's claimed orderings marked held / did not
hold / not measured. Failed and missing runs are listed with their error, never dropped. Every file is
written atomically (temp file + rename), so a reader never sees half a report.
"""

from __future__ import annotations

import json
import math
import os
import re
import statistics
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import matplotlib as mpl
import numpy as np
import yaml

from pbc.core.io import read_json, save_figure, write_text
from pbc.core.paths import CONF_DIR, SHIPPED_ROOT
from pbc.core.runs import (
    FAILED,
    INCOMPLETE,
    INTERIOR_JUMP,
    NORMAL_DISTANCE,
    OK,
    SEAM_JUMP,
    SWEEP_RECORD,
    VERTEX_ERROR,
    ModelKind,
    Run,
    expected_jobs,
    load_runs,
    monitor,
    scoped_name,
)

REPO = SHIPPED_ROOT  # the checkout (or the installed package): its paths are shown relative to it


PAPER_FILE = CONF_DIR / "paper.yaml"  # the paper's own numbers, shipped with the configs


# Metric names as pbc.train logs them, per split (pbc.core.runs defines them)...
VERTEX, NORMAL = VERTEX_ERROR, NORMAL_DISTANCE


# ...and a patch model's, over its patch's vertices only (pbc.core.runs.scoped_name)
PATCH_VERTEX, PATCH_NORMAL = scoped_name(VERTEX, ModelKind.PATCH), scoped_name(NORMAL, ModelKind.PATCH)


TABLE1_LOSSES = ("l1", "l2", "l2_normal", "l1_normal")


LOSS_LABEL = {"l1": "L1", "l2": "L2", "l2_normal": "L2 + N", "l1_normal": "L1 + N"}


FC_SPACES = (("local", "Off. Loc."), ("root", "Off. Root."), ("position", "Pos. Root."))


FC_EXPERIMENTS = tuple(f"fc_{m}_{s}" for s, _ in FC_SPACES for m in ("direct", "pca"))


# Columns of the hierarchy table, in this order, with their headers (pbc.evaluate's entry keys).
HIERARCHY_COLUMNS = {VERTEX_ERROR: "vertex (cm)", NORMAL_DISTANCE: "normal (1 - cos)",
                     SEAM_JUMP: "seam jump (cm)", INTERIOR_JUMP: "interior jump (cm)"}


# Scalar series plotted as learning curves, first found wins.
TRAIN_CURVES = ("train/loss_step", "train/loss", "train/loss_epoch", "train/image_loss_step")


VAL_CURVES = (monitor(ModelKind.WHOLE), monitor(ModelKind.PATCH), "val/loss")


HELD, NOT_HELD, NOT_MEASURED = "held", "did not hold", "not measured"


TIE = "tie (within 1%)"


# With two or more seeds per setting a difference no larger than the seeds' own range (max - min, the larger
# of the two settings') neither supports nor refutes an ordering.
WITHIN_NOISE = "within noise"


# Two numbers closer than this (relative) neither support nor refute an ordering: with one run per
# setting, differences this small are below the run-to-run noise of a short CPU schedule.
TIE_RELATIVE = 0.01


# ----------------------------------------------------------------------------------------- cells and rows
@dataclass
class Row:
    """One table row: what it selects, the runs behind it, mean values over its successful runs."""
    label: str
    select: dict[str, str]
    runs: list[str] = field(default_factory=list)
    status: str = "missing"  # ok | failed | incomplete | missing
    error: str | None = None
    values: dict[str, float] = field(default_factory=dict)
    paper: dict[str, float] = field(default_factory=dict)
    sourced: list[str] = field(default_factory=list)  # keys read from TensorBoard, not metrics.json
    spread: dict[str, float] = field(default_factory=dict)  # max - min over the runs (seeds), where >= 2 have it

    def value(self, key: str) -> float | None:
        return self.values.get(key)

    def noise(self, key: str) -> float | None:
        """The seeds' range of `key` (max - min), or None with fewer than two runs."""
        return self.spread.get(key)


def _matches(run: Run, select: dict[str, str]) -> bool:
    return all(run.get(k) == v for k, v in select.items())


def make_row(label: str, runs: list[Run], select: dict[str, str], keys, paper=None) -> Row:
    """Mean over the matching successful runs (several seeds average); else why there is no number."""
    row = Row(label=label, select=dict(select), paper=dict(paper or {}))
    hits = [r for r in runs if _matches(r, select)]
    row.runs = [r.name for r in hits]
    good = [r for r in hits if r.status == OK]
    if good:
        row.status = OK
        for k in keys:
            vals = [r.metrics[k] for r in good if k in r.metrics]
            if vals:
                row.values[k] = statistics.fmean(vals)
            if len(vals) >= 2:
                row.spread[k] = max(vals) - min(vals)
            if any(k in r.sources for r in good):
                row.sourced.append(k)
    elif hits:
        bad = hits[-1]
        row.status, row.error = bad.status, bad.error
    else:
        row.error = "no run with " + ", ".join(f"{k}={v}" for k, v in select.items())
    return row


def fmt(x: float | None) -> str:
    if x is None:
        return "—"
    if not math.isfinite(x):
        return str(x)
    return f"{x:.4g}"


def cell(row: Row, key: str, paper_key: str | None = None) -> str:
    if row.status != OK:
        return row.status
    ours = fmt(row.value(key)) + ("*" if key in row.sourced else "")
    if row.noise(key) is not None:  # several seeds: their mean ± half their range
        ours += f" ±{fmt(row.noise(key) / 2)}"
    if paper_key and paper_key in row.paper:
        return f"{ours} ({fmt(row.paper[paper_key])})"
    return ours


def _scoped_cell(run: Run, metric: str) -> str:
    """A run's test metric, marked "(patch)" when it is a patch model's (its patch's vertices only)."""
    whole, patch = run.metrics.get(f"test/{metric}"), run.metrics.get(f"test/{scoped_name(metric, ModelKind.PATCH)}")
    return fmt(whole) if patch is None else f"{fmt(patch)} (patch)"


# ----------------------------------------------------------------------------------------------- tables
def table1(runs: list[Run], paper: dict) -> list[Row]:
    keys = [f"{s}/{m}" for s in ("train", "test") for m in (VERTEX, NORMAL)]
    return [
        make_row(LOSS_LABEL[loss], runs, {"experiment": "whole", "loss": loss}, keys, paper.get(loss))
        for loss in TABLE1_LOSSES
    ]


def table2(runs: list[Run], paper: dict) -> list[Row]:
    keys = [f"{s}/{VERTEX}" for s in ("train", "test")]
    rows = []
    for space, label in FC_SPACES:
        for mode, mlabel in (("direct", "Direct"), ("pca", "128 PC")):
            exp = f"fc_{mode}_{space}"
            rows.append(make_row(f"{label} {mlabel}", runs, {"experiment": exp}, keys, paper.get(exp)))
    # The CNN row: the whole-shirt decoder under the paper's quantitative loss (L1), as in Table 1.
    cnn = make_row(
        "CNN (whole, L1)",
        runs,
        {"experiment": "whole", "loss": "l1"},
        keys,
        {"train_vertex": paper.get("cnn_train_vertex"), "test_vertex": paper.get("cnn_test_vertex")},
    )
    cnn.paper = {k: v for k, v in cnn.paper.items() if v is not None}
    rows.append(cnn)
    return rows


def _expected_patch_ids(expected: dict[str, list[str]] | None) -> set[int]:
    """The patch ids a sweep was launched with: its patch_NN experiments (the T-shirt) and/or its
    model.patch_id values (`+experiment=patch 'model.patch_id=range(0,P)'`, any garment)."""
    expected = expected or {}
    ids = {int(e[6:]) for e in expected.get("experiment", []) if e[:6] == "patch_" and e[6:].isdigit()}
    return ids | {int(v) for v in expected.get("model.patch_id", []) if str(v).isdigit()}


def patch_rows(runs: list[Run], expected: dict[str, list[str]] | None = None) -> list[Row]:
    """Each patch model's own test error (over the vertices inside its patch), by patch id, whether the run
    was `+experiment=patch_NN` or `+experiment=patch model.patch_id=N`; the patches the sweep was launched
    with but that left no run dir are listed as missing."""
    ids = sorted({p for r in runs if (p := r.patch_id) is not None} | _expected_patch_ids(expected))
    keys = [f"{s}/{m}" for s in ("train", "test") for m in (PATCH_VERTEX, PATCH_NORMAL)] + [f"test/{PATCH_VERTEX}_std"]
    rows = []
    for i in ids:
        row = make_row(f"patch_{i:02d}", [r for r in runs if r.patch_id == i], {}, keys)
        row.select = {"patch_id": str(i)}
        if not row.runs:
            row.error = f"no run with patch id {i}"
        rows.append(row)
    return rows


def _is_eval(run: Run) -> bool:
    return run.job == "evaluate" or any(k.startswith("entries/") for k in run.metrics)


def _entry_label(name: str) -> str:
    if name.startswith("patches_"):
        return f"stitched ({name[8:]})"
    if name.startswith("gt_crops_"):
        return f"stitcher on true crops ({name[9:]})"
    if name == "train_mean":
        return "mean training offsets (no model)"
    if name.startswith("floor_"):
        return f"representation floor ({name[6:]} px)"
    return name


def hierarchy_rows(runs: list[Run]) -> list[Row]:
    """Whole vs. stitched per seam method, from the sweep's `pbc.evaluate` runs: the newest one, or with one
    evaluation per seed (`pbc sweeps paper`: `evaluate_s<seed>`) the mean over the seeds and their range.

    pbc.evaluate's metrics.json holds "entries": {name: {vertex_error_cm, normal_distance, seam_jump_cm,
    interior_jump_cm}} for "whole", "patches_<method>", "gt_crops_<method>" and "floor_<res>".
    """
    evals = [r for r in runs if _is_eval(r)]
    if not evals:
        return []
    seeded = [r for r in evals if Path(r.name).name.startswith("evaluate_s") and r.status == OK]
    chosen = seeded or [evals[-1]]
    if chosen[0].status != OK:
        ev = chosen[0]
        return [Row(label=ev.name, select={}, runs=[ev.name], status=ev.status, error=ev.error)]
    entries: dict[str, dict[str, list[float]]] = {}
    for ev in chosen:
        for k, v in ev.metrics.items():
            parts = k.split("/")
            if len(parts) == 3 and parts[0] == "entries":
                entries.setdefault(parts[1], {}).setdefault(parts[2], []).append(v)

    def order(name):
        kinds = ("whole", "patches_", "train_mean", "gt_crops_", "floor_")
        return next(i for i, p in enumerate((*kinds, "")) if name.startswith(p)), name

    return [
        Row(label=_entry_label(n), select={"method": n}, runs=[ev.name for ev in chosen], status=OK,
            values={k: statistics.fmean(x) for k, x in vals.items()},
            spread={k: max(x) - min(x) for k, x in vals.items() if len(x) >= 2})
        for n, vals in sorted(entries.items(), key=lambda t: order(t[0]))
    ]


# ----------------------------------------------------------------------------------------------- claims
@dataclass
class Claim:
    text: str
    paper: str
    ours: str
    verdict: str


def _compare(pairs, what: str) -> tuple[str, str]:
    """pairs: [(label, a, b)] or [(label, a, b, noise)] each claiming a < b; noise: the seeds' range (None: one
    run a side). A pair is close when |a - b| <= noise, or <= TIE_RELATIVE without seeds. -> (ours text, verdict):
    did not hold when a pair is the wrong way round and not close; else within noise / tie when one is close."""
    pairs = [(*p, None) if len(p) == 3 else tuple(p) for p in pairs]
    missing = [lbl for lbl, a, b, _ in pairs if a is None or b is None]
    if missing:
        return "missing: " + ", ".join(missing), NOT_MEASURED
    parts = [f"{lbl}: {fmt(a)} {'<' if a < b else '≥'} {fmt(b)}" + (f" (seeds' range {fmt(n)})" if n else "")
             for lbl, a, b, n in pairs]
    close = [abs(a - b) <= (n if n is not None else TIE_RELATIVE * max(abs(a), abs(b))) for _, a, b, n in pairs]
    if any(a >= b and not c for (_, a, b, _), c in zip(pairs, close, strict=True)):
        return "; ".join(parts), NOT_HELD
    seeded = any(n is not None for *_, n in pairs)
    return "; ".join(parts), (WITHIN_NOISE if seeded else TIE) if any(close) else HELD


def _noise(*rows_keys) -> float | None:
    """The larger seeds' range of (row, key) pairs, or None unless every row has one."""
    vals = [r.noise(k) if r is not None and r.status == OK else None for r, k in rows_keys]
    return None if any(v is None for v in vals) else max(vals)


def claims(t1: list[Row], t2: list[Row], hier: list[Row], paper: dict) -> list[Claim]:
    by = {r.select.get("loss"): r for r in t1}
    fc = {r.select.get("experiment"): r for r in t2 if "experiment" in r.select and r.select["experiment"] != "whole"}
    cnn = t2[-1]
    out = []

    def v(row, key):
        return row.value(key) if row is not None and row.status == OK else None

    def p(loss, key):
        return paper.get("table1", {}).get(loss, {}).get(key)

    # 1. L1 < L2 on vertex error, on the training and the test set.
    pairs = [(s, v(by["l1"], f"{s}/{VERTEX}"), v(by["l2"], f"{s}/{VERTEX}"),
              _noise((by["l1"], f"{s}/{VERTEX}"), (by["l2"], f"{s}/{VERTEX}"))) for s in ("train", "test")]
    ours, verdict = _compare(pairs, VERTEX)
    out.append(
        Claim(
            "L1 < L2 on vertex error (train, test)",
            f"train {p('l1', 'train_vertex')} < {p('l2', 'train_vertex')}; "
            f"test {p('l1', 'test_vertex')} < {p('l2', 'test_vertex')}",
            ours,
            verdict,
        )
    )
    # 2. The normal loss lowers the normal error: the paper shows it on the training set (its test
    # normals are 0.029 vs 0.028, i.e. it did not hold there), so the claim is judged on train.
    pairs = [("L2+N vs L2, train", v(by["l2_normal"], f"train/{NORMAL}"), v(by["l2"], f"train/{NORMAL}"),
              _noise((by["l2_normal"], f"train/{NORMAL}"), (by["l2"], f"train/{NORMAL}")))]
    ours, verdict = _compare(pairs, NORMAL)
    out.append(
        Claim(
            "normal loss lowers normal error (L2+N < L2, train)",
            f"train {p('l2_normal', 'train_normal')} < {p('l2', 'train_normal')} "
            f"(test {p('l2_normal', 'test_normal')} vs {p('l2', 'test_normal')})",
            ours,
            verdict,
        )
    )
    pairs = [("L1+N vs L1, train", v(by["l1_normal"], f"train/{NORMAL}"), v(by["l1"], f"train/{NORMAL}"),
              _noise((by["l1_normal"], f"train/{NORMAL}"), (by["l1"], f"train/{NORMAL}")))]
    ours, verdict = _compare(pairs, NORMAL)
    out.append(Claim("normal loss lowers normal error (L1+N < L1, train; beyond the paper)", "—", ours, verdict))
    # 3. PCA beats direct prediction in every space, train and test.
    pairs = []
    for space, label in FC_SPACES:
        for s in ("train", "test"):
            pca, direct = fc.get(f"fc_pca_{space}"), fc.get(f"fc_direct_{space}")
            pairs.append((f"{label} {s}", v(pca, f"{s}/{VERTEX}"), v(direct, f"{s}/{VERTEX}"),
                          _noise((pca, f"{s}/{VERTEX}"), (direct, f"{s}/{VERTEX}"))))
    ours, verdict = _compare(pairs, VERTEX)
    t2p = paper.get("table2", {})
    ptxt = "; ".join(
        f"{label} test {t2p.get(f'fc_pca_{s}', {}).get('test_vertex')} < "
        f"{t2p.get(f'fc_direct_{s}', {}).get('test_vertex')}"
        for s, label in FC_SPACES
    )
    out.append(Claim("PCA beats direct (FC, every space, train and test vertex error)", ptxt, ours, verdict))
    # 4. The CNN beats every FC network on test vertex error.
    fc_test = [(v(r, f"test/{VERTEX}"), r) for r in fc.values() if v(r, f"test/{VERTEX}") is not None]
    best_fc, best_row = min(fc_test, key=lambda t: t[0], default=(None, None))
    ours, verdict = _compare([("CNN vs best FC, test", v(cnn, f"test/{VERTEX}"), best_fc,
                               _noise((cnn, f"test/{VERTEX}"), (best_row, f"test/{VERTEX}")))], VERTEX)
    paper_fc = min((x["test_vertex"] for x in t2p.values() if isinstance(x, dict) and "test_vertex" in x), default=None)
    out.append(Claim("CNN beats FC (test vertex error)", f"{p('l1', 'test_vertex')} < {paper_fc}", ours, verdict))
    # 5. Patches beat the whole-shirt model: the best seam method against the whole model.
    h = {r.select.get("method"): r for r in hier if r.status == OK}
    whole = h.get("whole")
    stitched = [
        (r.label, r.value(VERTEX)) for m, r in h.items() if m.startswith("patches_") and r.value(VERTEX) is not None
    ]
    best = min(stitched, key=lambda t: t[1]) if stitched else ("stitched", None)
    best_row = next((r for r in h.values() if r.label == best[0]), None)
    ours, verdict = _compare([(f"{best[0]} vs whole, test", best[1], whole.value(VERTEX) if whole else None,
                               _noise((best_row, VERTEX), (whole, VERTEX)))], VERTEX)
    out.append(Claim("patches beat whole (test vertex error)", "sec. 4.1 / 8.3 (qualitative here)", ours, verdict))
    return out


# ---------------------------------------------------------------------------------------------- figures
def _bars(ax, labels, ours, theirs, ylabel, title, ranges=None):
    """ranges: each bar's seeds' range (max - min, None for one run), drawn as an error bar of that span."""
    x = np.arange(len(labels))
    yerr = [(r or 0) / 2 for r in ranges] if ranges and any(r for r in ranges) else None
    ax.bar(x - 0.2, [o if o is not None else 0 for o in ours], 0.4, yerr=yerr, capsize=3,
           label="ours" + (" (mean, seeds' range)" if yerr else ""))
    if any(t is not None for t in theirs):
        ax.bar(x + 0.2, [t if t is not None else 0 for t in theirs], 0.4, label="paper", alpha=0.6)
    for i, o in enumerate(ours):
        if o is None:
            ax.text(i - 0.2, 0, "n/a", ha="center", va="bottom", fontsize=7, rotation=90)
    ax.set_xticks(x, labels, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)


def _legend_below(fig, ax) -> None:
    """One legend under the plots (a figure legend, so it is never wider than the figure): as many columns
    as fit the figure's width, the figure growing downwards by the rows it needs."""
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    width_in = fig.get_size_inches()[0]
    longest = max(len(x) for x in labels)
    # ~0.06 in per character at 7 pt, plus the line sample
    ncol = max(1, min(len(labels), int(width_in / (0.06 * longest + 0.5))))
    rows = -(-len(labels) // ncol)
    w, h = fig.get_size_inches()
    fig.set_size_inches(w, h + 0.18 * rows + 0.1)
    fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=7, frameon=False)


def curve_styles(labels: list[str], family_min: int = 5) -> tuple[list[dict], dict[str, tuple[int, int]]]:
    """Colour and legend label of each learning curve, so a 29-run sweep reads: labels that differ only by
    a trailing number (patch_00 ... patch_27) and number at least ``family_min`` form a family drawn in one
    colormap over that number (one colorbar, no legend entries); every other run gets a distinct colour and
    its own legend entry. A single varying choice loses its ``key=`` (``experiment=whole`` -> ``whole``).

    -> ([{"color", "label" (None: no legend entry), "family" (prefix or None), "lw"}] per label,
    {family prefix: (smallest, largest number)})."""
    keys = {lb.split("=", 1)[0] for lb in labels if "=" in lb and "," not in lb}
    short = [lb.split("=", 1)[1] if len(keys) == 1 and "," not in lb and "=" in lb else lb for lb in labels]
    numbered = [re.fullmatch(r"(.*?)(\d+)", lb) for lb in short]
    count: dict[str, int] = {}
    for m in numbered:
        if m:
            count[m.group(1)] = count.get(m.group(1), 0) + 1
    families = {f: (min(int(m.group(2)) for m in numbered if m and m.group(1) == f),
                    max(int(m.group(2)) for m in numbered if m and m.group(1) == f))
                for f, n in count.items() if n >= family_min}
    singles = [i for i, m in enumerate(numbered) if not (m and m.group(1) in families)]
    # distinct colours for the runs with their own legend entry: tab10, then tab20, then a sampled colormap
    palette = (mpl.colormaps["tab10"].colors if len(singles) <= 10 else mpl.colormaps["tab20"].colors
               if len(singles) <= 20 else mpl.colormaps["turbo"](np.linspace(0, 1, len(singles))))
    styles: list[dict] = [{} for _ in labels]
    for k, i in enumerate(singles):
        # the one run outside a family (the whole model beside 28 patches) is drawn black and thicker
        color = "k" if families and len(singles) == 1 else palette[k]
        styles[i] = {"color": color, "label": short[i], "family": None, "lw": 1.6 if families else 1.0}
    cmap = mpl.colormaps["viridis"]
    for i, m in enumerate(numbered):
        if m and m.group(1) in families:
            lo, hi = families[m.group(1)]
            styles[i] = {"color": cmap((int(m.group(2)) - lo) / max(hi - lo, 1)), "label": None,
                         "family": m.group(1), "lw": 0.8}
    return styles, families


def figures(out: Path, runs, t1, t2, patches, hier) -> dict[str, str]:
    """Write the PNGs that have data; returns {name: file name} for the markdown."""
    import matplotlib  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    made = {}
    if any(r.status == OK for r in t1):
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
        for ax, m, unit in ((axes[0], VERTEX, "cm"), (axes[1], NORMAL, "1 - cos")):
            _bars(
                ax,
                [r.label for r in t1],
                [r.value(f"test/{m}") for r in t1],
                [r.paper.get(f"test_{m.split('_')[0]}") for r in t1],
                unit,
                f"Table 1: test {m}",
                [r.noise(f"test/{m}") for r in t1],
            )
        fig.tight_layout()
        save_figure(fig, out / "table1.png")
        plt.close(fig)
        made["table1"] = "table1.png"
    if any(r.status == OK for r in t2[:-1]):  # an FC row, not only the CNN
        fig, ax = plt.subplots(figsize=(7, 3.2))
        _bars(
            ax,
            [r.label for r in t2],
            [r.value(f"test/{VERTEX}") for r in t2],
            [r.paper.get("test_vertex") for r in t2],
            "cm",
            "Table 2: test vertex error",
            [r.noise(f"test/{VERTEX}") for r in t2],
        )
        fig.tight_layout()
        save_figure(fig, out / "table2.png")
        plt.close(fig)
        made["table2"] = "table2.png"
    if any(r.status == OK for r in patches) or any(r.status == OK for r in hier):
        fig, ax = plt.subplots(figsize=(9, 3.2), layout="constrained")
        ok = [r for r in patches if r.status == OK]
        ids = [int(r.label[6:]) for r in ok]
        means = [r.value(f"test/{PATCH_VERTEX}") or 0.0 for r in ok]
        errs = [r.value(f"test/{PATCH_VERTEX}_std") or 0.0 for r in ok]
        if ok:
            ax.bar(ids, means, yerr=errs if any(errs) else None, capsize=2, label="patch model (own vertices)")
        for k, (r, style) in enumerate(zip(hier, ("-", "--", ":", "-.", (0, (1, 3)), (0, (5, 1))), strict=False)):
            if r.status == OK and r.value(VERTEX) is not None and not r.select["method"].startswith("gt_"):
                ax.axhline(
                    r.value(VERTEX),
                    linestyle=style,
                    # a colour of its own per line (C0 is the bars'): axhline does not advance the cycle
                    color="k" if r.label == "whole" else f"C{k + 1}",
                    label=f"{r.label}: {fmt(r.value(VERTEX))}",
                )
        for r in patches:
            if r.status != OK:
                ax.text(int(r.label[6:]), 0, "x", ha="center", color="red")
        ax.set_xlabel("patch id")
        ax.set_ylabel("test vertex error (cm)")
        drawn_std = any(errs)
        # the error bars are drawn only from a recorded per-pose spread; without one the title says so
        ax.set_title("Hierarchy: per-patch test error (bars" + (", ±std over test poses" if drawn_std else
                                                                 "; no per-pose spread recorded, no error bars")
                     + ") vs whole / stitched (lines)", fontsize=9)
        _legend_below(fig, ax)
        save_figure(fig, out / "hierarchy.png")
        plt.close(fig)
        made["hierarchy"] = "hierarchy.png"
    curved = [r for r in runs if r.curves]
    if curved:

        styles, families = curve_styles([label_of(r, runs) for r in curved])
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), layout="constrained")
        for ax, tags, title in (
            (axes[0], TRAIN_CURVES, "training loss"),
            (axes[1], VAL_CURVES, "validation"),
        ):
            drawn = None
            # families first, so the runs with their own legend entry are drawn on top of them
            for r, st in sorted(zip(curved, styles, strict=True), key=lambda x: x[1]["family"] is None):
                tag = next((t for t in tags if t in r.curves), None)
                if tag:
                    steps, vals = zip(*r.curves[tag], strict=True)
                    ax.plot(steps, vals, lw=st["lw"], color=st["color"], label=st["label"],
                            zorder=3 if st["family"] is None else 2)
                    drawn = tag
            ax.set_title(f"{title} ({drawn or 'not logged'})", fontsize=9)
            ax.set_xlabel("step")
            if drawn and all(v > 0 for r in curved for t in [drawn] if t in r.curves for _, v in r.curves[t]):
                ax.set_yscale("log")
        for fam, (lo, hi) in families.items():
            # one colorbar per family of numbered runs instead of one legend entry (and reused colour) each
            sm = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(lo, hi), matplotlib.colormaps["viridis"])
            bar = fig.colorbar(sm, ax=list(axes), shrink=0.9, pad=0.01, aspect=30)
            bar.set_label(f"{fam.rstrip('_')} number ({fam}{lo:02d} ... {fam}{hi:02d})", fontsize=8)
            bar.set_ticks(np.unique(np.linspace(lo, hi, min(hi - lo + 1, 8)).round().astype(int)))
            bar.ax.tick_params(labelsize=7)
        _legend_below(fig, axes[1] if axes[1].get_legend_handles_labels()[0] else axes[0])
        save_figure(fig, out / "learning_curves.png")
        plt.close(fig)
        made["curves"] = "learning_curves.png"
    return made


# --------------------------------------------------------------------------------------------- markdown
def label_of(run: Run, runs: list[Run]) -> str:
    """What distinguishes this run from the others in the sweep: the choices that vary among the runs that
    have them (a sweep's evaluate job has none of the training choices), less those the experiment decides
    (`experiment=patch_07` sets `model=patch`): a 29-run hierarchy reads `experiment=patch_07`."""
    def values(k):
        return {r.choices.get(k) for r in runs if k in r.choices}

    varying = sorted(k for k in run.choices if k != "sweep" and len(values(k)) > 1)
    if "experiment" in varying:
        by_experiment: dict = {}
        for r in runs:
            if "experiment" in r.choices:
                by_experiment.setdefault(r.choices["experiment"], []).append(r)
        varying = [k for k in varying if k == "experiment" or any(
            len({r.choices.get(k) for r in group}) > 1 for group in by_experiment.values())]
    parts = [f"{k}={run.choices[k]}" for k in varying]
    return ",".join(parts) or run.get("experiment") or run.name


def _md_table(header: list[str], rows: list[list[str]]) -> str:
    def esc(s):
        return str(s).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(esc(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _problems(rows: list[Row]) -> list[str]:
    return [f"- **{r.label}**: {r.status} — {r.error}" for r in rows if r.status != OK]


def _footnote(rows: list[Row]) -> list[str]:
    if not any(r.sourced for r in rows):
        return []
    return [
        "",
        "\\* from TensorBoard: the last training epoch's running mean over the training batches (train "
        "mode), because the run's metrics.json has no pass of the best checkpoint over that split.",
    ]


def _command(sweep_dir: Path) -> str | None:
    mr = sweep_dir / "multirun.yaml"
    cfg = yaml.safe_load(mr.read_text()) if mr.exists() else None
    if not isinstance(cfg, dict):
        return None
    h = cfg.get("hydra", {})
    task = " ".join(h.get("overrides", {}).get("task", []) or [])
    params = h.get("sweeper", {}).get("params") or {}
    swept = " ".join(f"{k}={v}" for k, v in params.items())
    return f"{h.get('job', {}).get('name', '?')} -m {task}" + (f"  (swept: {swept})" if swept else "")


def relative_paths(text: str, out: Path, sweep_dir: Path) -> str:
    """`text` with the absolute paths of this machine made relative, so a report reads the same anywhere:
    paths inside the report dir relative to it ("."), the sweep dir relative to the report dir, and paths
    inside the repository relative to its root."""
    out, sweep = Path(out).resolve(), Path(sweep_dir).resolve()
    bases = {REPO: "", sweep: os.path.relpath(sweep, out), out: "."}
    for base in sorted(bases, key=lambda b: len(str(b)), reverse=True):
        if str(base) == base.anchor:
            continue
        rel = bases[base]
        # a path below the base, then the base itself (not a longer name that merely starts with it)
        text = re.sub(re.escape(str(base)) + "/", lambda _, r=rel: r + "/" if r else "", text)
        text = re.sub(re.escape(str(base)) + r"(?![\w.-])", lambda _, r=rel: r or ".", text)
    return text


# (header, metric, the paper's key) of each column of the paper's tables
TABLE1_COLUMNS = (("train vertex", f"train/{VERTEX}", "train_vertex"),
                  ("train normal", f"train/{NORMAL}", "train_normal"),
                  ("test vertex", f"test/{VERTEX}", "test_vertex"), ("test normal", f"test/{NORMAL}", "test_normal"))
TABLE2_COLUMNS = (TABLE1_COLUMNS[0], TABLE1_COLUMNS[2])


def _paper_table(rows: list[Row], has_runs: bool, first: str, columns, figure: str | None, empty: str) -> list[str]:
    """A paper table's markdown lines: one line per row (ours beside the paper's, `cell`), its problems and
    footnotes, its figure; `empty` when the sweep has no run for it."""
    if not has_runs:
        return [empty]
    lines = [_md_table([first, *(h for h, _, _ in columns), "runs"],
                       [[r.label, *(cell(r, k, pk) for _, k, pk in columns), len(r.runs)] for r in rows])]
    lines += ["", *_problems(rows), *_footnote(rows)]
    if figure:
        lines += ["", f"![{figure.split('.')[0].replace('table', 'Table ')}]({figure})"]
    return lines


def render(sweep_dir: Path, runs, t1, t2, patches, hier, cl, figs) -> str:
    n = {s: sum(r.status == s for r in runs) for s in (OK, FAILED, INCOMPLETE)}
    md = [f"# Sweep report: `{sweep_dir.name}`", ""]
    md.append(
        f"Generated {datetime.now():%Y-%m-%d %H:%M} by `python -m pbc.report`. {len(runs)} runs: "
        f"{n[OK]} ok, {n[FAILED]} failed, {n[INCOMPLETE]} incomplete."
    )
    rec = sweep_dir / SWEEP_RECORD
    if rec.exists():
        r = read_json(rec, "sweep record")
        md.append(
            f"Command: `{' '.join(r['argv'])}` (started {r['started']}, wall time "
            f"{r['seconds'] / 60:.1f} min; steps: "
            + ", ".join(f"{s['step']} {s['seconds']:.0f} s exit {s['returncode']}" for s in r["steps"])
            + ")"
        )
        md += [f"- step **{st['step']}** failed: {st.get('error')}" for st in r["steps"] if st["returncode"]]
    elif cmd := _command(sweep_dir):
        md.append(f"Command: `{cmd}`")
    sizes = sorted(
        {
            (r.cfg("data.name"), r.cfg("data.num_samples"), r.cfg("trainer.max_epochs"))
            for r in runs
            if r.cfg("data.name")
        },
        key=str,
    )
    if sizes:
        md.append(
            "Data / schedule: " + "; ".join(f"{d} ({ns} samples requested), max_epochs {e}" for d, ns, e in sizes)
        )
    md += [
        "",
        "Numbers are ours; the paper's are in parentheses. Vertex errors in cm, normal errors as "
        "cosine distance. A row with several runs shows their mean.",
        "",
    ]

    md += ["## The paper's claims on our data", ""]
    md.append(_md_table(["claim", "paper", "ours", "verdict"], [[c.text, c.paper, c.ours, c.verdict] for c in cl]))
    md += ["", f"A claim is *{TIE}* when some compared pair differs by at most {TIE_RELATIVE:.0%}: with one run "
           "per setting that is within run-to-run noise, so it neither supports nor refutes the ordering. With "
           f"several seeds a setting shows their mean ± half their range, and a pair no further apart than the "
           f"larger range is *{WITHIN_NOISE}*."]

    md += ["", "## Table 1: loss functions (whole-shirt CNN)", ""]
    md += _paper_table(t1, any(r.runs for r in t1), "loss", TABLE1_COLUMNS, figs.get("table1"),
                       "No whole-shirt runs in this sweep (run the `losses` sweep).")
    md += ["", "## Table 2: fully connected baselines vs. the CNN", ""]
    md += _paper_table(t2, any(r.runs for r in t2[:-1]), "model", TABLE2_COLUMNS, figs.get("table2"),
                       "No FC runs in this sweep (run the `architectures` sweep).")

    md += ["", "## Hierarchy: whole vs. stitched patches", ""]
    if hier:
        present = {k for r in hier for k in r.values}
        keys = [k for k in HIERARCHY_COLUMNS if k in present] + sorted(present - set(HIERARCHY_COLUMNS))
        md.append(
            _md_table(
                ["model", *[HIERARCHY_COLUMNS.get(k, k) for k in keys], "status"],
                [
                    [
                        r.label,
                        *[fmt(r.value(k)) for k in keys],
                        r.status if r.status == OK else f"{r.status}: {r.error}",
                    ]
                    for r in hier
                ],
            )
        )
    else:
        md.append("No `pbc.evaluate` run in this sweep (the `hierarchy` sweep runs it after training).")
    if patches:
        md += ["", "Per-patch models (each scored on the vertices inside its patch):", ""]
        md.append(
            _md_table(
                ["patch", "train patch vertex", "test patch vertex", "test patch normal", "status"],
                [
                    [
                        r.label,
                        cell(r, f"train/{PATCH_VERTEX}"),
                        cell(r, f"test/{PATCH_VERTEX}"),
                        cell(r, f"test/{PATCH_NORMAL}"),
                        r.status if r.status == OK else f"{r.status}: {r.error}",
                    ]
                    for r in patches
                ],
            )
        )
    if "hierarchy" in figs:
        md += ["", f"![Hierarchy]({figs['hierarchy']})"]

    md += ["", "## Learning curves", ""]
    md.append(f"![Learning curves]({figs['curves']})" if "curves" in figs else "No TensorBoard events found.")

    md += ["", "## All runs", ""]
    md.append(
        _md_table(
            ["run", "label", "status", "test vertex", "test normal", "error"],
            [
                [
                    f"`{r.name}`",
                    label_of(r, runs),
                    r.status,
                    _scoped_cell(r, VERTEX),
                    _scoped_cell(r, NORMAL),
                    r.error or "",
                ]
                for r in runs
            ],
        )
    )
    md.append("")
    return "\n".join(md)


def load_paper(path: Path = PAPER_FILE) -> dict:
    paper = yaml.safe_load(Path(path).read_text()) or {}
    t1 = paper.setdefault("table1", {})
    # Table 2's CNN row is Table 1's L1 row: the paper compares them in the text of E.3.
    paper.setdefault("table2", {})
    l1 = t1.get("l1", {})
    paper["table2"]["cnn_train_vertex"] = l1.get("train_vertex")
    paper["table2"]["cnn_test_vertex"] = l1.get("test_vertex")
    return paper


def build_report(
    sweep_dir: Path, out_dir: Path | None = None, paper_file: Path = PAPER_FILE, plots: bool = True
) -> Path:
    """Read the runs under sweep_dir, write report.md/report.json/PNGs into out_dir (default: sweep_dir)."""
    sweep_dir = Path(sweep_dir)
    runs = load_runs(sweep_dir)
    if not runs:
        raise FileNotFoundError(f"no run dirs (.hydra/ or metrics.json) under {sweep_dir}")
    out = Path(out_dir) if out_dir else sweep_dir
    out.mkdir(parents=True, exist_ok=True)
    paper = load_paper(paper_file)
    t1 = table1(runs, paper["table1"])
    t2 = table2(runs, paper["table2"])
    patches = patch_rows(runs, expected_jobs(sweep_dir))
    hier = hierarchy_rows(runs)
    cl = claims(t1, t2, hier, paper)
    figs = figures(out, runs, t1, t2, patches, hier) if plots else {}
    md = render(sweep_dir.resolve(), runs, t1, t2, patches, hier, cl, figs)
    md += ("\nPaths are relative to this report's folder; paths without a leading `.` are relative to the "
           "repository root.\n")
    write_text(out / "report.md", relative_paths(md, out, sweep_dir))
    data = {
        "sweep_dir": str(sweep_dir.resolve()),
        "runs": [
            {"name": r.name, "status": r.status, "error": r.error, "choices": r.choices, "metrics": r.metrics}
            for r in runs
        ],
        "table1": [r.__dict__ for r in t1],
        "table2": [r.__dict__ for r in t2],
        "patches": [r.__dict__ for r in patches],
        "hierarchy": [r.__dict__ for r in hier],
        "claims": [c.__dict__ for c in cl],
        "figures": figs,
    }
    text = json.dumps(data, indent=1, default=str, allow_nan=True)
    write_text(out / "report.json", relative_paths(text, out, sweep_dir))
    return out / "report.md"
