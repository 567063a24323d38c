"""Losses and metrics on hand-made tensors (values checked by hand)."""

import pytest
import torch

from pbc.models.losses import edge_loss, image_loss, normal_loss, vertex_value_loss
from pbc.models.metrics import normal_cosine_distance, vertex_error_cm


def test_image_loss_masked_mean_per_piece_summed():
    gt = torch.zeros(1, 6, 2, 2)
    pred = torch.zeros(1, 6, 2, 2)
    pred[0, 0, 0, 0] = 2.0  # front piece, masked-in pixel: |err| 2
    pred[0, 1, 1, 1] = 5.0  # front piece, masked-out pixel: ignored
    pred[0, 3:6, 0, 1] = -1.0  # back piece, three channels at one pixel: per-pixel L1 = 3
    mask = torch.zeros(2, 2, 2, dtype=torch.bool)
    mask[0, 0, :] = True  # front: 2 pixels
    mask[1] = True  # back: 4 pixels
    # front: 2 / 2 = 1;  back: 3 / 4 = 0.75
    assert image_loss(pred, gt, mask, "l1").item() == pytest.approx(1.75)
    # L2: front 4 / 2 = 2; back 3 / 4
    assert image_loss(pred, gt, mask, "l2").item() == pytest.approx(2.75)


def test_image_loss_batch_mask_and_errors():
    pred, gt = torch.ones(2, 3, 4, 4), torch.zeros(2, 3, 4, 4)
    mask = torch.zeros(2, 1, 4, 4)
    mask[0, 0, 0, 0] = 1
    mask[1, 0, :2] = 1
    assert image_loss(pred, gt, mask).item() == pytest.approx(3.0)
    assert image_loss(gt, gt, mask).item() == 0.0
    with pytest.raises(ValueError):
        image_loss(pred, gt, torch.ones(2, 2, 4, 4))
    with pytest.raises(ValueError):
        image_loss(pred, gt, mask, "huber")


def test_normal_loss_zero_for_identical_positive_otherwise():
    n = torch.nn.functional.normalize(torch.randn(2, 7, 3), dim=-1)
    assert normal_loss(n, n).item() == pytest.approx(0.0, abs=1e-6)
    assert normal_loss(n, -n).item() == pytest.approx(2.0, abs=1e-6)
    z = torch.tensor([[[0.0, 0.0, 1.0]]])
    x = torch.tensor([[[3.0, 0.0, 0.0]]])  # unnormalised input is normalised
    assert normal_loss(x, z).item() == pytest.approx(1.0)
    tilted = torch.nn.functional.normalize(n + 0.3 * torch.randn_like(n), dim=-1)
    assert normal_loss(tilted, n).item() > 0.0


def test_edge_and_vertex_value_losses():
    assert edge_loss(torch.tensor([[1.0, 2.0]]), torch.tensor([[1.5, 1.0]])).item() == pytest.approx(0.75)
    a, b = torch.zeros(1, 2, 3), torch.tensor([[[1.0, -1.0, 0.0], [0.0, 0.0, 2.0]]])
    assert vertex_value_loss(b, a, "l1").item() == pytest.approx(2.0)
    assert vertex_value_loss(b, a, "l2").item() == pytest.approx(3.0)


def test_metrics_cm_and_subset():
    gt = torch.zeros(1, 3, 3)
    pred = torch.tensor([[[0.03, 0.04, 0.0], [0.0, 0.0, 0.0], [0.0, 0.01, 0.0]]])  # 5 cm, 0, 1 cm
    assert vertex_error_cm(pred, gt).item() == pytest.approx(2.0)
    assert vertex_error_cm(pred, gt, torch.tensor([0, 2])).item() == pytest.approx(3.0)
    n = torch.tensor([[[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]])
    m = torch.tensor([[[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])
    assert normal_cosine_distance(m, n).item() == pytest.approx(0.5)
    assert normal_cosine_distance(m, n, torch.tensor([0])).item() == pytest.approx(0.0)


def test_losses_backpropagate():
    pred = torch.randn(2, 6, 8, 8, requires_grad=True)
    image_loss(pred, torch.zeros_like(pred), torch.ones(2, 8, 8)).backward()
    assert pred.grad is not None and pred.grad.abs().sum() > 0
