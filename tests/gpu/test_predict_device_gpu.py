"""Inference on any device: the stacked patch net keeps every tensor in parameters/buffers, so `.to()`
moves all of it (checked on the CPU with the meta device), and picks its layout per device; on a CUDA
machine (marker `gpu`) it matches the CPU loop of decoders."""

from __future__ import annotations

import torch
from helpers.predict_device import decoders, every_tensor
from helpers.run_if import run_if

from pbc.inference.predictor import LoopPatchNet, StackedPatchNet


@run_if(cuda=True)
def test_stacked_net_runs_on_the_gpu():
    pose = torch.randn(4, 90)
    ref = LoopPatchNet(decoders()).eval()(pose)
    with torch.inference_mode():
        for modes in (None, ("bmm",), ("grouped",)):
            net = StackedPatchNet(decoders(), modes).eval().to("cuda")
            assert all(t.is_cuda for _, t in every_tensor(net))
            out = net(pose.cuda())
            assert out.is_cuda and torch.allclose(out.cpu(), ref, atol=1e-4), modes
        bf16 = StackedPatchNet(decoders(), dtype=torch.bfloat16).eval().to("cuda")
        assert (bf16(pose.cuda()).float().cpu() - ref).abs().max() < 0.05
