"""The viewer's library without a server: slider angles <-> poses, the update function (pose -> the meshes
drawn), error colours, sequences and ports; the command's refusals. The scene in a real browser is
tests/integration/test_view_browser.py."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

import matplotlib
import numpy as np
import pytest
import torch
from helpers.cli import exit_code
from omegaconf import OmegaConf

sys.path.insert(0, str(Path(__file__).parent))
from helpers.evaluate_world import IMAGE, ROOT, _rotations, fake_dataset  # noqa: E402

from pbc.cli import view as view_cli  # noqa: E402
from pbc.geometry.body.base import pose_body  # noqa: E402
from pbc.geometry.body.skeleton import skeleton_from_config  # noqa: E402
from pbc.inference.predictor import ClothPredictor  # noqa: E402
from pbc.jobs.view import (
    angles_to_pose,
    check_port,
    clamp_to_limits,
    error_colors,
    free_port,
    load_sequence,
    pose_to_angles,
    view_config,
    view_meshes,
)
from pbc.models.decoder import ConvDecoder  # noqa: E402
from pbc.sim.poses import euler_xzy_to_matrix  # noqa: E402

SKELETON = skeleton_from_config(OmegaConf.load(ROOT / "conf/body/mannequin.yaml"))


def small_decoder(kind: str, seed: int) -> ConvDecoder:
    """An untrained narrow decoder of the run layout `save_run` writes (whole: 6 x 256^2, patch: 3 x 160^2),
    its outputs scaled to a few mm as a barely trained model's."""
    torch.manual_seed(seed)
    whole = kind == "whole"
    net = ConvDecoder(90, 6 if whole else 3, (256, 256) if whole else (160, 160), (8, 8) if whole else (5, 5), 32,
                      "conv_transpose" if whole else "linear").eval()
    with torch.no_grad():
        net.head.weight.mul_(0.01)
        net.head.bias.zero_()
    return net


def tiny_predictor(directory: Path, patches: bool = False) -> ClothPredictor:
    """A predictor on the stand-in dataset (test_evaluate.fake_dataset): the whole model, and with `patches`
    one small patch model per cage patch stitched by conf/stitch/average.yaml's settings."""
    ds = fake_dataset(directory)
    nets = [small_decoder("patch", k) for k in range(len(ds.cage.patches))] if patches else []
    stitch = OmegaConf.load(ROOT / "conf/stitch/average.yaml") if patches else None
    return ClothPredictor(ds, IMAGE, small_decoder("whole", 100), nets, stitch)


@pytest.fixture(scope="module")
def predictor(tmp_path_factory):
    return tiny_predictor(tmp_path_factory.mktemp("view") / "fake")


def test_slider_angles_and_poses_are_inverse_within_the_limits():
    rng = np.random.default_rng(0)
    lim = SKELETON.limits_deg.double().numpy()
    angles = rng.uniform(lim[..., 0], lim[..., 1])  # (J, 3): every joint, anywhere in its range
    pose = angles_to_pose(angles)
    assert torch.allclose(pose, euler_xzy_to_matrix(torch.as_tensor(angles)).float(), atol=1e-6)
    assert np.allclose(pose_to_angles(pose), angles, atol=1e-3)
    # a pose outside the limits shows on the sliders at the nearest limit
    wide = angles.copy()
    wide[7, 0] = lim[7, 0, 1] + 10.0
    assert clamp_to_limits(pose_to_angles(angles_to_pose(wide)), lim)[7, 0] == pytest.approx(lim[7, 0, 1])


