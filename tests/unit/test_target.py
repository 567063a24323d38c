"""The cloth target on a synthetic two-chart garment (no dataset, no body): one factory for the three kinds,
one render path, predictions back to 3D, the served size and the checkpoint identity."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers.synthetic import FakeSkinner, batch_for, two_chart_garment

from pbc.pixels.target import PatchTarget, VertexTarget, WholeTarget, image_operators, make_target

IMAGE = {"whole_resolution": 32, "patch_resolution": 64, "reference_resolution": 512, "crop_size": 256,
         "margin": 16, "pad": 16, "exact_sample": True, "method": "sparse"}


@pytest.fixture
def world(tmp_path):
    g = two_chart_garment(8)
    # the front sheet's 3 x 3 corner vertices (uv 0.1 .. 0.33) as patch 0, its box in 512 px
    patch = SimpleNamespace(id=0, side=0, box_512=(51, 51, 170, 170),
                            vertices=np.array([8 * i + j for i in range(3) for j in range(3)]))
    ds = SimpleNamespace(garment=g, cage=SimpleNamespace(patches=[patch]), dir=tmp_path,
                         manifest={"garment_hash": "h"}, verts=np.zeros((1, len(g.vertices), 3), np.float32))
    return ds, FakeSkinner(g.vertices)


def test_one_factory_serves_each_kind(world):
    ds, sk = world
    whole = make_target(ds, IMAGE, "whole", space="root", skinner=sk)
    patch = make_target(ds, IMAGE, "patch", patch_id=0, skinner=sk)
    fc = make_target(ds, IMAGE, "fc", skinner=sk)
    assert (type(whole), type(patch), type(fc)) == (WholeTarget, PatchTarget, VertexTarget)
    assert whole.image_size == (32, 32) and patch.image_size == (32, 32) and fc.image_size is None
    assert fc.num_vertices == whole.num_vertices == 128
    assert whole.identity(ds) == {"garment_hash": "h", "num_vertices": 128, "kind": "whole", "resolution": 32,
                                  "patch_id": None, "space": "root", "crop_size": None}
    assert patch.identity(ds)["resolution"] == 64 and patch.identity(ds)["crop_size"] == 32
    assert fc.identity(ds)["resolution"] is None
    # operators come from the one cache, with the configured method
    assert whole.ops.method == "sparse" and list((ds.dir / "operators").iterdir())
    with pytest.raises(ValueError, match="model.kind must be one of"):
        make_target(ds, IMAGE, "vertices", skinner=sk)
    with pytest.raises(ValueError, match="unknown patch_id 3"):
        make_target(ds, IMAGE, "patch", patch_id=3, skinner=sk)


def test_render_then_positions_round_trips(world):
    ds, sk = world
    batch = batch_for(ds.garment, b=3)
    for t in (make_target(ds, IMAGE, k, patch_id=0, skinner=sk) for k in ("whole", "patch", "fc")):
        out = t.render(batch)
        truth, mask = t.truth(out)
        pred = truth.clone()
        # exact operators: the ground-truth target maps back to the draped vertices
        assert torch.allclose(t.positions(pred, out), batch["verts"], atol=1e-5), t.kind
        assert (mask is None) == (t.kind == "fc")
        assert t.ensure(out) is out  # rendered once: never twice
    patch = make_target(ds, IMAGE, "patch", patch_id=0, skinner=sk)
    out = patch.render(batch)
    moved = patch.positions(out["image"] + 0.01 * out["mask"], out)
    inside = torch.zeros(128, dtype=torch.bool)
    inside[patch.vertices] = True
    # a patch prediction moves only the patch's vertices; the rest stays ground truth
    assert torch.equal(moved[:, ~inside], batch["verts"][:, ~inside])
    assert (moved[:, inside] - batch["verts"][:, inside]).abs().max() > 1e-3


def test_image_operators_refuse_unknown_images(world):
    with pytest.raises(ValueError, match="'whole' or 'patch'"):
        image_operators(world[0], IMAGE, "crop")
