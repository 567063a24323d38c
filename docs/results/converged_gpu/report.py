"""Tables and figure of docs/results/converged_gpu/results*.json (written by run.py in three GPU sessions: the
first seeds on an H100, then on an H200 the second seeds, the hierarchy (results_h200.json) and its second seed
with Table 2 under L2 (results_h200b.json)).

    python docs/results/converged_gpu/report.py      # -> tables.md, converged_gpu.png beside this file
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
FC = ("fc_direct_local", "fc_pca_local", "fc_direct_root", "fc_pca_root", "fc_direct_position", "fc_pca_position")
PAPER = {"l1": 0.44, "l2": 0.47, "l2_normal": 0.51, "fc_direct_local": 0.67, "fc_pca_local": 0.55,
         "fc_direct_root": 0.72, "fc_pca_root": 0.58, "fc_direct_position": 0.68, "fc_pca_position": 0.65}


def seeds(runs: dict, prefix: str) -> list[dict]:
    return [r for k, r in sorted(runs.items()) if k.rsplit("_s", 1)[0] == prefix and r.get("test")]


def row(name: str, rs: list[dict], mean_shape: float) -> str:
    err = [r["test"]["vertex_error_cm"] for r in rs]
    nd = [r["test"]["normal_distance"] for r in rs]
    real = [r["mocap"]["model_cm"] for r in rs if "mocap" in r]
    real_txt = " / ".join(f"{x:.3f}" for x in real) if real else "not scored"
    per_seed = " / ".join(f"{e:.3f}" for e in err)
    return (f"| {name} | {per_seed} | {np.mean(err):.3f} | {np.mean(err) / mean_shape:.2f}x | "
            f"{np.mean(nd):.4f} | {real_txt} | {PAPER.get(name.split(' ')[0], '-')} |")


SESSIONS = ("results.json", "results_h200.json", "results_h200b.json")


def all_runs() -> dict:
    """Every run of the three sessions by name. A later session's repeat of a run (the hierarchy's whole models,
    table1_l1_s*, trained again beside their patches) replaces it, never counts as another seed: the repeats
    reproduced the first runs to 0.0001 cm."""
    runs = {}
    for name in SESSIONS:
        if (HERE / name).is_file():
            runs.update(json.loads((HERE / name).read_text())["runs"])
    return runs


def hierarchy_lines(runs: dict) -> list[str]:
    """One table, a column pair per seed: each seed's stitched patches beside its own whole model."""
    evs = {int(k.rsplit("_s", 1)[1]): r for k, r in sorted(runs.items()) if k.startswith("evaluate_s")}
    if not evs:
        return []
    rows = [("training mean shape", "train_mean"), ("whole CNN (L1)", "whole")] + [
        (f"28 patches stitched: {m}", f"patches_{m}") for m in ("pca", "cage", "average", "inpaint", "hierarchy",
                                                                "hierarchy_detail")]
    seeds_ = sorted(evs)
    n = evs[seeds_[0]]["num_samples"]
    out = ["", f"### Hierarchy: 28 stitched patch models vs the whole model (L1, {n} test poses, seeds "
           f"{' / '.join(map(str, seeds_))})", "",
           "| entry | vertex error (cm), per seed | mean | normal distance, per seed | seam jump (cm), per seed |",
           "| --- | --- | --- | --- | --- |"]
    for label, k in rows:
        have = [evs[s]["entries"][k] for s in seeds_ if k in evs[s]["entries"]]
        if not have:
            continue

        def per(key, fmt, k=k):
            return " / ".join(format(evs[s]["entries"][k][key], fmt) if k in evs[s]["entries"] else "-"
                              for s in seeds_)

        note = "" if len(have) == len(seeds_) else " (one seed)"
        out.append(f"| {label} | {per('vertex_error_cm', '.3f')} | "
                   f"{np.mean([h['vertex_error_cm'] for h in have]):.3f}{note}"
                   f" | {per('normal_distance', '.4f')} | {per('seam_jump_cm', '.3f')} |")
    out.append("")
    for s in seeds_:
        hier, ev = runs[f"hier_patches_s{s}"], evs[s]
        out.append(f"Seed {s}: patch models {hier['epochs']} of 41 epochs ({hier['stopped_by']}); neighbouring "
                   f"patches disagree by {ev['patch_disagreement_before_blend_cm']:.3f} cm across {ev['seam_edges']} "
                   "seam edges before blending.")
    return out


