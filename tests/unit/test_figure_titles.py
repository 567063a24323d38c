"""Figure labels say what each panel shows: Fig. 10's panels (pbc.robustness.fig10) each carry their own cloth's
numbers, not the other panel's; drawn from synthetic meshes, no model."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import torch

import pbc.robustness as robustness


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
