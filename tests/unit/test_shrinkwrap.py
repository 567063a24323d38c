"""Shrink-wrap of the coarse T-shirt onto a coarse rest body, and the barycentric embedding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.core.config import load_garment_config
from pbc.geometry.body.base import body_sdf
from pbc.geometry.body.mannequin import build_mannequin
from pbc.geometry.garment.base import Garment
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.meshops import face_areas
from pbc.geometry.shrinkwrap import (
    embed_points,
    embedded_points,
    garment_regions,
    relax_on_surface,
    vertex_parts,
    vertex_stretch,
    wrap_positions,
)

ROOT = Path(__file__).resolve().parents[2]
COARSE_VOXEL = 0.025  # a coarse body mesh keeps the test in seconds


@pytest.fixture(scope="module")
def wrapped():
    bcfg = OmegaConf.load(ROOT / "conf" / "body" / "mannequin.yaml")
    bcfg.mesh.voxel_size = COARSE_VOXEL
    body = build_mannequin(bcfg)
    conf = ROOT / "conf"
    cfg = load_garment_config(conf / "garment" / "tshirt_coarse.yaml", conf / "image" / "default.yaml")
    garment, cage = make_tshirt(cfg)
    x, stats = wrap_positions(garment, cage, body, cfg)
    region = garment_regions(garment.faces.numpy(), cage, x, body, cfg.shrinkwrap.min_encircled_deg,
                             cfg.shrinkwrap.region_smoothing)
    emb = embed_points(x, body, vertex_parts(region), int(cfg.shrinkwrap.nearest_triangles))
    return body, garment, cage, x, stats, emb


def test_embedding_reproduces_the_wrap(wrapped):
    body, garment, _, x, _, emb = wrapped
    assert emb.face.shape == (garment.num_vertices,) and emb.bary.shape == (garment.num_vertices, 3)
    assert torch.allclose(emb.bary.sum(1), torch.ones(garment.num_vertices), atol=1e-6)
    assert (emb.bary >= 0).all()
    rest = embedded_points(body.vertices[None], body.faces, emb)[0]
    assert (rest - torch.tensor(x, dtype=torch.float32)).norm(dim=1).max() < 1e-5


def test_embedded_points_is_batched_and_differentiable(wrapped):
    body, garment, _, _, _, emb = wrapped
    bv = body.vertices[None].repeat(2, 1, 1).requires_grad_(True)
    out = embedded_points(bv, body.faces, emb)
    assert out.shape == (2, garment.num_vertices, 3)
    out.sum().backward()
    assert bv.grad is not None and torch.isfinite(bv.grad).all()


def test_wrap_lies_on_the_body(wrapped):
    body, _, _, x, stats, _ = wrapped
    rot = torch.eye(3).expand(1, body.skeleton.rest_heads.shape[0], 3, 3)
    d = body_sdf(body, rot, torch.tensor(x, dtype=torch.float32)[None])[0]
    # on the mesh, which approximates the SDF surface to a fraction of the voxel size
    assert d.abs().max() < 0.5 * COARSE_VOXEL
    assert stats["max_abs_sdf"] < 0.5 * COARSE_VOXEL


def test_relaxation_evens_out_the_distortion(wrapped):
    _, _, _, _, stats, _ = wrapped
    assert stats["area_after_std"] < 0.8 * stats["area_before_std"]
    assert stats["area_after_max"] < stats["area_before_max"]
    assert 0.3 < stats["area_after_mean"] < 1.5


def test_parts_follow_the_sleeves(wrapped):
    _, garment, cage, _, _, emb = wrapped
    names = {p.id: p.name for p in cage.patches}
    vp = cage.vertex_patch(garment.num_vertices)
    part = emb.part.numpy()
    for v in range(garment.num_vertices):
        n = names[vp[v]]
        assert part[v] == (1 if "sleeve_left" in n else 2 if "sleeve_right" in n else 0)
    # the left arm is at +x
    x = garment.vertices[:, 0].numpy()
    assert (x[part == 1] > 0).all() and (x[part == 2] < 0).all()
    assert np.isin(part, [0, 1, 2]).all()


class _Plane:
    """A flat body surface, z = 0: `relax_on_surface` projects onto it."""

    def closest_in_regions(self, points, region):
        p = np.array(points, np.float64)
        p[:, 2] = 0.0
        return p, np.zeros(len(p), np.int64)


def _squeezed_grid(squeeze: float, n: int = 8, h: float = 0.01):
    """A flat n x n grid of h-m squares in z = 0 whose pattern is the same grid with its middle row of squares
    ``squeeze`` x shorter (a sliver of UV, as a MakeHuman crotch or seam strip): (garment, vertices, faces)."""
    ys = np.arange(n) * h
    uy = np.where(np.arange(n) >= n // 2, ys - (h - h / squeeze), ys)
    x, y = np.meshgrid(np.arange(n) * h, ys)
    _, v = np.meshgrid(np.arange(n) * h, uy)
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    uv = torch.tensor(np.stack([x.ravel(), v.ravel()], 1), dtype=torch.float32)
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    f = torch.tensor(faces)
    garment = Garment(torch.tensor(vertices, dtype=torch.float32), f, uv, f, torch.zeros(len(faces), dtype=torch.long),
                      uv, torch.zeros(n * n, dtype=torch.long), 1.0)
    return garment, vertices, faces


def test_vertex_stretch_weighs_each_edge_by_its_rest_length():
    edges = np.array([[0, 1], [0, 2], [0, 3]])
    rest = np.array([0.001, 0.01, 0.01])
    length = np.array([0.02, 0.01, 0.01])  # the short edge 20x its rest, the others at theirs
    alpha = vertex_stretch(edges, length, rest, 5)
    assert alpha[0] == pytest.approx(0.04 / 0.021)  # total length over total rest, not the ratios' mean (7.7)
    assert alpha[1] == pytest.approx(20.0) and alpha[2] == alpha[3] == pytest.approx(1.0)
    assert alpha[4] == 1.0  # no edge


def test_relaxation_is_stable_on_a_pattern_with_a_squeezed_strip():
    # a strip of pattern 20x shorter than its cloth among squares at their size: the relaxation spreads its
    # stretch and the garment keeps about its size (the plain mean of the edges' ratios feeds the short edges'
    # stretch back through their neighbours' targets: the grid grows to a million times its area)
    garment, x0, faces = _squeezed_grid(20.0)
    pattern = garment.pattern().double().numpy().reshape(-1, 2)
    pattern_area = face_areas(pattern, np.arange(len(pattern)).reshape(-1, 3)).sum()
    given = face_areas(x0, faces).sum() / pattern_area
    x, _ = relax_on_surface(garment, x0, _Plane(), 60, 0.5, 1e-9)
    assert np.isfinite(x).all()
    assert face_areas(x, faces).sum() / pattern_area < 1.2 * given
    assert (np.ptp(x[:, :2], 0) < 1.2 * np.ptp(x0[:, :2], 0)).all()


def test_auto_relaxes_with_the_mean_and_again_rest_weighted_where_the_mean_runs_away():
    from omegaconf import OmegaConf

    from pbc.geometry.shrinkwrap import relax_as_configured

    sw = OmegaConf.create({"relax_stretch": "auto", "relax_runaway": 3.0, "relax_iterations": 60, "relax_step": 0.5,
                           "relax_tol": 1e-9})
    squeezed, x0, faces = _squeezed_grid(20.0)
    x, _, rule = relax_as_configured(squeezed, x0, _Plane(), sw)
    assert rule == "rest_weighted" and face_areas(x, faces).sum() < 1.5 * face_areas(x0, faces).sum()
    even, y0, _ = _squeezed_grid(1.0)  # a pattern at its cloth's size: the mean, as a recorded config has it
    y, _, rule = relax_as_configured(even, y0, _Plane(), sw)
    mean, _ = relax_on_surface(even, y0, _Plane(), 60, 0.5, 1e-9, None, "mean")
    assert rule == "mean" and np.array_equal(y, mean)
    recorded = OmegaConf.create({k: v for k, v in sw.items() if k != "relax_stretch"})
    assert relax_as_configured(squeezed, x0, _Plane(), recorded)[2] == "mean"
