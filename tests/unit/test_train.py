"""Training wiring: one optimisation step lowers the loss, NaN guard, checkpoint refusal, every config
composes, and (when the data pipeline is importable) `python -m pbc.train` end to end with resume.

The unit tests run on a synthetic two-chart garment (no dataset): a fake skinner puts every cloth pixel
at its rest position with identity frames, so targets are just the stored vertices.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.synthetic import batch_for
from helpers.train_runs import whole_module

ROOT = Path(__file__).resolve().parents[2]


def test_one_optimisation_step_lowers_the_loss():
    torch.manual_seed(0)
    m, g = whole_module()
    batch = batch_for(g)
    opt = m.configure_optimizers()
    m.train()
    losses = []
    for _ in range(3):
        loss, _ = m.step(batch, "train", 0)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    m.eval()  # BatchNorm in eval mode: compare on the same footing as training-mode loss is noisy
    with torch.no_grad():
        after, _ = m.step(batch, "val", 0)
    assert losses[1] < losses[0] and np.isfinite(after.item())


def test_nan_loss_names_step_and_batch():
    m, g = whole_module()
    batch = batch_for(g)
    batch["verts"][0, 0, 0] = float("nan")
    with pytest.raises(FloatingPointError, match=r"global step 0.*batch 3.*sample ids"):
        m.step(batch, "train", 3)


def test_checkpoint_of_other_patch_is_refused():
    m, _ = whole_module()
    other = dict(m.hparams.identity, resolution=64, patch_id=5)
    with pytest.raises(ValueError, match=r"resolution: checkpoint 64 vs this run 32"):
        m.on_load_checkpoint({"hyper_parameters": {"identity": other}})
    m.on_load_checkpoint({"hyper_parameters": {"identity": dict(m.hparams.identity)}})


# ------------------------------------------------------------------------------------ end to end
# crop_size / margin / pad are given at the reference resolution and scale with it: 40 px crops at 128
# data.num_samples as the session's dataset was made: pbc.train refuses data made with other settings


@pytest.fixture(scope="module")
def e2e_root(tmp_path_factory):
    """A run root of its own; the data is the session's real tiny dataset."""
    return tmp_path_factory.mktemp("train_e2e")


def test_module_optimiser_and_scheduler_come_from_the_config():
    from hydra.utils import instantiate

    from pbc.core.config import load_config

    cfg = load_config(["model=patch", "model.lr=0.005", "image.crop_size=80", "paths.output_dir=/tmp/x"])
    m = instantiate(cfg.model, identity={}, summary={})
    opt = m.configure_optimizers()  # the default: Adam at model.lr, no scheduler (the paper's schedule)
    assert isinstance(opt, torch.optim.Adam) and opt.param_groups[0]["lr"] == 0.005
    cfg = load_config(["model=patch", "image.crop_size=80", "paths.output_dir=/tmp/x",
                       "model.scheduler={_target_: torch.optim.lr_scheduler.StepLR, _partial_: true, step_size: 3}"])
    out = instantiate(cfg.model, identity={}, summary={}).configure_optimizers()
    assert isinstance(out["lr_scheduler"]["scheduler"], torch.optim.lr_scheduler.StepLR)
    assert out["lr_scheduler"]["scheduler"].step_size == 3
