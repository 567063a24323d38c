"""Tables and figure of docs/results/converged_gpu/results.json (written by run.py on the GPU machine).

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
            f"{np.mean(nd):.4f} | {real_txt} | {PAPER.get(name, '-')} |")


def main() -> None:
    runs = json.loads((HERE / "results.json").read_text())["runs"]
    base = runs["table1_l1_s0"]
    ms, ms_real = base["sampled"]["mean_shape_cm"], base["mocap"]["mean_shape_cm"]
    head = ("| setting | test error per seed (cm) | mean | vs mean shape | normal distance "
            "| real frames (cm, per seed) | paper (cm) |\n| --- | --- | --- | --- | --- | --- | --- |")
    lines = [f"Training mean shape on the same rows: {ms:.3f} cm on the 92 sampled test poses, {ms_real:.3f} cm on "
             "the 18 motion-capture frames.", "", "### Table 1: the whole-shirt CNN under each loss", "", head]
    lines += [row(loss, seeds(runs, f"table1_{loss}"), ms) for loss in ("l1", "l2", "l2_normal", "l1_normal")]
    lines += ["", "### Table 2: fully connected baselines (L1) beside the CNN", "", head]
    lines += [row("cnn (l1)", seeds(runs, "table1_l1"), ms), row("cnn (l2)", seeds(runs, "table1_l2"), ms)]
    lines += [row(e, seeds(runs, f"table2_{e}"), ms) for e in
              ("fc_direct_local", "fc_pca_local", "fc_direct_root", "fc_pca_root", "fc_direct_position",
               "fc_pca_position")]
    lines += ["", "### Learning curve: the whole CNN (L1), first n training drapes, no mirrors, seed 0", "",
              "| training poses | epochs | best epoch | test (cm) | its mean shape (cm) | ratio | real frames (cm) | "
              "its mean shape there | ratio |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    curve = sorted((r for k, r in runs.items() if k.startswith("curve_")), key=lambda r: r["train_rows"])
    for r in curve:
        sampled, real = r["sampled"], r["mocap"]
        lines.append(f"| {r['train_rows']} | {r['epochs']} | {int(r['best_checkpoint'][6:9])} | "
                     f"{sampled['model_cm']:.3f} | {sampled['mean_shape_cm']:.3f} | {sampled['ratio']:.2f} | "
                     f"{real['model_cm']:.3f} | {real['mean_shape_cm']:.3f} | {real['ratio']:.2f} |")
    (HERE / "tables.md").write_text("\n".join(lines) + "\n")

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    x = [r["train_rows"] for r in curve]
    for key, style, label in (("sampled", "-o", "sampled test poses"), ("mocap", "-s", "motion-capture frames")):
        ax[0].plot(x, [r[key]["model_cm"] for r in curve], style, color="C0" if key == "sampled" else "C2",
                   label=f"model, {label}")
        ax[0].plot(x, [r[key]["mean_shape_cm"] for r in curve], style, color="C1" if key == "sampled" else "C3",
                   alpha=0.6, label=f"training mean shape, {label}")
    mir = seeds(runs, "table1_l1")
    ax[0].plot([739] * len(mir), [r["sampled"]["model_cm"] for r in mir], "^", color="C4",
               label="739 + 739 mirror images (2 seeds), sampled")
    ax[0].set_xscale("log")
    ax[0].set_xticks(x, [str(v) for v in x])
    ax[0].minorticks_off()
    ax[0].set_xlabel("training poses (draped)")
    ax[0].set_ylabel("mean vertex error (cm)")
    ax[0].set_title("learning curve, whole CNN (L1), trained to the schedule's end")
    ax[0].legend(fontsize=7)
    for a, names, title in ((ax[1], [("l1", "table1_l1"), ("l2", "table1_l2"), ("l2_normal", "table1_l2_normal"),
                                      ("l1_normal", "table1_l1_normal")], "Table 1: losses (1,478 rows)"),
                            (ax[2], [("cnn l1", "table1_l1"), ("cnn l2", "table1_l2")] +
                             [(e.replace("fc_", ""), f"table2_{e}") for e in
                              ("fc_direct_local", "fc_pca_local", "fc_direct_root", "fc_pca_root",
                               "fc_direct_position", "fc_pca_position")], "Table 2: FC baselines vs CNN")):
        for i, (_label, prefix) in enumerate(names):
            err = [r["test"]["vertex_error_cm"] for r in seeds(runs, prefix)]
            a.bar(i, np.mean(err), color="C0", alpha=0.5)
            a.plot([i] * len(err), err, "k.", ms=8)
            paper = PAPER.get(prefix.replace("table1_", "").replace("table2_", ""))
            if paper:
                a.plot(i, paper, "r_", ms=18, mew=2)
        a.axhline(ms, color="C1", ls="--", label=f"training mean shape {ms:.2f} cm")
        a.set_xticks(range(len(names)), [n for n, _ in names], rotation=30, ha="right")
        a.set_title(title + " (dots: seeds; red: paper)")
        a.set_ylabel("test vertex error (cm)")
        a.legend(fontsize=7)
    fig.suptitle("Converged on one H100: the default data config, 923 kept drapes (739 training + 739 mirror images)")
    fig.tight_layout()
    fig.savefig(HERE / "converged_gpu.png", dpi=110)
    print((HERE / "tables.md").read_text())


if __name__ == "__main__":
    main()
