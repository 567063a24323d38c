"""The mend of a predicted garment (pbc.geometry.mend): a stretched edge shortened and cloth pushed out of a
collider by one screened solve each, a mesh that needs neither left bit-equal; its settings read from
conf/mend.yaml and held to conf/bounds.yaml; the shipped shirt mended by default (ClothPredictor.mend)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh
from helpers.cli import exit_code
from omegaconf import OmegaConf

from pbc.core.validate import check_settings_file
from pbc.geometry.mend import (
    SETTINGS_FILE,
    Collider,
    MendSettings,
    edge_ratios,
    mend_settings,
    push_out_of,
    shorten_edges,
)
from pbc.geometry.meshops import mesh_edges, surface_distance

SETTINGS = MendSettings()


def sheet(n: int = 12, size: float = 0.2, y: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A flat square sheet of n x n vertices in the xz-plane at height y: (vertices (n*n, 3), faces)."""
    u, v = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij")
    x = np.stack([u.ravel(), np.full(n * n, y), v.ravel()], 1)
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    # wound so the normals point up (+y): the sheet's outside is above it
    return x, np.concatenate([np.stack([a, d, c], 1), np.stack([a, c, b], 1)])


def test_a_mesh_needing_no_mend_comes_back_bit_equal():
    x, f = sheet()
    edges = mesh_edges(f)
    usual = edge_ratios(x, edges, np.ones(len(edges)))  # each edge's own length
    y, st = shorten_edges(x, edges, usual, SETTINGS)
    assert y is not None and np.array_equal(y, x) and st["stretched"] == 0 and st["moved_mm"] == 0.0
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    far = Collider(np.asarray(ball.vertices) + [0.0, -0.5, 0.0], np.asarray(ball.faces))
    y, st = push_out_of(x, edges, [far], replace(SETTINGS, push_out=True))
    assert np.array_equal(y, x) and st["inside"] == 0 and st["passes"] == 0


def test_a_shard_is_pulled_back_and_the_far_cloth_stays_put():
    x, f = sheet()
    edges = mesh_edges(f)
    usual = edge_ratios(x, edges, np.ones(len(edges)))
    shard = x.copy()
    centre = 5 * 12 + 5
    shard[centre, 1] += 0.08  # one vertex 8 cm off its 1.8 cm neighbours: edges past 4x their length
    before = edge_ratios(shard, edges, usual)
    assert before.max() > 4.0
    y, st = shorten_edges(shard, edges, usual, SETTINGS)
    assert st["stretched"] == int((before > SETTINGS.stretch_cap).sum()) > 0
    assert st["ratio_before"] == pytest.approx(before.max())
    assert edge_ratios(y, edges, usual).max() <= 1.15 * SETTINGS.stretch_cap < before.max()
    assert st["ratio_after"] == pytest.approx(edge_ratios(y, edges, usual).max())
    # the correction stays local: the sheet's corners barely move, the shard moves most
    moved = np.linalg.norm(y - shard, axis=1)
    assert moved.argmax() == centre and moved[[0, 11, 132, 143]].max() < 1e-3 < moved[centre]
    off = replace(SETTINGS, stretch_cap=0.0)
    assert np.array_equal(shorten_edges(shard, edges, usual, off)[0], shard)


def test_cloth_inside_a_body_is_pushed_out_to_the_margin():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    body = Collider(np.asarray(ball.vertices), np.asarray(ball.faces))
    x, f = sheet(n=16, size=0.3, y=0.03)  # the sheet cuts through the ball's cap
    edges = mesh_edges(f)
    settings = replace(SETTINGS, push_out=True)
    d0 = surface_distance(x, body.vertices, body.faces)[0]
    assert (d0 < 0).sum() > 5
    y, st = push_out_of(x, edges, [body], settings)
    d1 = surface_distance(y, body.vertices, body.faces)[0]
    assert st["inside"] == int((d0 < 0).sum()) and st["inside_after"] == int((d1 < 0).sum()) == 0
    assert d1.min() > 0.5 * settings.margin
    assert st["depth_max_mm"] == pytest.approx(-d0.min() * 1e3)
    # the sheet's rim, far from the ball, moves a tenth of what its middle does
    rim = np.abs(x[:, [0, 2]]).max(1) > 0.14
    moved = np.linalg.norm(y - x, axis=1)
    assert moved[rim].max() < 0.1 * moved.max()
    # off: nothing moves, the count is still reported
    z, st = push_out_of(x, edges, [body], replace(settings, push_out=False))
    assert np.array_equal(z, x) and st["inside_after"] == st["inside"] > 0
    # a collider holding none of the vertices (its mask) judges none
    masked = Collider(body.vertices, body.faces, mask=np.zeros(len(x), bool))
    assert push_out_of(x, edges, [masked], settings)[1]["inside"] == 0


