"""An outfit at inference (pbc.inference.outfit, `pbc outfit predict`): layers composed inner to outer, each pushed
out of the layers under it, the order inferred from which piece covers which, bad input refused in one line with
nothing written, and outfit.json's figures the ones its files give."""

from __future__ import annotations

import copy
import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh
from omegaconf import OmegaConf

from pbc.cli import outfit as cli
from pbc.core.validate import check_settings_file
from pbc.geometry.mend import mend_settings
from pbc.geometry.meshops import surface_distance
from pbc.inference.outfit import (
    SETTINGS_FILE,
    LayerMesh,
    OutfitPredictor,
    OutfitSettings,
    check_order,
    compose_frame,
    infer_order,
    inside_body,
    inside_layers,
    off_rim,
    outfit_settings,
)
from pbc.inference.poses import posed_bodies, read_poses
from pbc.inference.predictor import ClothPredictor

MEND = mend_settings(push_out=True)
SETTINGS = outfit_settings()


def tube(radius: float, z0: float, z1: float, n: int = 48, m: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """An open cylinder about the z axis from z0 to z1: (vertices (n*m, 3), faces wound outward)."""
    t, z = np.meshgrid(np.linspace(0, 2 * np.pi, n, endpoint=False), np.linspace(z0, z1, m), indexing="ij")
    x = np.stack([radius * np.cos(t.ravel()), radius * np.sin(t.ravel()), z.ravel()], 1)
    k = np.arange(n * m).reshape(n, m)
    a, b = k[:, :-1].ravel(), np.roll(k, -1, 0)[:, :-1].ravel()
    c, d = np.roll(k, -1, 0)[:, 1:].ravel(), k[:, 1:].ravel()
    return x, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def body() -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder (radius 8 cm) the tubes sit on."""
    mesh = trimesh.creation.cylinder(radius=0.08, height=0.6, sections=64)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def layer(name: str, x: np.ndarray, faces: np.ndarray) -> LayerMesh:
    return LayerMesh.of(name, faces, len(x))


def test_the_settings_mirror_conf_and_are_held_to_their_bounds(tmp_path):
    assert outfit_settings() == OutfitSettings()
    node = OmegaConf.load(SETTINGS_FILE)
    node.rounds = 0
    with pytest.raises(ValueError, match=r"outfit.yaml: rounds=0 .*expected an integer in \[1, 100\]"):
        check_settings_file("outfit", node, tmp_path / "outfit.yaml")
    with pytest.raises(ValueError, match="body='skin': one of none, parts, whole"):
        outfit_settings(body="skin")


def test_the_tubes_are_wound_outward():
    x, f = tube(0.1, 0.0, 0.2)
    assert (surface_distance(x * np.array([1.1, 1.1, 1.0]), x, f)[0] > 0).all()


def test_the_outer_layer_is_pushed_out_of_the_inner_and_none_of_it_stays_inside():
    inner, fi = tube(0.10, -0.15, 0.15)
    outer, fo = tube(0.11, -0.05, 0.25)
    t = np.arctan2(outer[:, 1], outer[:, 0])
    dip = (np.abs(t) < 0.6) & (np.abs(outer[:, 2] - 0.05) < 0.05)  # a patch 5 mm inside the inner tube
    outer[dip, :2] *= 0.095 / 0.11
    layers = [layer("inner", inner, fi), layer("outer", outer, fo)]
    bv, bf = body()
    before = inside_layers(outer, [(inner, layers[0])], MEND, SETTINGS)
    assert before.sum() == dip.sum()
    (yi, yo), stats = compose_frame([inner, outer], layers, bv, bf, None, MEND, SETTINGS)
    assert np.array_equal(yi, inner)  # the innermost has nothing under it (settings.body none)
    assert not inside_layers(yo, [(yi, layers[0])], MEND, SETTINGS).any()
    assert stats[1]["inside_under_before"] == dip.sum() and stats[1]["inside_under_after"] == 0
    far = np.abs(outer[:, 2] - 0.05) > 0.15
    # the dip moved out by its depth and the margin; the tube far from it follows by far less
    assert np.linalg.norm(yo[dip] - outer[dip], axis=1).min() > 0.5 * (0.005 + MEND.margin)
    assert np.linalg.norm(yo[far] - outer[far], axis=1).max() < 0.3 * (0.005 + MEND.margin)
    assert stats[0]["inside_body_after"] == stats[0]["inside_body_before"] == 0


def test_a_point_beyond_a_layers_rim_is_not_inside_it():
    inner, fi = tube(0.10, -0.15, 0.15)
    m = layer("inner", inner, fi)
    pts = np.array([[0.098, 0.0, 0.0], [0.098, 0.0, 0.16]])  # under the tube; above its top rim
    assert off_rim(pts, inner, m, MEND.candidates, SETTINGS.rim_tolerance).tolist() == [True, False]
    assert inside_layers(pts, [(inner, m)], MEND, SETTINGS).tolist() == [True, False]


def test_the_order_is_inferred_the_piece_farther_from_the_body_outer():
    inner, fi = tube(0.10, -0.15, 0.15)
    outer, fo = tube(0.115, -0.05, 0.25)
    bv, bf = body()
    order, pairs = infer_order([(outer, layer("shirt", outer, fo)), (inner, layer("trousers", inner, fi))],
                               bv, bf, MEND, SETTINGS)
    assert order == [1, 0] and pairs[0]["outer"] == "shirt"


def fake(vertices, faces):
    """A stand-in for a ClothPredictor: only its body is looked at before the refusal."""
    return SimpleNamespace(dataset=SimpleNamespace(body=SimpleNamespace(vertices=vertices, faces=faces)))


def test_bad_orders_and_bodies_are_refused_in_one_line():
    with pytest.raises(ValueError, match="no piece 'shirt' in the outfit; name its pieces"):
        check_order(["trousers", "shirt"], ["tshirt", "trousers"])
    with pytest.raises(ValueError, match="tshirt named twice"):
        check_order(["tshirt", "tshirt"], ["tshirt", "trousers"])
    with pytest.raises(ValueError, match="leaves out trousers"):
        check_order(["tshirt"], ["tshirt", "trousers"])
    bv, bf = body()
    with pytest.raises(ValueError, match="tshirt and trousers are on different bodies .*mm apart"):
        OutfitPredictor({"tshirt": fake(bv, bf), "trousers": fake(bv * 1.1, bf)})
    with pytest.raises(ValueError, match="an outfit needs two pieces or more"):
        OutfitPredictor({"tshirt": fake(bv, bf)})


@pytest.mark.parametrize("argv, line", [
    (["--pretrained", "tshirt"], "an outfit needs two pieces or more"),
    (["--pretrained", "tshirt", "trousers", "--order", "trousers,shirt"], "no piece 'shirt'"),
    (["--pretrained", "tshirt", "trousers", "--order", "tshirt,tshirt"], "tshirt named twice"),
    (["--pretrained", "tshirt", "tshirt"], "tshirt given twice"),
])
def test_the_command_refuses_bad_input_before_writing(tmp_path, argv, line):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=line):
        cli.run(["predict", *argv, "--poses", "test", "--out", str(out)])
    assert not out.exists()


def test_the_command_refuses_models_on_different_bodies_before_writing(tmp_path, monkeypatch):
    real = ClothPredictor.from_pretrained

    def load(name, **kw):
        p = real(name, **kw)
        if name != "trousers":
            return p
        other = copy.copy(p)
        other.dataset = fake(p.dataset.body.vertices * 1.05, p.dataset.body.faces).dataset
        return other

    monkeypatch.setattr(cli.ClothPredictor, "from_pretrained", staticmethod(load))
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="tshirt and trousers are on different bodies"):
        cli.run(["predict", "--pretrained", "tshirt", "trousers", "--poses", "test", "--out", str(out)])
    assert not out.exists()


def test_pbc_outfit_predict_writes_what_its_files_say(tmp_path, capsys):
    out = tmp_path / "outfit"
    assert cli.run(["predict", "--pretrained", "tshirt", "trousers", "--poses", "test", "--max", "4",
                    "--sheet", "4", "--video", "gif", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "order (inferred), innermost first: trousers, tshirt"
    assert lines[1].startswith("layer 1 trousers") and lines[2].startswith("layer 2 tshirt (over trousers)")
    report = json.loads((out / "outfit.json").read_text())
    assert report["order"] == ["trousers", "tshirt"] and report["num_frames"] == 8
    for name in ("motion.gif", "garment_tshirt.glb", "garment_trousers.glb", "contact_sheet.png"):
        assert (out / name).stat().st_size > 0
    preds = {n: ClothPredictor.from_pretrained(n) for n in report["order"]}
    meshes = {n: LayerMesh.of(n, p.dataset.garment.faces, len(p.dataset.garment.vertices))
              for n, p in preds.items()}
    poses = torch.from_numpy(np.load(out / "poses.npy"))
    bodies = posed_bodies(preds["tshirt"].dataset, poses).numpy().astype(np.float64)
    bf = np.asarray(preds["tshirt"].dataset.body.faces)
    got = {n: {"before": np.load(out / f"predicted_{n}.npy").astype(np.float64),
               "after": np.load(out / f"vertices_{n}.npy").astype(np.float64)} for n in report["order"]}
    for i, layer_report in enumerate(report["layers"]):
        name = layer_report["piece"]
        for when in ("before", "after"):
            under = [n for n in report["order"][:i]]
            counts = [int(inside_layers(got[name][when][k], [(got[u][when][k], meshes[u]) for u in under], MEND,
                                        SETTINGS).sum()) for k in range(8)]
            body_counts = [int(inside_body(got[name][when][k], bodies[k], bf, MEND.candidates).sum())
                           for k in range(8)]
            assert counts == report["per_frame"][name][f"inside_under_{when}"], (name, when)
            assert body_counts == report["per_frame"][name][f"inside_body_{when}"], (name, when)
            pct = 100.0 * sum(counts) / (8 * meshes[name].num_vertices)
            assert layer_report[f"inside_under_{when}_pct"] == pytest.approx(pct, abs=1e-4)
    shirt = report["layers"][1]
    assert shirt["inside_under_before_pct"] > 1.0 and shirt["inside_under_after_pct"] == 0.0
    for name, err in report["vertex_error"].items():
        rows = [k for k, n in enumerate(report["names"]) if n.startswith(f"{name}_")]
        truth = read_poses("test", preds[name].dataset).first(4).truth.numpy()
        for key, when in (("alone_cm", "before"), ("composed_cm", "after")):
            e = np.linalg.norm(got[name][when][rows] - truth, axis=-1).mean() * 100.0
            assert err[key] == pytest.approx(e, abs=1e-3)
