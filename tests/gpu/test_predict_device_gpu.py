"""Inference on any device: the stacked patch net keeps every tensor in parameters/buffers, so `.to()`
moves all of it (checked on the CPU with the meta device), and picks its layout per device; on a CUDA
machine (marker `gpu`) it matches the CPU loop of decoders."""

from __future__ import annotations

import torch
from helpers.run_if import run_if

from pbc.models.decoder import ConvDecoder
from pbc.predict import LoopPatchNet, StackedPatchNet


def decoders(n: int = 3) -> list[ConvDecoder]:
    torch.manual_seed(0)
    nets = [ConvDecoder(90, 3, [32, 32], [4, 4], 16, first_layer="linear") for _ in range(n)]
    for d in nets:  # non-trivial BatchNorm statistics and buffers, so folding them is exercised
        for m in d.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.normal_(std=0.1)
                m.running_var.uniform_(0.5, 2)
        d.output_mean.normal_(std=0.01)
        d.input_scale.uniform_(0.5, 2)
    return [d.eval() for d in nets]


def every_tensor(module: torch.nn.Module):
    """(name, tensor) of every tensor a module holds: parameters, buffers and plain attributes (also inside
    dicts, lists and tuples), the place a weight copied by hand would hide from `.to()`."""
    for mname, mod in module.named_modules():
        for k, v in vars(mod).items():
            vals = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list | tuple) else [(k, v)]
            for kk, t in vals:
                if torch.is_tensor(t):
                    yield f"{mname}.{k}.{kk}", t






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
