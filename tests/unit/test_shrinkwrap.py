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
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.shrinkwrap import embed_points, embedded_points, garment_regions, vertex_parts, wrap_positions

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