def test_the_update_is_the_predictor_on_the_posed_body_and_the_error_is_per_vertex(predictor):
    ds = predictor.dataset
    pose = torch.from_numpy(np.array(ds.poses[8]))
    truth = np.asarray(ds.verts[8])
    m = view_meshes(predictor, pose, "whole", truth=truth)
    assert np.allclose(m.garment, predictor(pose, model="whole").numpy(), atol=1e-6)
    assert np.allclose(m.body, pose_body(ds.body, pose[None])[0].numpy(), atol=1e-6)
    assert m.error_cm.shape == (truth.shape[0],)
    assert np.allclose(m.error_cm, np.linalg.norm(m.garment - truth, axis=1) * 100, atol=1e-4)
    assert view_meshes(predictor, pose, "whole").error_cm is None
    # another pose moves both meshes
    other = view_meshes(predictor, torch.from_numpy(_rotations(1, 10, seed=5)[0]), "whole")
    assert np.abs(other.garment - m.garment).max() > 1e-3 and np.abs(other.body - m.body).max() > 1e-3


def test_error_colours_run_over_the_colormap_and_saturate():
    cfg = view_config()
    cmap = matplotlib.colormaps[str(cfg.error_colormap)]
    c = error_colors(np.array([0.0, 1.5, 3.0, 30.0]), 3.0, str(cfg.error_colormap))
    assert c.shape == (4, 4) and c.dtype == np.uint8
    assert np.array_equal(c[0], (np.array(cmap(0.0)) * 255).astype(np.uint8))
    assert np.array_equal(c[2], c[3])  # above the scale's top: the top colour
    assert not np.array_equal(c[0], c[1]) and not np.array_equal(c[1], c[2])


def test_a_port_in_use_gives_the_next_free_one_and_a_bad_port_is_refused():
    with socket.socket() as busy:
        busy.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = busy.getsockname()[1]
        got = free_port("127.0.0.1", taken)
        assert got > taken
        with socket.socket() as s:  # the port given back can really be bound
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", got))
    assert free_port("127.0.0.1", 0) == 0
    for bad in (-1, 65536, "8080", True, 80.0):
        with pytest.raises(ValueError, match="TCP port number"):
            check_port(bad)


def test_a_sequence_is_an_npy_of_rotations_or_a_bvh(predictor, tmp_path):
    ds = predictor.dataset
    seq = np.asarray(ds.poses[:4])
    np.save(tmp_path / "walk.npy", seq)
    poses, fps, motion = load_sequence(tmp_path / "walk.npy", ds)
    assert torch.allclose(poses, torch.from_numpy(seq)) and fps is None and motion is None
    with pytest.raises(ValueError, match=r"\.npy of \(N, 10, 3, 3\) rotations or a \.bvh"):
        load_sequence(tmp_path / "walk.txt", ds)
    with pytest.raises(ValueError, match="does not exist"):
        load_sequence(tmp_path / "missing.npy", ds)
    # a BVH clip through pbc.motion (test_bvh's writer of the body's skeleton): its poses and its frame rate
    from test_bvh import clip_text, random_poses

    clip = random_poses(5, seed=2)
    (tmp_path / "walk.bvh").write_text(clip_text(clip))
    poses, fps, motion = load_sequence(tmp_path / "walk.bvh", ds)
    assert np.allclose(poses.numpy(), clip, atol=1e-5) and fps == pytest.approx(120, rel=1e-4)
    assert motion.units and len(motion.poses) == 5
    np.save(tmp_path / "scaled.npy", seq * 2)
    with pytest.raises(ValueError, match="rotation"):
        load_sequence(tmp_path / "scaled.npy", ds)


def test_the_command_refuses_a_missing_pretrained_model_and_a_bad_port(capsys):
    assert exit_code(view_cli.main, ["--pretrained", "no_such_model"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pbc view: error: no pretrained model named 'no_such_model': pbc ships ") and "tshirt" in err
    assert len(err.splitlines()) == 1
    assert exit_code(view_cli.main, ["run", "--port", "http"]) == 2
    assert "give a TCP port number" in capsys.readouterr().err
    assert exit_code(view_cli.main, []) == 2
    assert "give a whole-shirt run dir" in capsys.readouterr().err
