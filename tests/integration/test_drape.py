"""The drape (newton SolverStyle3D) on a tiny stand-in: a ~150-vertex cloth strip wrapped, compressed,
over a horizontal capsule split into three collision parts; plus the D.6 discard rule.

The first run compiles warp kernels into the kernel cache (35-45 s on a CPU); later runs take seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from pbc.sim.drape import (
    _oriented_panels,
    build_drape_sim,
    check_sample,
    closest_points,
    drape,
    pattern_triangles,
    rest_triangle_areas,
    triangle_area_ratios,
)

ROOT = Path(__file__).resolve().parents[2]
RADIUS = 0.08


def sim_cfg():
    """conf/sim/style3d.yaml resolved the way Hydra would (root_dir = the repo)."""
    root = OmegaConf.create({"paths": {"root_dir": str(ROOT)}, "sim": OmegaConf.load(ROOT / "conf/sim/style3d.yaml")})
    return root.sim


def grid(nu: int, nv: int):
    """(nu*nv) vertex grid -> faces (F, 3) and uv (V, 2) in [0, 1]^2, consistently wound."""
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    u, v = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv), indexing="ij")
    return faces, np.stack([u.ravel(), v.ravel()], 1)


@pytest.fixture(scope="module")
def scene():
    """A capsule along x (the 'arms' at its ends) and a 0.4 x 0.5 m strip wrapped over its top.

    The strip's start is 10% compressed around the capsule (like a skinned garment), 1 mm off the
    surface; its arc covers +-100 degrees so both sides hang free under gravity.
    """
    import trimesh

    cap = trimesh.creation.capsule(height=0.5, radius=RADIUS, count=[16, 16])
    v, f = trimesh.remesh.subdivide_to_size(cap.vertices, cap.faces, 0.04)
    rot = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])[:3, :3]
    bv = np.asarray(v) @ rot.T
    bf = np.asarray(f)
    masks = np.stack([np.abs(bv[:, 0]) < 0.15, bv[:, 0] > 0.05, bv[:, 0] < -0.05])

    nu, nv = 9, 17
    faces, uv = grid(nu, nv)
    width, length = 0.4, 0.5  # pattern size (m) along x and around the capsule
    uv_scale = 1.0  # uv is [0,1]^2: scale the pattern per axis through the uv themselves
    uv = uv * np.array([width, length])
    x = (uv[:, 0] - width / 2) * 0.9
    theta = (uv[:, 1] - length / 2) * 0.9 / (RADIUS + 0.001)
    start = np.stack([x, (RADIUS + 0.001) * np.cos(theta), (RADIUS + 0.001) * np.sin(theta)], 1)
    part = np.where(start[:, 0] > 0.12, 1, np.where(start[:, 0] < -0.12, 2, 0))
    pattern = pattern_triangles(uv, faces, uv_scale)
    return {"bv": bv, "bf": bf, "masks": masks, "faces": faces, "start": start, "part": part, "pattern": pattern}


@pytest.fixture(scope="module")
def draped(scene):
    cfg = sim_cfg()
    s = scene
    return drape(s["pattern"], s["faces"], s["start"], s["bv"], s["bf"], s["part"], s["masks"], cfg), cfg


def test_area_check_flags_crushed_and_stretched_triangles():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    rest = np.full(2, 0.5)
    cfg = sim_cfg()
    assert check_sample(pts, faces, rest, cfg) == (True, "")
    crushed = pts.copy()
    crushed[3] = [0.55, 0.55, 0]  # second triangle keeps 10% of its area
    ratio = triangle_area_ratios(crushed, faces, rest)
    assert ratio[0] == pytest.approx(1.0) and ratio[1] == pytest.approx(0.1)
    assert check_sample(crushed, faces, rest, cfg) == (False, "area_compressed")
    stretched = pts.copy()
    stretched[3] = [2.5, 2.5, 0]  # second triangle grows to 4x
    assert check_sample(stretched, faces, rest, cfg) == (False, "area_stretched")
    assert check_sample(pts, faces, rest, cfg, converged=False) == (False, "not_converged")
    bad = pts.copy()
    bad[0, 0] = np.nan
    assert check_sample(bad, faces, rest, cfg) == (False, "nan")


def test_panels_are_positively_oriented_and_keep_their_shape():
    faces, uv = grid(3, 3)
    tri = pattern_triangles(uv[:, ::-1], faces, 0.5)  # swapped axes: every face is mirrored
    panels = _oriented_panels(tri, faces, None).reshape(-1, 3, 2)
    e1, e2 = panels[:, 1] - panels[:, 0], panels[:, 2] - panels[:, 0]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)
    np.testing.assert_allclose(rest_triangle_areas(panels), rest_triangle_areas(tri))
    np.testing.assert_allclose(
        np.linalg.norm(panels[:, 1] - panels[:, 0], axis=1), np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)
    )


def test_each_vertex_collides_with_its_own_part_only(scene):
    s = scene
    sim = build_drape_sim(s["pattern"], s["faces"], s["start"], s["bv"], s["bf"], s["part"], s["masks"], sim_cfg())
    pairs = sim["pipeline"].soft_rigid_contact_pairs.numpy()
    assert pairs.shape == (len(s["start"]), 2)
    np.testing.assert_array_equal(pairs[:, 0], np.arange(len(s["start"])))
    np.testing.assert_array_equal(pairs[:, 1], s["part"])  # shape k is part k
    sim["pipeline"].collide(sim["states"][0], sim["contacts"])
    n = int(sim["contacts"].soft_contact_count.numpy()[0])
    particles = sim["contacts"].soft_contact_particle.numpy()[:n]
    assert 0 < n <= len(s["start"]) and len(np.unique(particles)) == n  # at most one contact each


def test_drape_converges_without_penetration(draped, scene):
    res, cfg = draped
    assert res.converged, res
    assert res.residual < cfg.tolerance
    assert res.positions.shape == scene["start"].shape and res.positions.dtype == np.float32
    sd, _ = closest_points(res.positions, scene["bv"], scene["bf"])
    # nothing inside the body, and the cloth rests at the contact thickness (1 mm slack for the penalty)
    assert sd.min() > cfg.thickness - 1.0e-3, sd.min()


def test_drape_falls_under_gravity_and_relaxes(draped, scene):
    res, cfg = draped
    start, end = scene["start"], res.positions.astype(np.float64)
    rest = rest_triangle_areas(scene["pattern"])
    # gravitational potential (uniform mass per vertex is enough to compare) went down ...
    assert end[:, 1].mean() < start[:, 1].mean() - 0.005
    # ... the 10%-compressed start relaxed towards the pattern's areas ...
    dist0 = np.abs(triangle_area_ratios(start, scene["faces"], rest) - 1).mean()
    dist1 = np.abs(triangle_area_ratios(end, scene["faces"], rest) - 1).mean()
    assert dist1 < dist0
    # ... and the strip still hangs on the capsule: its middle row rests on top
    top = np.argmax(start[:, 1])
    assert end[top, 1] > RADIUS
    assert check_sample(end, scene["faces"], rest, cfg, res.converged) == (True, "")
