"""The wrong-body study (pbc.geometry.body.sculpt, pbc.jobs.robustness): the sculpted bodies, the painted weights and
the whole chain at scale=smoke (one model per body, report, Figs. 9-10) on a stand-in dataset made in
seconds: the coarse body and shirt, the shirt embedded at its closest body points, smooth offsets."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.geometry.body.sculpt import paint_weights, sculpt_displacement, shaped_body
from pbc.geometry.meshops import vertex_normals

ROOT = Path(__file__).resolve().parents[2]
N = 12


def stand_in_dataset(d: Path, body) -> Path:
    """A dataset dir (the real file layout) of the coarse shirt on `body`: N poses, smooth offsets."""
    from pbc.core.config import load_garment_config
    from pbc.data.dataset import save_embedding
    from pbc.geometry.body.base import save_body
    from pbc.geometry.cage.base import save_cage
    from pbc.geometry.garment.base import save_garment_obj
    from pbc.geometry.garment.tshirt import make_tshirt
    from pbc.geometry.shrinkwrap import embed_points
    from pbc.pixels.reconstruct import Skinner

    garment, cage = make_tshirt(load_garment_config(ROOT / "conf/garment/tshirt_coarse.yaml"))
    V, J = garment.vertices.shape[0], len(body.skeleton.names)
    emb = embed_points(garment.vertices.numpy(), body, np.zeros(V, np.int64), 16)
    rng = np.random.default_rng(0)
    angles = rng.uniform(-0.4, 0.4, (N, J))
    c, s = np.cos(angles), np.sin(angles)
    poses = np.zeros((N, J, 3, 3), np.float32)
    poses[..., 0, 0], poses[..., 0, 2], poses[..., 2, 0], poses[..., 2, 2], poses[..., 1, 1] = c, s, -s, c, 1
    anchors, frames = Skinner(body, garment, emb)(torch.from_numpy(poses))
    rest = garment.vertices
    field = torch.einsum("nk,vk->nv", torch.from_numpy(angles[:, :6]).float(), torch.cat([rest, rest ** 2], 1))
    local = torch.stack([0.01 * field, -0.005 * field, 0.015 + 0.01 * field.tanh()], -1)
    verts = anchors + torch.einsum("nvij,nvi->nvj", frames, local)
    d.mkdir(parents=True, exist_ok=True)
    np.save(d / "poses.npy", poses)
    np.save(d / "verts.npy", verts.numpy().astype(np.float32))
    save_garment_obj(garment, d / "garment.obj")
    save_cage(cage, d / "cage.json", V)
    save_body(body, d / "body.npz")
    save_embedding(emb, d / "embedding.npz")
    manifest = {"format_version": 1, "garment_hash": "standin", "body_hash": "true", "counts": {"kept": N},
                "splits": {"train": list(range(8)), "val": [8, 9], "test": [10, 11]}}
    (d / "manifest.json").write_text(json.dumps(manifest))
    return d


def settings():
    from pbc.jobs.robustness import load_settings

    return load_settings()


def test_sculpt_thickens_chest_and_belly_linearly(body):
    rob = settings()
    disp = sculpt_displacement(body, OmegaConf.to_container(rob.sculpt.bumps), part=0)
    n = vertex_normals(body.vertices, body.faces)
    along = (disp * n).sum(-1)
    # only the torso moves, outward, by at most the bumps' summed depth, and the front of the belly moves most
    total = sum(float(b.depth) for b in rob.sculpt.bumps)
    assert (along >= -1e-7).all() and 0.03 < float(along.max()) <= total + 1e-6
    assert float(along[~body.parts[0]].abs().max()) == 0.0
    front = (body.vertices[:, 2] > 0.08) & (body.vertices[:, 1].sub(0.14).abs() < 0.05) & body.parts[0]
    back = (body.vertices[:, 2] < -0.08) & (body.vertices[:, 1].sub(0.14).abs() < 0.05)
    assert float(along[front].mean()) > 0.02 > float(along[back].abs().max())
    for t in (-1.0, 0.5, 2.0):
        b = shaped_body(body, disp, t)
        assert torch.allclose(b.vertices - body.vertices, t * disp, atol=1e-6)
        assert torch.equal(b.faces, body.faces) and torch.equal(b.weights, body.weights)
    assert torch.equal(shaped_body(body, disp, 0.0).vertices, body.vertices)


def test_painted_weights_follow_the_arm(body):
    rob = settings()
    art = OmegaConf.to_container(rob.artifacts.paint_torso_arm)
    painted = paint_weights(body, art["joint"], art["regions"])
    col = 1 + list(body.skeleton.names).index(art["joint"])
    assert torch.allclose(painted.weights.sum(1), torch.ones(body.vertices.shape[0]), atol=1e-5)
    gained = painted.weights[:, col] - body.weights[:, col]
    assert (gained >= -1e-6).all()
    right_arm = body.parts[2] & ~body.parts[0]
    assert float(gained[right_arm].max()) > 0.3  # the opposite arm now follows the left upper arm
    torso = body.parts[0] & ~body.parts[1] & ~body.parts[2]
    assert float(gained[torso].max()) > 0.3
    far = (body.vertices[:, 1] < 0.0)  # the hips are far from both regions
    assert float(gained[far].abs().max()) < 1e-4
    with pytest.raises(ValueError, match="unknown joint"):
        paint_weights(body, "tail", art["regions"])




def test_a_dataset_of_several_people_is_refused_before_any_trial_is_made(tmp_path, body):
    # its trial dirs lacked shapes.npz and person.npy, so every trial failed later on a missing file
    from pbc.data.shapes import BodyShapes, save_shapes
    from pbc.jobs.robustness import make_bodies

    d = stand_in_dataset(tmp_path / "data", body)
    J = len(body.skeleton.names)
    rest = body.vertices[None].repeat(2, 1, 1)
    save_shapes(BodyShapes(("height",), np.array([[0.4], [0.6]]), rest * torch.tensor([1.0, 1.02, 1.0]),
                           body.skeleton.rest_heads[None].repeat(2, 1, 1).reshape(2, J, 3)), d / "shapes.npz")
    np.save(d / "person.npy", np.arange(N, dtype=np.int64) % 2)
    manifest = json.loads((d / "manifest.json").read_text())
    (d / "manifest.json").write_text(json.dumps(dict(manifest, body_shapes={"keys": ["height"], "count": 2})))
    with pytest.raises(ValueError, match=r"draped on 2 people \(data.body_shape\).*dataset of one body"):
        make_bodies(d, tmp_path / "sweep", settings(), ["shape_0.5"])
    assert not (tmp_path / "sweep").exists()