def main() -> None:
    runs = all_runs()
    base = runs["table1_l1_s0"]
    ms, ms_real = base["sampled"]["mean_shape_cm"], base["mocap"]["mean_shape_cm"]
    head = ("| setting | test error per seed (cm) | mean | vs mean shape | normal distance "
            "| real frames (cm, per seed) | paper (cm) |\n| --- | --- | --- | --- | --- | --- | --- |")
    lines = [f"Training mean shape on the same rows: {ms:.3f} cm on the 92 sampled test poses, {ms_real:.3f} cm on "
             "the 18 motion-capture frames.", "", "### Table 1: the whole-shirt CNN under each loss", "", head]
    lines += [row(loss, seeds(runs, f"table1_{loss}"), ms) for loss in ("l1", "l2", "l2_normal", "l1_normal")]
    lines += ["", "### Table 2: fully connected baselines beside the CNN, under L1 and under L2", "", head]
    lines += [row("cnn (l1)", seeds(runs, "table1_l1"), ms), row("cnn (l2)", seeds(runs, "table1_l2"), ms)]
    lines += [row(f"{e} ({loss})", seeds(runs, f"table2_{'' if loss == 'l1' else 'l2_'}{e}"), ms)
              for loss in ("l1", "l2") for e in FC]
    lines += ["", "### Learning curve: the whole CNN (L1), first n training drapes, no mirrors, seeds 0 / 1", "",
              "| training poses | epochs | best epoch | test (cm) | its mean shape (cm) | ratio | real frames (cm) | "
              "its mean shape there | ratio |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    curve = {}
    for k, r in runs.items():
        if k.startswith("curve_") and r.get("test"):
            curve.setdefault(r["train_rows"], []).append(r)
    curve = {n: sorted(rs, key=lambda r: r["seed"]) for n, rs in sorted(curve.items())}

    def both(rs, f):
        return " / ".join(f(r) for r in rs)

    for n, rs in curve.items():
        lines.append(f"| {n} | {both(rs, lambda r: str(r['epochs']))} | "
                     f"{both(rs, lambda r: str(int(r['best_checkpoint'][6:9])))} | "
                     f"{both(rs, lambda r: format(r['test']['vertex_error_cm'], '.3f'))} | "
                     f"{rs[0]['sampled']['mean_shape_cm']:.3f} | "
                     f"{np.mean([r['test']['vertex_error_cm'] for r in rs]) / rs[0]['sampled']['mean_shape_cm']:.2f} | "
                     f"{both([r for r in rs if 'mocap' in r], lambda r: format(r['mocap']['model_cm'], '.3f'))} | "
                     f"{rs[0]['mocap']['mean_shape_cm']:.3f} | "
                     f"{np.mean([r['mocap']['ratio'] for r in rs if 'mocap' in r]):.2f} |")
    lines += hierarchy_lines(runs)
    (HERE / "tables.md").write_text("\n".join(lines) + "\n")

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    x = list(curve)
    for key, style, label in (("sampled", "-o", "sampled test poses"), ("mocap", "-s", "motion-capture frames")):
        def err(r, key=key):  # the sampled test poses are pbc.train's own test split: its metric where unscored
            return r[key]["model_cm"] if key in r else (r["test"]["vertex_error_cm"] if key == "sampled" else None)

        mean = [np.mean([e for e in map(err, rs) if e is not None]) for rs in curve.values()]
        ax[0].plot(x, mean, style, color="C0" if key == "sampled" else "C2", label=f"model, {label} (mean of seeds)")
        for n, rs in curve.items():
            ys = [e for e in map(err, rs) if e is not None]
            ax[0].plot([n] * len(ys), ys, ".", color="k", ms=5)
        ax[0].plot(x, [rs[0][key]["mean_shape_cm"] for rs in curve.values()], style,
                   color="C1" if key == "sampled" else "C3", alpha=0.6, label=f"training mean shape, {label}")
    mir = seeds(runs, "table1_l1")
    ax[0].plot([739] * len(mir), [r["sampled"]["model_cm"] for r in mir], "^", color="C4",
               label="739 + 739 mirror images (2 seeds), sampled")
    ax[0].set_xscale("log")
    ax[0].set_xticks(x, [str(v) for v in x])
    ax[0].minorticks_off()
    ax[0].set_xlabel("training poses (draped)")
    ax[0].set_ylabel("mean vertex error (cm)")
    ax[0].set_title("learning curve, whole CNN (L1), trained to the schedule's end, 2 seeds")
    ax[0].legend(fontsize=7)
    panels = ((ax[1], [("l1", "table1_l1"), ("l2", "table1_l2"), ("l2_normal", "table1_l2_normal"),
                       ("l1_normal", "table1_l1_normal")], "Table 1: losses (1,478 rows)"),
              (ax[2], [("cnn", "table1_l1")] + [(e.replace("fc_", ""), f"table2_{e}") for e in FC],
               "Table 2: FC baselines vs CNN, L1 (blue) and L2 (green)"))
    for a, names, title in panels:
        l2_twin = a is ax[2]  # Table 2: each setting's L2 runs beside its L1 runs
        for i, (_label, prefix) in enumerate(names):
            twins = [(prefix, "C0", -0.2 if l2_twin else 0.0)]
            if l2_twin:
                twins.append((prefix.replace("table1_l1", "table1_l2").replace("table2_", "table2_l2_"), "C2", 0.2))
            for pre, colour, dx in twins:
                err = [r["test"]["vertex_error_cm"] for r in seeds(runs, pre)]
                a.bar(i + dx, np.mean(err), width=0.4 if l2_twin else 0.8, color=colour, alpha=0.5)
                a.plot([i + dx] * len(err), err, "k.", ms=8)
            paper = PAPER.get(prefix.replace("table1_", "").replace("table2_", ""))
            if paper:
                a.plot(i, paper, "r_", ms=18, mew=2)
        a.axhline(ms, color="C1", ls="--", label=f"training mean shape {ms:.2f} cm")
        a.set_xticks(range(len(names)), [n for n, _ in names], rotation=30, ha="right")
        a.set_title(title + " (dots: seeds; red: paper)", fontsize=9)
        a.set_ylabel("test vertex error (cm)")
        a.legend(fontsize=7)
    fig.suptitle("Converged on one GPU (first seeds H100; second seeds, hierarchy, Table 2 under L2 H200): the default "
                 "data config, 923 kept "
                 "drapes (739 training + 739 mirror images); black dots: seeds")
    fig.tight_layout()
    fig.savefig(HERE / "converged_gpu.png", dpi=110)
    print((HERE / "tables.md").read_text())


if __name__ == "__main__":
    main()
