"""Inference on any device: the stacked patch net keeps every tensor in parameters/buffers, so `.to()`
moves all of it (checked on the CPU with the meta device), and picks its layout per device; on a CUDA
machine (marker `gpu`) it matches the CPU loop of decoders."""

from __future__ import annotations

import pytest
import torch
from helpers.predict_device import decoders, every_tensor

from pbc.inference.predictor import (
    DEFAULT_LAYER_MODES,
    GPU_LAYER_MODES,
    LoopPatchNet,
    StackedPatchNet,
    default_layer_modes,
)


@pytest.mark.parametrize("modes", [None, ("bmm",) * 3, ("grouped",) * 3])
def test_to_moves_every_tensor(modes):
    net = StackedPatchNet(decoders(), modes).eval()
    names = [n for n, _ in every_tensor(net)]
    assert any("bmm" in n for n in names) == (modes != ("grouped",) * 3)  # the bmm copies are counted
    net.to("meta")
    stayed = [n for n, t in every_tensor(net) if t.device.type != "meta"]
    assert not stayed, f"left behind by .to(): {stayed}"
    net.to(torch.float64)
    assert {t.dtype for _, t in every_tensor(net) if t.is_floating_point()} == {torch.float64}


def test_layout_is_chosen_per_device():
    assert default_layer_modes("cpu") == DEFAULT_LAYER_MODES and default_layer_modes("cuda:0") == GPU_LAYER_MODES
    net = StackedPatchNet(decoders())
    assert net.layer_modes("cpu") == DEFAULT_LAYER_MODES[:3] and net.layer_modes("cuda") == GPU_LAYER_MODES[:3]
    fixed = StackedPatchNet(decoders(), ("grouped",))
    assert fixed.layer_modes("cpu") == ("grouped",) * 3
    with pytest.raises(ValueError, match="'bmm' or 'grouped'"):
        StackedPatchNet(decoders(), ("fold",))
    # every layout gives the loop's answer on the CPU
    pose = torch.randn(2, 90)
    ref = LoopPatchNet(decoders()).eval()(pose)
    with torch.inference_mode():
        for modes in (None, ("bmm",), ("grouped",), ("bmm", "grouped")):
            assert torch.allclose(StackedPatchNet(decoders(), modes).eval()(pose), ref, atol=1e-5), modes


