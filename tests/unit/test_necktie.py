"""The necktie (appendix F): garment, cage, 4-joint poses, the configs and the 2.16M decoder preset."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from pbc.core.config import load_config
from pbc.geometry.garment import garment_from_config
from pbc.geometry.garment.necktie import necktie_pattern
from pbc.geometry.meshops import boundary_loops, face_charts, signed_uv_area
from pbc.models.decoder import count_parameters


@pytest.fixture(scope="module")
def cfg():
    return load_config(["+experiment=necktie", "garment.grid_spacing=0.015"])


@pytest.fixture(scope="module")
def tie(cfg):
    return garment_from_config(cfg.garment)


def test_necktie_is_one_chart_with_knot_blade_and_band(cfg, tie):
    g, cage = tie
    gc = cfg.garment
    assert (face_charts(g) == 0).all() and (g.face_side == 0).all() and (g.vertex_side == 0).all()
    assert (signed_uv_area(g.uv[g.face_uv].double().numpy()) < 0).all()  # the shirt's orientation
    v0, v1 = gc.uv_window
    assert g.uv[:, 1].min() >= v0 and g.uv[:, 1].max() <= v1  # inside the 64 x 256 window of the image
    # the flat piece is as long as band + knot + blade + tip, at uv_padding from both ends
    length = 0.5 * gc.neck_girth + gc.knot_length + gc.blade_length + gc.tip_length
    assert float(np.ptp(g.uv[:, 0].numpy())) * g.uv_scale == pytest.approx(length, abs=gc.grid_spacing)
    assert g.uv[:, 0].min() == pytest.approx(gc.uv_padding, abs=1e-6)
    # the band ends are sewn behind the neck: an outline plus the hole the neck goes through
    loops = boundary_loops(g.faces.numpy())
    assert len(loops) == 2
    corners_per_vertex = np.bincount(g.faces.numpy().ravel(), minlength=g.num_vertices)
    assert corners_per_vertex.min() >= 1
    uvs = {}
    for v, t in zip(g.faces.numpy().ravel(), g.face_uv.numpy().ravel(), strict=True):
        uvs.setdefault(int(v), set()).add(int(t))
    band_cells = necktie_pattern(gc)[1]["band_cells"]
    assert band_cells >= 1
    assert sum(len(t) == 2 for t in uvs.values()) == band_cells + 1  # the seam's vertices, two uvs each
    # knot at the collar, blade hanging down the front
    y = g.vertices[:, 1].numpy()
    assert y.max() == pytest.approx(gc.collar_height + (band_cells + gc.band_gap_cells) * gc.grid_spacing, abs=1e-6)
    assert y.min() < gc.collar_height - gc.knot_length - gc.blade_length
    assert all(p.side == 0 and p.name.startswith("necktie_") for p in cage.patches)
    # faces turn like the outward normal (away from the body), as the shirt's: the blade's face forward
    tri = g.vertices[g.faces].double()
    normal = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    blade = tri[:, :, 1].mean(1) < gc.collar_height - gc.knot_length
    assert (normal[blade, 2] > 0).all()


def test_necktie_poses_vary_only_the_four_centre_line_joints(cfg, body):
    from pbc.sim.poses import sample_poses, sampling_settings_from_config

    assert list(cfg.data.pose_joints) == ["lower_back", "spine", "neck", "neck1"]
    settings = sampling_settings_from_config(cfg.body.sampling)
    poses, _ = sample_poses(body.skeleton, 16, 0, body, settings)
    moved = [not torch.allclose(poses[:, j], torch.eye(3)) for j in range(poses.shape[1])]
    assert [n for n, m in zip(body.skeleton.names, moved, strict=True) if m] == list(cfg.data.pose_joints)
    ids = [body.skeleton.names.index(n) for n in cfg.data.pose_joints]
    assert poses[:, ids].reshape(16, -1).shape[1] == cfg.model.net.in_features == 36
    # the same seed without the joint set: the posed joints get the same angles (one random stream)
    full, _ = sample_poses(body.skeleton, 16, 0, None, sampling_settings_from_config(
        {**cfg.body.sampling, "posed_joints": []}))
    assert not torch.equal(full, poses)


def test_necktie_experiment_config_and_decoder(cfg):
    assert cfg.model.space == "root" and list(cfg.model.net.output_size) == [64, 256]
    assert cfg.model.net.out_channels == 3
    assert (cfg.loss.norm, cfg.loss.normal_weight, cfg.loss.edge_weight) == ("l1", 0.1, 0.1)
    assert cfg.data.name == "necktie_small" and cfg.garment.name == "necktie"
    assert load_config(["data=necktie_paper"]).data.num_samples == 9999
    net = instantiate(cfg.model.net)
    n = count_parameters(net)
    assert n == 2_161_667 and abs(n / 2.16e6 - 1) < 0.01  # appendix F: "2.16 million parameters"
    assert net(torch.randn(2, 36)).shape == (2, 3, 64, 256)


def test_necktie_shrink_wraps_onto_the_mannequin(cfg, tie, body):
    from pbc.geometry.shrinkwrap import shrinkwrap

    g, cage = tie
    emb, stats = shrinkwrap(g, cage, body, cfg.garment.shrinkwrap)
    assert emb.face.shape == (g.num_vertices,) and (emb.part == 0).all()  # the torso carries the whole tie
    assert stats["max_abs_sdf"] < 0.01
    assert stats["area_after_min"] > 0.2 and stats["area_after_max"] < 5.0


def test_necktie_obj_round_trip_keeps_the_sampled_uvs(tie, tmp_path):
    from pbc.geometry.cage.base import validate_cage
    from pbc.geometry.garment.base import load_garment_obj, save_garment_obj

    g, cage = tie
    save_garment_obj(g, tmp_path / "tie.obj")
    h = load_garment_obj(tmp_path / "tie.obj")
    assert torch.equal(h.vertex_uv, g.vertex_uv) and torch.equal(h.faces, g.faces)
    validate_cage(cage, h, 512, 160, 16)


def test_an_unknown_posed_joint_is_refused(body):
    from pbc.sim.poses import SamplingSettings, sample_poses

    with pytest.raises(ValueError, match=r"posed_joints: unknown joints \['neck2'\]"):
        sample_poses(body.skeleton, 2, 0, None, SamplingSettings(posed_joints=("neck", "neck2")))


# ------------------------------------------------------------------------------------- training the tie
@pytest.fixture(scope="module")
def tie_ops(tie, tmp_path_factory):
    from pbc.pixels.operators import ImageOperators

    return ImageOperators.for_garment(tie[0], 256, 4, exact=True, cache_dir=tmp_path_factory.mktemp("ops"))


def test_the_tie_image_is_the_window_its_chart_fills_and_goes_back_exactly(cfg, tie, tie_ops):
    from pbc.pixels.operators import image_sizes
    from pbc.pixels.target import WindowTarget

    g = tie[0]
    sizes = image_sizes(cfg.image)
    assert sizes["whole_sides"] == (0,) and sizes["whole_rows"] == (96, 160)  # appendix F: 64 x 256
    target = WindowTarget(None, g.faces, tie_ops, sizes["whole_sides"], sizes["whole_rows"], "root")
    assert target.image_size == (64, 256) and target.channels == 3
    x = 0.02 * torch.randn(3, g.num_vertices, 3, generator=torch.Generator().manual_seed(0))
    image = target.encode(x)
    assert image.shape == (3, 3, 64, 256)
    full = tie_ops.render(x)
    # the window is the full image's front rows 96..160, and nothing of the chart lies outside it
    assert torch.equal(image, full[:, 0:3, 96:160])
    assert full[:, 3:].abs().max() == 0 and full[:, :, :96].abs().max() == 0 and full[:, :, 160:].abs().max() == 0
    # back to the vertices exactly (the operators' exact round trip survives the window)
    assert (target.values(image) - x).abs().max() < 1e-5
    assert torch.equal(target.values(image), tie_ops.sample(full))
    # differentiable: the losses train through it
    pred = image.clone().requires_grad_(True)
    target.values(pred).square().sum().backward()
    assert pred.grad is not None and pred.grad.abs().sum() > 0


def test_an_image_window_that_cuts_the_chart_is_refused(tie, tie_ops):
    from pbc.pixels.target import WindowTarget

    rows = tie[0].vertex_uv[:, 1] * 256 - 0.5  # the pixel rows the vertices sample between
    cut = int(rows.min()) + 3
    with pytest.raises(ValueError, match=r"cuts the garment's charts.*rows \d+\.\.\d+\); widen image.whole_rows"):
        WindowTarget(None, tie[0].faces, tie_ops, (0,), (cut, 160))
    WindowTarget(None, tie[0].faces, tie_ops, (0,), (int(rows.min()), int(rows.max()) + 2))  # just fits
    with pytest.raises(ValueError, match=r"add the side to image.whole_sides"):
        WindowTarget(None, tie[0].faces, tie_ops, (1,), (96, 160))


def test_the_net_reads_its_own_joints_of_the_full_pose():
    from pbc.models.decoder import ConvDecoder

    kw = {"out_channels": 3, "output_size": [16, 64], "start_size": [4, 16], "start_channels": 16,
          "first_layer": "linear", "hidden": [8]}
    ids = [0, 1, 3, 4]
    torch.manual_seed(0)
    net = ConvDecoder(36, input_joints=ids, num_joints=10, **kw).eval()
    plain = ConvDecoder(36, **kw).eval()
    plain.load_state_dict(net.state_dict())
    upper = torch.randn(2, 10, 3, 3).triu(1)
    pose = torch.linalg.matrix_exp(upper - upper.mT)  # exp of a skew-symmetric matrix: a rotation
    with torch.no_grad():
        assert torch.equal(net(pose), plain(pose[:, ids]))
        moved = pose.clone()
        moved[:, [2, 5, 7]] = torch.eye(3)  # joints it does not read
        assert torch.equal(net(moved), net(pose))
        assert torch.equal(net(pose.reshape(2, 90)), net(pose))
    with pytest.raises(ValueError, match="4 joints .* 36 input numbers, but in_features=90"):
        ConvDecoder(90, input_joints=ids, num_joints=10, **kw)
    with pytest.raises(ValueError, match="a 10-joint pose has joints 0..9"):
        ConvDecoder(18, input_joints=[3, 12], num_joints=10, **kw)


def test_net_config_sizes_the_tie_net_from_the_target_and_the_skeleton(cfg, body):
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from pbc.jobs.train import net_config

    target = SimpleNamespace(image_size=(64, 256), channels=3, skinner=SimpleNamespace(skeleton=body.skeleton))
    net = net_config(cfg, target)
    assert net["input_joints"] == [0, 1, 3, 4] and net["num_joints"] == 10 and net["in_features"] == 36
    assert net["output_size"] == [64, 256] and net["out_channels"] == 3
    assert count_parameters(instantiate(net)) == 2_161_667
    wrong = OmegaConf.merge(cfg, {"data": {"pose_joints": ["neck", "nek"]}})
    with pytest.raises(ValueError, match=r"data.pose_joints: unknown joints \['nek'\]"):
        net_config(wrong, target)


def test_a_dataset_posing_joints_the_model_does_not_read_is_refused(body):
    from pbc.core.validate import check_pose_joints, moving_joints

    names = body.skeleton.names
    poses = torch.eye(3).expand(5, len(names), 3, 3).clone()
    assert moving_joints(poses.numpy(), names) == []
    rot = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.3, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    poses[2, names.index("neck")] = rot
    poses[4, names.index("l_arm")] = rot
    assert moving_joints(poses.numpy(), names) == ["neck", "l_arm"]  # skeleton order
    check_pose_joints(poses.numpy(), names, None, "d")  # null reads every joint
    with pytest.raises(ValueError, match=r"poses joints \['l_arm'\] that the model does not read"):
        check_pose_joints(poses.numpy(), names, ["lower_back", "neck"], "d")


