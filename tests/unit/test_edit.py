"""Image editing (pbc.edit): zero edits are the identity, a normal offset moves the masked vertices along
their normals by exactly that much, and nothing outside the mask moves. Coarse shirt, random frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pbc.core.runs import RunRecord, monitor
from pbc.jobs.edit import EditSpec, apply_edit, patch_mask, place_feature, png_mask, reconstruct, rect_mask

RES = 64


@pytest.fixture(scope="module")
def scene():
    from pbc.core.config import load_garment_config
    from pbc.geometry.garment.tshirt import make_tshirt
    from pbc.pixels.frames import to_offsets
    from pbc.pixels.operators import ImageOperators

    garment, cage = make_tshirt(load_garment_config("conf/garment/tshirt_coarse.yaml"))
    ops = ImageOperators.for_garment(garment, RES, pad=4)
    g = torch.Generator().manual_seed(0)
    V = garment.vertices.shape[0]
    anchors = garment.vertices[None].float() + 0.01 * torch.randn(1, V, 3, generator=g)
    frames = torch.linalg.qr(torch.randn(1, V, 3, 3, generator=g))[0].transpose(-1, -2)  # rows orthonormal
    verts = anchors + 0.02 * torch.randn(1, V, 3, generator=g)
    image = ops.render(to_offsets(verts, anchors, frames))
    return garment, cage, ops, anchors, frames, image


def _tap_weight(ops, mask):
    """Per vertex: fraction of its 4 bilinear taps inside the mask, and whether any tap touches it."""
    taps = torch.from_numpy(np.asarray(ops.arrays["S_pix"]))
    m = mask.reshape(-1)[taps]  # (V, 4)
    return m.min(1).values, m.max(1).values


def test_zero_edit_is_identity(scene):
    garment, cage, ops, anchors, frames, image = scene
    spec = EditSpec(feature=np.zeros((2, RES, RES)), feature_amplitude=0.0)
    assert spec.is_identity()
    for mask in (torch.ones(2, RES, RES), patch_mask(ops, cage.patches[5]), rect_mask(RES, 1, (0.1, 0.2, 0.6, 0.7))):
        out = apply_edit(image, mask, spec, ops.mask)
        assert torch.equal(out, image)
        assert torch.equal(reconstruct(out, ops, anchors, frames), reconstruct(image, ops, anchors, frames))


@pytest.mark.parametrize("region", ["patch", "rect"])
def test_normal_offset_moves_masked_vertices_along_normal(scene, region):
    garment, cage, ops, anchors, frames, image = scene
    patch = cage.patches[7]
    mask = patch_mask(ops, patch) if region == "patch" else rect_mask(RES, 0, (0.3, 0.3, 0.7, 0.8))
    delta = 0.013
    before = reconstruct(image, ops, anchors, frames)
    after = reconstruct(apply_edit(image, mask, EditSpec(normal=delta), ops.mask), ops, anchors, frames)
    full, touched = _tap_weight(ops, mask)
    inside = full == 1
    if region == "patch":  # every vertex of the patch reads only edited pixels
        assert inside[torch.as_tensor(patch.vertices)].all()
    assert inside.sum() >= 5
    moved = after - before
    expected = delta * frames[0, :, 2]  # the n row of each cloth pixel's frame
    # float32 sampling of a 1 cm image: well below the 1e-5 cm representation floor at these sizes
    assert torch.allclose(moved[0, inside], expected[inside], atol=1e-6)
    assert (moved[0, touched == 0].abs().max() == 0)


def test_edit_outside_mask_moves_nothing_outside(scene, tmp_path):
    garment, cage, ops, anchors, frames, image = scene
    from skimage import io

    painted = np.zeros((32, 32), np.uint8)
    painted[5:20, 8:25] = 255
    io.imsave(tmp_path / "mask.png", painted, check_contrast=False)
    mask = png_mask(tmp_path / "mask.png", RES, side=1)
    folds = 0.5 + 0.5 * np.sin(np.linspace(0, 6 * np.pi, 40))[None, :].repeat(30, 0)
    feature = place_feature(folds, RES, 1, (0.0, 0.0, 1.0, 1.0))
    spec = EditSpec(shift_u=0.02, shift_v=-0.01, normal=0.005, normal_gain=0.3, feature=feature,
                    feature_amplitude=0.01)
    before = reconstruct(image, ops, anchors, frames)
    after = reconstruct(apply_edit(image, mask, spec, ops.mask), ops, anchors, frames)
    full, touched = _tap_weight(ops, mask)
    outside = touched == 0
    assert outside.sum() > 100 and (full == 1).sum() > 5
    assert torch.equal(after[0, outside], before[0, outside])
    assert (after[0, full == 1] - before[0, full == 1]).norm(dim=-1).min() > 1e-3
    assert mask[0].sum() == 0  # a one-chart PNG edits that chart only


def test_bad_region_is_one_clear_error(scene):
    garment, cage, ops, anchors, frames, image = scene
    with pytest.raises(ValueError, match="u0 < u1"):
        rect_mask(RES, 0, (0.5, 0.2, 0.4, 0.6))
    with pytest.raises(ValueError, match=r"\(2, H, W\)"):
        apply_edit(image, torch.ones(2, 8, 8), EditSpec(normal=0.01))


def _whole_run(run, res: int = 64):
    """A run dir as pbc.train leaves it (metrics.json + checkpoint of a ClothModule's `net.*`), written
    without Lightning: a narrow untrained decoder whose mean image is random."""
    from pbc.models.decoder import ConvDecoder

    net_cfg = {"_target_": "pbc.models.decoder.ConvDecoder", "in_features": 90, "out_channels": 6,
               "output_size": [res, res], "start_size": [8, 8], "start_channels": 16,
               "first_layer": "conv_transpose"}
    net = ConvDecoder(**{k: v for k, v in net_cfg.items() if k != "_target_"})
    net.output_mean.copy_(0.01 * torch.randn_like(net.output_mean))
    identity = {"garment_hash": "fake", "kind": "whole", "patch_id": None, "space": "local", "resolution": res}
    image = {"whole_resolution": res, "patch_resolution": res, "reference_resolution": res, "pad": 4,
             "crop_size": 16, "margin": 2}  # the run's image config, as pbc.train records it
    ck = run / "checkpoints" / "epoch_000.ckpt"
    ck.parent.mkdir(parents=True)
    torch.save({"hyper_parameters": {"net": net_cfg, "space": "local", "identity": identity},
                "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ck)
    RunRecord(kind="whole", optimized_metric=monitor("whole"), best_checkpoint=str(ck), identity=identity,
              config={"image": image}).write(run)
    return run


def test_prediction_source_edits_a_models_image(tmp_path):
    """--run: the image is a whole-shirt model's output for the sample's pose, masked to the charts."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from helpers.evaluate_world import IMAGE, fake_dataset

    from pbc.jobs.edit import source_from_dataset

    ds = fake_dataset(tmp_path / "ds")
    run = _whole_run(tmp_path / "whole")
    src = source_from_dataset(ds, 3, IMAGE, run=str(run))  # the run's own image config (RES) wins
    assert src.image.shape == (1, 6, RES, RES) and src.ops.res == RES
    assert (src.image * (1 - src.ops.image_mask())).abs().max() == 0
    assert src.image.abs().max() > 0
    after = reconstruct(apply_edit(src.image, torch.ones(2, RES, RES), EditSpec(normal=0.01), src.ops.mask),
                        src.ops, src.anchors, src.frames)
    before = reconstruct(src.image, src.ops, src.anchors, src.frames)
    torch.testing.assert_close(after - before, 0.01 * src.frames[:, :, 2], atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="out of range"):
        source_from_dataset(ds, 99, IMAGE)
