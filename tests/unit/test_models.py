"""Decoder family and fully connected baselines: paper parameter counts, shapes, PCA round trip."""

from pathlib import Path

import pytest
import torch

from pbc.models.decoder import ConvDecoder, count_parameters, group_strides
from pbc.models.fc import FCNet, fit_pca

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"


def test_whole_preset_parameter_count():
    net = ConvDecoder(90, 6, (256, 256), (8, 8), 384, first_layer="conv_transpose")
    assert count_parameters(net) == 3_785_322


def test_patch_preset_parameter_count():
    net = ConvDecoder(90, 3, (160, 160), (5, 5), 512, first_layer="linear")
    assert count_parameters(net) == 3_960_195


def test_necktie_preset_shape_and_count():
    net = ConvDecoder(36, 3, (64, 256), (8, 8), 64, first_layer="linear", hidden=[128])
    assert count_parameters(net) == 576_851  # literal appendix F reading; paper says 2.16M
    assert net(torch.randn(2, 36)).shape == (2, 3, 64, 256)


def test_presets_from_conf_match_counts():
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        # necktie: the 8 x 32 x 64 start map reading of appendix F (2.16M; conf/model/necktie.yaml)
        for name, expected in [("whole", 3_785_322), ("patch", 3_960_195), ("necktie", 2_161_667)]:
            cfg = compose("config", overrides=[f"model={name}"])
            assert count_parameters(instantiate(cfg.model.net)) == expected, name


def test_decoder_shapes_small():
    net = ConvDecoder(90, 6, (64, 64), (8, 8), 384)
    assert net(torch.randn(3, 10, 3, 3)).shape == (3, 6, 64, 64)


def test_group_strides_non_square_and_errors():
    assert group_strides((8, 8), (64, 256)) == [(2, 2)] * 3 + [(1, 2)] * 2
    with pytest.raises(ValueError):
        group_strides((5, 5), (100, 100))
    with pytest.raises(ValueError):
        ConvDecoder(90, 3, (64, 64), (8, 8), 4)  # cannot halve 4 channels three times
    with pytest.raises(ValueError):
        ConvDecoder(90, 3, (64, 64), (8, 8), 64, first_layer="mlp")


def test_fc_direct_and_pca_shapes_and_paper_size():
    net = FCNet(90, 100, mode="direct")
    assert net(torch.randn(4, 90)).shape == (4, 100, 3)
    assert count_parameters(FCNet(90, 100, mode="pca")) == 90 * 256 + 256 + 256 * 256 + 256 + 256 * 128 + 128


def test_pca_fit_reconstructs_low_rank_data_and_is_checkpointed():
    torch.manual_seed(0)
    basis = torch.randn(5, 30)
    x = torch.randn(50, 5) @ basis + 1.0
    mean, comps, scale = fit_pca(x, 8)
    assert comps.shape == (8, 30) and scale.shape == (8,)
    coef = (x - mean) @ comps.T
    assert torch.allclose(coef @ comps + mean, x, atol=1e-4)
    net = FCNet(90, 10, mode="pca", num_components=8)
    net.set_pca(mean, comps, scale)
    state = net.state_dict()
    assert {"pca_mean", "pca_components", "pca_scale", "pca_fitted"} <= set(state)
    other = FCNet(90, 10, mode="pca", num_components=8)
    other.load_state_dict(state)
    assert torch.equal(other.pca_components, comps) and bool(other.pca_fitted)
