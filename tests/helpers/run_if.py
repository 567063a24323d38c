"""RunIf-style skips (as in lightning-hydra-template): `@run_if(cuda=True)` marks a test `gpu` and skips it,
naming why, where the machine cannot run it."""

from __future__ import annotations

import pytest
import torch


def run_if(cuda: bool = False, min_cuda_memory_gb: float = 0.0):
    """A decorator: the test's marks plus a skip when a requirement is not met."""
    reasons = []
    marks = []
    if cuda:
        marks.append(pytest.mark.gpu)
        if not torch.cuda.is_available():
            reasons.append("no CUDA device")
        elif min_cuda_memory_gb and torch.cuda.get_device_properties(0).total_memory < min_cuda_memory_gb * 2**30:
            reasons.append(f"less than {min_cuda_memory_gb} GiB of GPU memory")

    def wrap(fn):
        for m in marks:
            fn = m(fn)
        return pytest.mark.skipif(bool(reasons), reason="; ".join(reasons) or "runs here")(fn)

    return wrap
