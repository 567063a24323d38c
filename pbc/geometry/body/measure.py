"""A body's measurements for people: height, arm angle and the chest / waist / hip girths (conf/measure.yaml).

Works on any Body (mannequin or Anny): girths are the convex-hull perimeters of horizontal sections of the
torso part (a tape measure spans the hollows), scanned over bands set relative to the shoulder height.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from omegaconf import OmegaConf
from scipy.spatial import ConvexHull

from pbc.core.paths import CONF_DIR
from pbc.geometry.body.base import Body, body_sdf

TORSO = 0  # part index of the torso in every body's part masks


def measure_config():
    return OmegaConf.load(CONF_DIR / "measure.yaml")


def girth(mesh: trimesh.Trimesh, y: float, half_width: float | None = None, centre_x: float = 0.0) -> float:
    """Convex-hull perimeter (mesh units) of the section of `mesh` at height y, with ``half_width`` only of its
    points within that distance of x = ``centre_x`` (a top's torso, not its sleeves); 0 where the plane cuts no
    area there (it misses the mesh, or the points left lie on a line)."""
    seg = trimesh.intersections.mesh_plane(mesh, [0.0, 1.0, 0.0], [0.0, float(y), 0.0])
    pts = np.asarray(seg).reshape(-1, 3)
    if half_width is not None:
        pts = pts[np.abs(pts[:, 0] - centre_x) < half_width]
    pts = pts[:, [0, 2]]
    if len(pts) < 3 or np.linalg.matrix_rank(pts - pts.mean(0)) < 2:
        return 0.0
    return float(ConvexHull(pts).area)  # in 2D, ConvexHull.area is the perimeter


def torso_mesh(body: Body) -> trimesh.Trimesh:
    """The rest mesh's faces whose corners are all in the torso part and in no limb part."""
    f = body.faces.numpy()
    torso = body.parts[TORSO].numpy() & ~body.parts[1:].numpy().any(0)
    return trimesh.Trimesh(body.vertices.double().numpy(), f[torso[f].all(1)], process=False)


def measurements(body: Body, cfg=None) -> dict[str, float]:
    """{height, shoulder_height, chest, waist, hips (girths), and their heights} in metres."""
    cfg = cfg or measure_config()
    v = body.vertices.double().numpy()
    mesh = torso_mesh(body)
    sk = body.skeleton
    ys = float(sk.rest_heads[[sk.index("l_arm"), sk.index("r_arm")], 1].mean())
    out = {"height": float(v[:, 1].max() - v[:, 1].min()), "shoulder_height": ys}
    for name, pick in (("chest", np.argmax), ("waist", np.argmin), ("hips", np.argmax)):
        lo, hi = (float(x) * ys for x in cfg[name])
        heights = np.arange(lo, hi + 1e-9, float(cfg.step))
        g = np.array([girth(mesh, y) for y in heights])
        ok = g > 0
        k = int(pick(g[ok]))
        out[name], out[f"{name}_at"] = float(g[ok][k]), float(heights[ok][k])
    return out


def inside_test_gap(body: Body) -> dict[str, float]:
    """|inside-test SDF| (m) at the rest mesh's vertices, mean / p95 / max: how far the surface the inside
    test sees (pose pruning, the shrink-wrap's rays) lies from the mesh (the embedding, the drape)."""
    with torch.no_grad():
        d = body_sdf(body, torch.eye(3).expand(1, body.skeleton.num_joints, 3, 3), body.vertices)[0].abs()
    return {"mean": float(d.mean()), "p95": float(torch.quantile(d, 0.95)), "max": float(d.max())}