def test_an_outer_layer_is_pushed_out_of_an_open_inner_one_within_the_band():
    inner_v, inner_f = sheet(n=10, size=0.3, y=0.0)  # open, outside up
    outer, f = sheet(n=12, size=0.2, y=0.01)
    outer[:, 1] = 0.01 - 0.02 * np.exp(-(outer[:, 0] ** 2 + outer[:, 2] ** 2) / 0.002)  # dips 1 cm under it
    edges = mesh_edges(f)
    layer = Collider(inner_v, inner_f, closed=False)
    settings = replace(SETTINGS, push_out=True)
    y, st = push_out_of(outer, edges, [layer], settings)
    assert st["inside"] > 0 and st["inside_after"] == 0
    assert y[:, 1].min() > 0.5 * settings.margin
    # cloth farther under an open layer than push_band is not judged by it (it lies on another side of the body)
    deep = outer.copy()
    deep[:, 1] -= 0.2
    assert push_out_of(deep, edges, [layer], settings)[1]["inside"] == 0


def test_settings_come_from_conf_and_are_held_to_bounds(tmp_path):
    assert mend_settings() == MendSettings()  # the dataclass's defaults mirror conf/mend.yaml
    assert mend_settings(stretch_cap=2.5).stretch_cap == 2.5
    with pytest.raises(ValueError, match="unknown mend setting.*stretch_kap"):
        mend_settings(stretch_kap=2.5)
    node = OmegaConf.load(SETTINGS_FILE)
    node.anchor = -1.0
    with pytest.raises(ValueError, match=r"mend.yaml: anchor=-1.0 .*expected a number in \(0, 1000\]"):
        check_settings_file("mend", node, tmp_path / "mend.yaml")


def test_the_shipped_shirt_is_mended_by_default_and_not_with_no_mend(tmp_path, capsys):
    """The shirt's armpit stretches edges past 3x their usual length on some of its own test poses; mended, no
    edge passes 3x and the garment is no farther from the simulator's drapes."""
    from pbc.cli.predict import main
    from pbc.inference.predictor import ClothPredictor

    pred = ClothPredictor.from_pretrained("tshirt")
    assert pred.mend == mend_settings()
    ds = pred.dataset
    test = np.asarray(ds.split("test"))[:30]
    poses = torch.from_numpy(np.asarray(ds.poses)[test].astype(np.float32))
    truth = np.asarray(ds.verts)[test]
    stats: list[dict] = []
    mended = pred(poses, model="whole", mend_stats=stats).numpy()
    pred.mend = None
    raw = pred(poses, model="whole").numpy()
    edges, usual = pred.edge_lengths()
    ratio = lambda v: np.stack([edge_ratios(p, edges, usual).max() for p in v])  # noqa: E731
    assert ratio(raw).max() > 3.0 > ratio(mended).max()
    assert len(stats) == len(test) and sum(st["stretched"] > 0 for st in stats) > 0
    err = lambda v: np.linalg.norm(v - truth, axis=-1).mean()  # noqa: E731
    assert err(mended) <= err(raw)
    out = tmp_path / "out"
    assert exit_code(main, ["--pretrained", "tshirt", "--poses", "test", "--max", "4", "--sheet", "0",
                            "--out", str(out)]) == 0
    report = json.loads((out / "predict.json").read_text())["mend"]
    assert report["on"] and report["stretch_cap"] == SETTINGS.stretch_cap
    assert "mend:" in capsys.readouterr().out
    assert exit_code(main, ["--pretrained", "tshirt", "--poses", "test", "--max", "4", "--sheet", "0",
                            "--no-mend", "--out", str(tmp_path / "raw")]) == 0
    assert json.loads((tmp_path / "raw" / "predict.json").read_text())["mend"]["on"] is False
    assert "mend: off" in capsys.readouterr().out
