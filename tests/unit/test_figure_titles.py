"""Figure labels say what each panel shows: Fig. 10's panels (pbc.jobs.robustness.fig10) each carry their own cloth's
numbers, not the other panel's; drawn from synthetic meshes, no model."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

import pbc.jobs.robustness as robustness


def _sheet(n: int = 5, z: float = 0.0):
    t = np.linspace(0, 0.5, n)
    v = np.stack(np.meshgrid(t, t), -1).reshape(-1, 2)
    quads = [(i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1)
             for i in range(n - 1) for j in range(n - 1)]
    f = np.array([[a, c, b] for a, b, c, d in quads] + [[b, c, d] for a, b, c, d in quads])
    return torch.tensor(np.c_[v, np.full(len(v), z)], dtype=torch.float32), torch.tensor(f)


def test_fig10_titles_each_panel_with_its_own_cloth(tmp_path, monkeypatch):
    cloth, faces = _sheet()
    body, body_faces = _sheet(z=-0.05)
    ds = SimpleNamespace(body=SimpleNamespace(faces=body_faces), garment=SimpleNamespace(faces=faces))
    nv = len(cloth)
    off_pred = torch.zeros(nv, 3)
    off_pred[:, 2] = 0.01  # every predicted vertex above the body
    off_sim = off_pred.clone()
    off_sim[: nv // 5, 2] = -0.01  # 5 of the 25 simulated vertices below it: 20 %
    pred = cloth + torch.tensor([0.0, 0.0, 0.03])  # 3 cm from the simulation at every vertex
    monkeypatch.setattr(robustness, "predict_on",
                        lambda run, data, index: (pred, cloth, off_pred, off_sim, body, ds))
    titles = []
    draw = robustness._draw_scene
    monkeypatch.setattr(robustness, "_draw_scene",
                        lambda ax, bv, bf, cv, cf, title: (titles.append(title), draw(ax, bv, bf, cv, cf, title)))
    (tmp_path / "shape_2.0").mkdir()
    (tmp_path / "shape_2.0" / "metrics.json").write_text(json.dumps({"status": "ok"}))
    out = robustness.fig10(tmp_path / "fig10.png", tmp_path, ["shape_2.0"], 0)
    assert (tmp_path / "fig10.png").stat().st_size > 0
    pen = out["shape_2.0"]
    assert abs(pen["ground_truth"]["fraction"] - 0.2) < 1e-6 and pen["predicted"]["fraction"] == 0
    predicted, simulated = titles
    assert "prediction" in predicted and "3.00 cm error" in predicted and "0% of vertices below" in predicted
    # the simulated cloth has no error against itself: its panel states its own penetration
    assert "simulated" in simulated and "20% of vertices below" in simulated and "error" not in simulated


def _sweep_runs(tmp_path):
    """A hierarchy-like sweep: 28 patch runs and the whole model, each with a train and a val curve."""
    from pbc.core.runs import OK, Run

    names = [f"patch_{i:02d}" for i in range(28)] + ["whole"]
    return [Run(path=tmp_path / n, name=n, choices={"experiment": n, "loss": "l1", "sweep": "hierarchy"},
                status=OK,
                curves={"train/loss_step": [(s, 0.1 / (s + 1) + 0.001 * k) for s in range(0, 100, 10)],
                        "val/vertex_error_cm": [(s, 3.0 / (s + 1) + 0.01 * k) for s in range(0, 100, 10)]})
            for k, n in enumerate(names)]


def test_curve_styles_fold_numbered_runs_into_one_colormap(tmp_path):
    from pbc.jobs.report import curve_styles, label_of

    runs = _sweep_runs(tmp_path)
    styles, families = curve_styles([label_of(r, runs) for r in runs])
    assert families == {"patch_": (0, 27)}
    # one legend entry, the whole model, short (no "experiment="): not 29 override strings
    assert [s["label"] for s in styles if s["label"]] == ["whole"]
    patch_colours = {tuple(s["color"]) for s in styles[:28]}
    assert len(patch_colours) == 28 and styles[28]["color"] == "k"
    # runs outside a family get distinct colours even past the 10 of the default cycle
    many = [f"loss={x}" for x in "abcdefghijklmn"]
    styles, families = curve_styles(many)
    assert families == {} and len({tuple(s["color"]) for s in styles}) == len(many)
    assert [s["label"] for s in styles] == list("abcdefghijklmn")


def test_learning_curves_legend_is_short_and_outside(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from pbc.jobs import report

    runs = _sweep_runs(tmp_path)
    made = {}
    real_save = report.save_figure

    def keep(fig, path, **kw):  # read the figure before it is closed
        made[Path(path).name] = ([t.get_text() for lg in fig.legends for t in lg.get_texts()],
                                 [a.get_legend() for a in fig.axes], [a.get_ylabel() for a in fig.axes])
        real_save(fig, path, **kw)

    monkeypatch.setattr(report, "save_figure", keep)
    report.figures(tmp_path, runs, [], [], [], [])
    plt.close("all")
    figure_legend, axes_legends, ylabels = made["learning_curves.png"]
    assert figure_legend == ["whole"]  # one short entry, in a figure legend outside the plots
    assert axes_legends == [None] * len(axes_legends)  # no legend drawn over the curves
    assert any("patch number" in y for y in ylabels)  # the colorbar names the family
    assert (tmp_path / "learning_curves.png").stat().st_size > 0


def test_hierarchy_title_promises_error_bars_only_when_drawn(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from pbc.core.runs import OK
    from pbc.jobs import report
    from pbc.jobs.report import PATCH_VERTEX, VERTEX, Row

    def rows(with_std):
        return [Row(label=f"patch_{i:02d}", select={}, status=OK,
                    values={f"test/{PATCH_VERTEX}": 2.0 + i / 10,
                            **({f"test/{PATCH_VERTEX}_std": 0.3} if with_std else {})}) for i in range(4)]

    hier = [Row(label="whole", select={"method": "whole"}, status=OK, values={VERTEX: 2.5})]
    seen = []  # (title, number of error-bar segments) of each hierarchy figure, read before it is closed
    real_save = report.save_figure

    def keep(fig, path, **kw):
        ax = fig.axes[0]
        seen.append((ax.get_title(), sum(len(c.get_segments()) for c in ax.collections
                                         if hasattr(c, "get_segments"))))
        real_save(fig, path, **kw)

    monkeypatch.setattr(report, "save_figure", keep)
    for with_std in (False, True):
        report.figures(tmp_path, [], [], [], rows(with_std), hier)
        plt.close("all")
    (plain, plain_bars), (with_bars, n_bars) = seen
    assert "±std" not in plain and "no error bars" in plain and plain_bars == 0
    assert "±std" in with_bars and "no error bars" not in with_bars and n_bars == 4  # one bar per patch
