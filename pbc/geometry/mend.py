"""A predicted garment mended where it falls apart: edges stretched past a cap shortened, and cloth inside a
collider (the body, or the layers under it) pushed out, each by one sparse least-squares solve that keeps the
rest of the mesh where it was predicted.

Both are the same screened solve over the garment's edges: find y (V, 3) minimising

    sum_e |(y_a - y_b) - d_e|^2 + sum_i w_i |y_i - t_i|^2

with d_e the target edge vectors and t_i, w_i the target positions and their weights. Where every target agrees
with the prediction x (d = G x, t = x) the answer is x itself: a mesh that needs no mending is returned unchanged
to the last bit, since the solve is skipped.

- `shorten_edges`: d_e is the predicted edge cut to `cap` times its usual length (the median over the model's
  drapes), t = x with the weight `anchor`; repeated, since shortening an edge stretches its neighbours a little.
- `push_out_of`: d = G x (the predicted shape), t_i the point `margin` outside the collider for the vertices
  inside it (or nearer than the margin), with a weight far above `anchor`, t = x elsewhere (TailorNet's one-solve
  push-out; PBNS's layers each use the body and the layers under them as the collider).

Pure numpy / scipy on arrays (the settings read from conf/mend.yaml); nothing here knows what a garment, a
model or a pose is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from omegaconf import OmegaConf

from pbc.core.paths import CONF_DIR
from pbc.core.validate import check_settings_file
from pbc.geometry.meshops import surface_distance

SETTINGS_FILE = CONF_DIR / "mend.yaml"


@dataclass(frozen=True)
class MendSettings:
    """conf/mend.yaml as typed values (the defaults mirror it; a test keeps them equal)."""

    stretch_cap: float = 2.0  # an edge past this many times its usual length is shortened to it; 0 = off
    anchor: float = 0.1  # weight of each vertex's predicted position against its edges' (lower: wider spread)
    iterations: int = 10  # shortening passes at most
    push_out: bool = False  # push the cloth out of the collider (the posed body, the layers under it)
    margin: float = 0.003  # m: where a vertex inside the collider is put, outside its surface
    push_weight: float = 100.0  # weight of a pushed vertex's target against the edges that keep the shape
    push_band: float = 0.03  # m: a vertex farther inside an open collider (a layer) than this is not judged
    candidates: int = 12  # triangles searched for each vertex's closest collider point (meshops.surface_distance)
    usual_drapes: int = 512  # drapes an edge's usual length is the median over (spread over the model's data)


def mend_settings(**overrides) -> MendSettings:
    """conf/mend.yaml held to conf/bounds.yaml's `mend` section (one ValueError naming every bad key), as
    MendSettings, with `overrides` (field=value) on top."""
    node = OmegaConf.load(SETTINGS_FILE)
    check_settings_file("mend", node, SETTINGS_FILE)
    values = {**OmegaConf.to_container(node), **overrides}
    unknown = sorted(set(values) - {f.name for f in fields(MendSettings)})
    if unknown:
        raise ValueError(f"{SETTINGS_FILE}: unknown mend setting(s) {unknown}; the settings are "
                         f"{[f.name for f in fields(MendSettings)]}")
    return MendSettings(**values)


def edge_operator(edges: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """G (E, V): row e is +1 at edges[e, 0] and -1 at edges[e, 1], so G x gives the edge vectors."""
    e = np.asarray(edges, np.int64)
    rows = np.r_[np.arange(len(e)), np.arange(len(e))]
    vals = np.r_[np.ones(len(e)), -np.ones(len(e))]
    return sp.csr_matrix((vals, (rows, np.r_[e[:, 0], e[:, 1]])), shape=(len(e), int(num_vertices)))


def screened_factor(g: sp.csr_matrix, weights: np.ndarray):
    """The factorised system G^T G + diag(weights) of `screened_solve`: g (E, V), weights (V,) > 0. Its
    `.solve(rhs (V, 3))` answers one right-hand side; a loop whose weights stay (`shorten_edges`) factors once."""
    return spla.splu((g.T @ g + sp.diags(np.asarray(weights, np.float64))).tocsc())


def screened_solve(g: sp.csr_matrix, edge_vectors: np.ndarray, targets: np.ndarray, weights: np.ndarray
                   ) -> np.ndarray:
    """y (V, 3) minimising |G y - edge_vectors|^2 + sum_i weights_i |y_i - targets_i|^2: g (E, V),
    edge_vectors (E, 3), targets (V, 3), weights (V,) > 0."""
    w = np.asarray(weights, np.float64)
    rhs = g.T @ edge_vectors + w[:, None] * np.asarray(targets, np.float64)
    return screened_factor(g, w).solve(np.asarray(rhs, np.float64))


def edge_ratios(x: np.ndarray, edges: np.ndarray, usual: np.ndarray) -> np.ndarray:
    """(E,) each edge's length in x (V, 3) over its usual length (E,)."""
    return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=-1) / np.maximum(usual, 1e-12)


