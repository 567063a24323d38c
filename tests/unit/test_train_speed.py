"""The fast training path on a synthetic two-chart garment (no dataset, no body): the target cache serves
exactly what per-batch rendering gives (float16 images within their rounding), the DataModule builds and
uses it (and falls back when it would not fit), the cheaper vertex normals equal the reference formula
(values and gradients), a patch's normals need only its neighbourhood's faces, the step's losses are the
same with cached targets, bf16-mixed keeps the 3D path in float32, and the schedule presets compose."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers.synthetic import FakeSkinner, batch_for, two_chart_garment
from helpers.train_speed_world import IMAGE, N, datamodule, module, reference_normals, targets

from pbc.data.datamodule import ClothDataModule
from pbc.geometry.meshops import vertex_normals
from pbc.pixels.target import build_cache, make_target


@pytest.fixture
def world(tmp_path):
    g = two_chart_garment(8)
    patch = SimpleNamespace(id=0, side=0, box_512=(51, 51, 170, 170),
                            vertices=np.array([8 * i + j for i in range(3) for j in range(3)]))
    b = batch_for(g, b=N, seed=1)
    ds = SimpleNamespace(garment=g, cage=SimpleNamespace(patches=[patch]), dir=tmp_path,
                         manifest={"garment_hash": "h"}, poses=b["pose"].reshape(N, -1).numpy(),
                         verts=b["verts"].numpy())
    return ds, FakeSkinner(g.vertices), b


def test_cached_batch_equals_rendered_batch(world):
    ds, sk, b = world
    for t in targets(ds, sk):
        # the cache holds samples in another order than the batch asks for them
        order = torch.tensor([3, 0, 6, 1, 5, 2, 4])
        cache = build_cache(t, b["pose"][order], b["verts"][order], b["index"][order], chunk=3)
        t.cache = cache
        want = {"pose": b["pose"][[4, 4, 0, 6]], "verts": b["verts"][[4, 4, 0, 6]], "index": torch.tensor([4, 4, 0, 6])}
        rendered, cached = t.render(want), t.fetch(want)
        assert set(cached) == set(rendered) | {"normals"}, t.kind
        for k, v in rendered.items():
            assert torch.equal(cached[k], v), (t.kind, k)
        assert torch.equal(cached["normals"], vertex_normals(want["verts"], t.faces))
        # an index the cache does not hold is rendered instead
        other = dict(want, index=torch.tensor([4, 4, 0, 9]))
        assert not cache.covers(other) and "normals" not in t.fetch(other)
        assert t.ensure(cached) is cached


def test_float16_image_cache_is_within_its_rounding(world):
    ds, sk, b = world
    t = make_target(ds, IMAGE, "whole", skinner=sk)
    exact = t.render(b)
    cache = build_cache(t, b["pose"], b["verts"], b["index"], chunk=3, image_dtype=torch.float16)
    assert cache.per_sample["image"].dtype == torch.float16 and cache.per_sample["offsets"].dtype == torch.float32
    got = cache.lookup(b)
    assert got["image"].dtype == torch.float32
    # half precision rounds to nearest: 11 significant bits (|error| <= 2^-11 |value|), and below 2^-14 the
    # subnormals' fixed spacing 2^-24 (|error| <= 2^-25)
    err = (got["image"] - exact["image"]).abs()
    assert (err <= exact["image"].abs() * 2.0**-11 + 2.0**-25).all() and err.max() > 0
    assert torch.equal(got["offsets"], exact["offsets"]) and torch.equal(got["frames"], exact["frames"])


def test_datamodule_serves_cached_targets_equal_to_rendered(world, caplog):
    ds, sk, b = world
    for t in targets(ds, sk):
        dm = datamodule(ds, t)
        batch = next(iter(dm.train_dataloader()))
        got = dm.on_after_batch_transfer(dict(batch), 0)
        assert t.cache is not None and len(t.cache) == N  # every split's samples, built on first use
        assert dm.ensure_cache("cpu") is t.cache  # built once
        want = t.render(dict(batch))
        for k, v in want.items():
            assert torch.equal(got[k], v), (t.kind, k)
        # cache off: rendered per batch, nothing attached
        t.cache = None
        off = datamodule(ds, t, cache_targets=False).on_after_batch_transfer(dict(batch), 0)
        assert t.cache is None and "normals" not in off
        for k, v in want.items():
            assert torch.equal(off[k], v), (t.kind, k)
    # too big for cache_max_gb: one warning, then batches are rendered as they come
    t = make_target(ds, IMAGE, "whole", skinner=sk)
    dm = datamodule(ds, t, cache_max_gb=1e-9)
    with caplog.at_level(logging.WARNING):
        out = dm.on_after_batch_transfer(dict(batch), 0)
        dm.on_after_batch_transfer(dict(batch), 0)
    assert t.cache is None and "image" in out
    assert sum("cache_max_gb" in r.message for r in caplog.records) == 1
    with pytest.raises(ValueError, match="cache_dtype must be one of"):
        ClothDataModule(str(ds.dir), IMAGE, cache_dtype="int8")


def test_vertex_normals_equal_reference_values_and_gradients():
    g = two_chart_garment(7)
    gen = torch.Generator().manual_seed(0)
    p = (g.vertices[None] + 0.05 * torch.randn(3, len(g.vertices), 3, generator=gen)).requires_grad_()
    w = torch.randn(3, len(g.vertices), 3, generator=gen)
    faces = g.faces.long()
    fast, ref = vertex_normals(p, faces), reference_normals(p, faces)
    torch.testing.assert_close(fast, ref, rtol=1e-5, atol=1e-6)
    (g_fast,) = torch.autograd.grad((fast * w).sum(), p)
    (g_ref,) = torch.autograd.grad((ref * w).sum(), p)
    torch.testing.assert_close(g_fast, g_ref, rtol=1e-4, atol=1e-5)


def test_patch_normals_need_only_the_patch_neighbourhood(world):
    ds, sk, b = world
    whole, patch, _ = targets(ds, sk)
    assert torch.equal(whole.normal_faces("cpu"), whole.faces)
    sub = patch.normal_faces("cpu")
    assert 0 < len(sub) < len(patch.faces)
    ids = patch.vertices
    torch.testing.assert_close(vertex_normals(b["verts"], sub)[:, ids], vertex_normals(b["verts"], patch.faces)[:, ids],
                               rtol=0, atol=1e-6)


@pytest.mark.parametrize("kind", ["whole", "patch"])
def test_step_is_the_same_with_cached_targets(world, kind):
    ds, sk, b = world
    t = {x.kind: x for x in targets(ds, sk)}[kind]
    torch.manual_seed(0)
    m = module(t).eval()
    losses = {}
    for split in ("train", "val"):
        t.cache = None
        rendered = m.step(t.render(dict(b)), split, 0)
        t.cache = build_cache(t, b["pose"], b["verts"], b["index"], chunk=4)
        cached = m.step(t.fetch(dict(b)), split, 0)
        torch.testing.assert_close(cached[0], rendered[0], rtol=1e-6, atol=1e-8)
        torch.testing.assert_close(cached[1]["positions"], rendered[1]["positions"])
        losses[split] = cached[0]
    assert torch.isfinite(losses["train"])


def test_bf16_autocast_runs_only_the_network_in_bf16(world):
    ds, sk, b = world
    t = make_target(ds, IMAGE, "whole", skinner=sk)
    torch.manual_seed(0)
    m = module(t).eval()
    batch = t.render(dict(b))
    with torch.no_grad():
        ref_loss, ref = m.step(batch, "val", 0)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            loss, out = m.step(batch, "val", 0)
    # the network did run in bf16 (its output is float32 only because the mean image is added in float32)
    assert not torch.equal(out["pred"], ref["pred"])
    assert loss.dtype == torch.float32 and out["positions"].dtype == torch.float32
    # the same positions as decoding the bf16 prediction in float32 outside autocast
    torch.testing.assert_close(out["positions"], t.positions(out["pred"], batch))
    assert (out["positions"] - ref["positions"]).abs().max() < 0.05 and torch.isfinite(loss)


