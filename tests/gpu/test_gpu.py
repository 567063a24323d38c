"""The device render equals the CPU render: the cloth target renders a batch where it lives (the GPU in
training), so its operators must give the same images and samples there. Runs where a CUDA device exists."""

from __future__ import annotations

import pytest
import torch
from helpers.run_if import run_if
from helpers.synthetic import FakeSkinner, batch_for, two_chart_garment

from pbc.pixels.operators import ImageOperators
from pbc.pixels.target import PatchTarget, WholeTarget


@run_if(cuda=True)
@pytest.mark.parametrize("method", ["sparse", "gather"])
def test_cuda_render_equals_cpu_render(method):
    g = two_chart_garment(8)
    ops = ImageOperators(ImageOperators.for_garment(g, 64, pad=3).arrays, method=method)
    # the front sheet's 3 x 3 corner vertices (uv 0.1 .. 0.33) as a patch, its box in 512 px
    patch = type("Patch", (), {"id": 0, "side": 0, "box_512": (51, 51, 170, 170),
                               "vertices": torch.tensor([8 * i + j for i in range(3) for j in range(3)])})()
    crop = ops.crop(patch, crop_size=32, margin=2)
    batch = batch_for(g, b=3)
    for target in (WholeTarget(FakeSkinner(g.vertices), g.faces, ops),
                   PatchTarget(FakeSkinner(g.vertices), g.faces, crop, ops.res)):
        cpu = target.render(batch)
        gpu = target.render({k: v.cuda() for k, v in batch.items()})
        assert gpu["image"].is_cuda
        torch.testing.assert_close(gpu["image"].cpu(), cpu["image"], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(gpu["mask"].cpu(), cpu["mask"])
        # and back: the prediction -> 3D map agrees on the device too
        torch.testing.assert_close(target.positions(gpu["image"], gpu).cpu(), target.positions(cpu["image"], cpu),
                                   rtol=1e-5, atol=1e-6)