def shorten_edges(x: np.ndarray, edges: np.ndarray, usual: np.ndarray, settings: MendSettings,
                  g: sp.csr_matrix | None = None) -> tuple[np.ndarray, dict]:
    """x (V, 3) with every edge longer than settings.stretch_cap times its usual length (E,) shortened towards
    it, the rest of the mesh moved as little as the edges allow. Returns (y (V, 3), stats: edges past the cap
    before, the longest ratio before and after, the most any vertex moved in mm)."""
    x = np.asarray(x, np.float64)
    ratio = edge_ratios(x, edges, usual)
    stats = {"stretched": int((ratio > settings.stretch_cap).sum()), "ratio_before": float(ratio.max()),
             "ratio_after": float(ratio.max()), "moved_mm": 0.0}
    if settings.stretch_cap <= 0 or not stats["stretched"]:
        return x, stats
    g = edge_operator(edges, len(x)) if g is None else g
    w = np.full(len(x), float(settings.anchor))
    lu = screened_factor(g, w)
    y = x
    for _ in range(int(settings.iterations)):
        d = g @ y
        length = np.linalg.norm(d, axis=1)
        cut = np.minimum(1.0, settings.stretch_cap * usual / np.maximum(length, 1e-12))
        if (cut >= 1.0).all():
            break
        y = lu.solve(np.asarray(g.T @ (d * cut[:, None]) + w[:, None] * x, np.float64))
    stats["ratio_after"] = float(edge_ratios(y, edges, usual).max())
    stats["moved_mm"] = float(np.linalg.norm(y - x, axis=1).max() * 1e3)
    return y, stats


@dataclass(frozen=True)
class Collider:
    """A surface the cloth must stay outside: vertices (N, 3), faces (F, 3) with outward normals; mask (V,) bool
    the garment vertices it holds out (None: all of them); closed: negative distance is inside (a body part),
    else an open surface (a garment layer) judged only within `MendSettings.push_band` of it."""

    vertices: np.ndarray
    faces: np.ndarray
    mask: np.ndarray | None = None
    closed: bool = True


def collider_distances(x: np.ndarray, colliders: Sequence[Collider], settings: MendSettings
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each vertex of x (V, 3) against the colliders that hold it: (signed distance (V,) to the one it is
    deepest in, +inf where none judges it; the closest point there (V, 3); the outward normal there (V, 3))."""
    dist = np.full(len(x), np.inf)
    closest, normal = np.zeros_like(x), np.zeros_like(x)
    for c in colliders:
        rows = np.arange(len(x)) if c.mask is None else np.flatnonzero(c.mask)
        if not len(rows):
            continue
        d, q, n = surface_distance(x[rows], c.vertices, c.faces, settings.candidates)
        if not c.closed:
            d = np.where(d > -settings.push_band, d, np.inf)
        better = d < dist[rows]
        r = rows[better]
        dist[r], closest[r], normal[r] = d[better], q[better], n[better]
    return dist, closest, normal


def push_out_of(x: np.ndarray, edges: np.ndarray, colliders: Sequence[Collider], settings: MendSettings,
                g: sp.csr_matrix | None = None) -> tuple[np.ndarray, dict]:
    """x (V, 3) with the vertices inside a collider that holds them (or nearer its surface than
    settings.margin, once one is inside) moved to settings.margin outside it, their neighbours following as the
    predicted shape's edges ask. Returns (y (V, 3), stats: vertices inside before and after, as counts and
    fractions, the deepest in mm before, the solves taken)."""
    x = np.asarray(x, np.float64)
    dist, closest, normal = collider_distances(x, colliders, settings)
    inside = dist < 0.0
    stats = {"inside": int(inside.sum()), "inside_fraction": float(inside.mean()) if len(x) else 0.0,
             "depth_max_mm": float(-dist[inside].min() * 1e3) if inside.any() else 0.0}
    if not settings.push_out or not inside.any():
        stats.update(inside_after=stats["inside"], inside_fraction_after=stats["inside_fraction"], passes=0)
        return x, stats
    g = edge_operator(edges, len(x)) if g is None else g
    shape = g @ x
    pushed = np.zeros(len(x), bool)
    targets = x.copy()
    y, passes = x, 0
    # a pushed vertex lands near its target, not on it: judged again on the result, at most `iterations` times
    while passes < int(settings.iterations) and (dist < 0.0).any():
        push = dist < settings.margin
        targets[push] = closest[push] + settings.margin * normal[push]
        pushed |= push
        y = screened_solve(g, shape, targets, np.where(pushed, settings.push_weight, settings.anchor))
        passes += 1
        dist, closest, normal = collider_distances(y, colliders, settings)
    still = dist < 0.0
    stats.update(inside_after=int(still.sum()), inside_fraction_after=float(still.mean()), passes=passes)
    return y, stats
