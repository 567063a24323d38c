"""Helpers shared by tests/unit/test_predict_device.py and tests/gpu/test_predict_device_gpu.py."""

from __future__ import annotations

import torch

from pbc.models.decoder import ConvDecoder


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
