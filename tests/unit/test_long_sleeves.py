"""Each garment region is wrapped and embedded on the body part it covers (pbc.geometry.shrinkwrap's regions):
a long-sleeved MakeHuman shirt (tests/helpers/long_sleeves.py) on Anny A- and T-posed has its sleeves on the
arms down to the wrists, trouser legs go on the legs, a skirt stays on the trunk, pbc's own garments embed as
they did, and the stretch refusal names the body part and the cause. No drapes here
(tests/integration/test_garment_fit.py fits the shirt)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from helpers.long_sleeves import long_sleeve_mhclo, trousers_mhclo

from pbc.cli.garment import run
from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import base_mesh_vertices
from pbc.geometry.body.skeleton import limb_segments
from pbc.geometry.garment import garment_from_config
from pbc.geometry.garment.checks import check_stretch, cloth_encircled_degrees
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.geometry.meshio import write_garment_mesh
from pbc.geometry.meshops import encircled_degrees
from pbc.geometry.shrinkwrap import (
    REGIONS,
    body_region_faces,
    embed_points,
    garment_regions,
    shrinkwrap,
    vertex_parts,
    wrap_positions,
)
from pbc.pixels.operators import build_operators

SLEEVE_X = 0.25  # m: a cage patch centred this far from the midplane is a sleeve's (the torso's are at 0)


def _sleeves(cage, x0: np.ndarray, sgn: float) -> np.ndarray:
    """(V,) bool: the vertices of the patches of the sleeve on the side sgn (+1 left, -1 right)."""
    out = np.zeros(len(x0), bool)
    for p in cage.patches:
        if sgn * x0[p.vertices, 0].mean() > SLEEVE_X:
            out[p.vertices] = True
    return out


@pytest.fixture(scope="module", params=["anny", "anny_tpose"])
def blouse(request, tmp_path_factory):
    """(body, garment, cage, garment config) of the long-sleeved shirt as MakeHuman clothes on the body."""
    cfg = load_config([f"body={request.param}"])
    body = body_from_config(cfg.body)
    path = long_sleeve_mhclo(tmp_path_factory.mktemp(request.param), body, base_mesh_vertices(cfg.body).numpy())
    gcfg = load_config(["garment=mhclo", f"garment.path={path}", f"body={request.param}"]).garment
    g, cage = garment_from_config(gcfg, body)
    return body, g, cage, gcfg


def _joint_of_faces(body, faces: np.ndarray) -> list[str]:
    """The joint with the most skinning weight on each body triangle."""
    w = body.weights.numpy()[body.faces.numpy()[faces]].sum(1)  # (N, J+1)
    names = ["root", *body.skeleton.names]
    return [names[j] for j in w.argmax(1)]


def test_long_sleeves_are_wrapped_and_embedded_on_their_arms_down_to_the_wrists(blouse):
    body, g, cage, gcfg = blouse
    x0 = g.vertices.double().numpy()
    emb, stats = shrinkwrap(g, cage, body, gcfg)
    x, _ = wrap_positions(g, cage, body, gcfg)
    region = garment_regions(g.faces.numpy(), cage, x0, body, gcfg.shrinkwrap.min_encircled_deg,
                             gcfg.shrinkwrap.region_smoothing)
    arm_faces = body_region_faces(body)
    for sgn, r in ((1.0, 1), (-1.0, 2)):
        sleeve = _sleeves(cage, x0, sgn)
        assert sleeve.sum() > 40 and (region[sleeve] == r).all(), REGIONS[r]
        # embedded on the arm's own triangles and colliding with that arm
        assert np.isin(emb.face.numpy()[sleeve], arm_faces[r]).all()
        assert (emb.part.numpy()[sleeve] == r).all()
        # the cuff (the farthest tenth of the sleeve along the arm) rides on the forearm or the hand
        hand = body.skeleton.rest_heads[body.skeleton.index("l_hand" if r == 1 else "r_hand")].numpy()
        d = np.linalg.norm(x0 - hand, axis=1)
        cuff = sleeve & (d < np.quantile(d[sleeve], 0.1))
        joints = set(_joint_of_faces(body, emb.face.numpy()[cuff]))
        assert joints <= {"l_forearm", "l_hand", "r_forearm", "r_hand"}, joints
    # the wrap keeps every sleeve round its arm: the nearest-surface wrap carried sleeve vertices 40 cm onto the
    # torso (cage rays from the spine) and stretched the sleeves 2x on this shirt
    sleeves = _sleeves(cage, x0, 1.0) | _sleeves(cage, x0, -1.0)
    assert np.linalg.norm(x - x0, axis=1)[sleeves].max() < 0.12
    assert stats["patch_stretch_max"] < 1.5
    assert stats["region_left_arm_vertices"] >= _sleeves(cage, x0, 1.0).sum()


def test_pbcs_own_shirt_embeds_as_the_nearest_surface_does(body):
    # the procedural shirt names its sleeves; restricting them to the arms' triangles changes no vertex of it
    # (the starter model's embedding stays valid): the naive nearest-triangle embedding is the reference
    cfg = load_config(["garment=tshirt_coarse", "body.mesh.voxel_size=0.03"]).garment
    g, cage = make_tshirt(cfg)
    x, _ = wrap_positions(g, cage, body, cfg)
    region = garment_regions(g.faces.numpy(), cage, x, body, cfg.shrinkwrap.min_encircled_deg,
                             cfg.shrinkwrap.region_smoothing)
    assert set(np.unique(region)) == {0, 1, 2}
    ours = embed_points(x, body, vertex_parts(region), 12, region)
    naive = embed_points(x, body, vertex_parts(region), 12)
    assert (ours.face == naive.face).all() and (ours.bary == naive.bary).all()


def test_trouser_legs_go_on_the_legs_and_a_skirt_stays_on_the_trunk(tmp_path):
    cfg = load_config(["body=anny"])
    body = body_from_config(cfg.body)
    found = {}
    for kind in ("trousers", "skirt"):
        g, _ = garment_from_config(load_config([f"garment={kind}", "body=anny"]).garment, body)
        path = write_garment_mesh(tmp_path / f"{kind}.obj", g)  # as a file from elsewhere: its cage made anew
        gcfg = load_config(["garment=obj", f"garment.obj={path}", "body=anny"]).garment
        g2, cage = garment_from_config(gcfg, body)
        found[kind] = garment_regions(g2.faces.numpy(), cage, g2.vertices.double().numpy(), body,
                                       gcfg.shrinkwrap.min_encircled_deg, gcfg.shrinkwrap.region_smoothing)
        x = g2.vertices.double().numpy()
        if kind == "trousers":
            low = x[:, 1] < -0.3  # the lower legs
            assert (found[kind][low & (x[:, 0] > 0)] == 3).all() and (found[kind][low & (x[:, 0] < 0)] == 4).all()
    assert (found["skirt"] == 0).all()  # beside the legs, round neither of them


def test_encircled_degrees_tells_a_ring_from_one_side():
    segs = np.array([[[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]]])  # an arm along x
    t = np.linspace(0.0, 0.3, 11)
    ang = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    ring = np.array([[a, 0.06 * np.cos(q), 0.06 * np.sin(q)] for a in t for q in ang])
    half = ring[ring[:, 2] > 0]
    assert encircled_degrees(ring, segs) > 340.0
    assert 140.0 < encircled_degrees(half, segs) < 200.0  # 15 to 165 degrees: 150
    assert np.isnan(encircled_degrees(ring[:2], segs))  # nothing to measure


def _coarse_sleeve(body, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A coarse tube round the mannequin's left arm (along +x, T-posed) as a tool exports a long sleeve: rings of 8
    vertices 4.5 cm apart, 7 cm from the bone, each ring's plane turned ``tilt_deg`` off square to the bone.
    Returns its vertices (V, 3) and faces (F, 3)."""
    a = limb_segments(body.skeleton, "l_arm")[0, 0]
    x = np.arange(0.22, 0.5, 0.045)
    q = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    r, skew = 0.07, np.tan(np.radians(tilt_deg))
    pts = np.array([[xi + skew * r * np.cos(u), a[1] + r * np.cos(u), a[2] + r * np.sin(u)] for xi in x for u in q])
    i, j = np.meshgrid(np.arange(len(x) - 1), np.arange(8), indexing="ij")
    p0, p1 = 8 * i + j, 8 * i + (j + 1) % 8
    quads = np.stack([p0, p1, p0 + 8, p1 + 8], -1).reshape(-1, 4)
    return pts, np.concatenate([quads[:, [0, 2, 1]], quads[:, [1, 2, 3]]])


def test_a_coarse_sleeve_skewed_to_the_bone_is_wrapped_on_its_arm(body):
    # each ring, 12 degrees off square, spans the 3 cm slices of the encircling measure: its vertices fall partly
    # in each and read as cloth on one side (180 degrees), where the faces between the rings close round the arm
    # (292-315), as the sleeve check measures it; half the tube (a flap) still goes on the torso
    cage = SimpleNamespace(patches=[])  # no named sleeve patches: the regions are measured
    cfg = load_config(["garment=obj", "garment.obj=x"]).garment.shrinkwrap
    need, smoothing = float(cfg.min_encircled_deg), float(cfg.region_smoothing)
    x, f = _coarse_sleeve(body, 12.0)
    segs = limb_segments(body.skeleton, "l_arm")
    assert encircled_degrees(x, segs) < need <= cloth_encircled_degrees(x, f, segs)
    assert (garment_regions(f, cage, x, body, need, smoothing) == REGIONS.index("left arm")).all()
    flap = f[x[f][:, :, 2].mean(1) > segs[0, 0, 2]]
    assert (garment_regions(flap, cage, x, body, need, smoothing)[np.unique(flap)] == 0).all()


def test_limb_segments_follow_the_skeleton(body):
    anny = body_from_config(load_config(["body=anny"]).body)
    chain = limb_segments(anny.skeleton, "l_arm")
    heads = anny.skeleton.rest_heads.numpy()
    assert len(chain) == 2 and np.allclose(chain[0, 0], heads[anny.skeleton.index("l_arm")])
    assert np.allclose(chain[-1, 1], heads[anny.skeleton.index("l_hand")])
    assert len(limb_segments(anny.skeleton, "l_hip")) == 2
    # the mannequin's arm is one joint: one segment out along the arm (+x for the left, T-posed)
    one = limb_segments(body.skeleton, "l_arm")
    assert one.shape == (1, 2, 3) and one[0, 1, 0] - one[0, 0, 0] > 0.3


def test_the_stretch_refusal_names_the_body_part_and_the_cause():
    names, charts = ["front_00", "sleeve_00"], ["front", "sleeve"]
    stretch = np.array([1.1, 9.5])
    with pytest.raises(ValueError) as err:
        check_stretch(stretch, names, charts, 2.0, {}, ["torso", "torso"], ["torso", "left arm"], 1.3)
    msg = str(err.value)
    assert "chart 'sleeve' (patch sleeve_00, wrapped on the torso) to 9.5x" in msg
    assert "lies nearest the left arm" in msg and "uv_unit" not in msg
    with pytest.raises(ValueError) as err:  # on the part it lies nearest: placement, not the UV unit
        check_stretch(stretch, names, charts, 2.0, {}, ["torso", "left arm"], ["torso", "left arm"], 1.3)
    assert "closer to the left arm" in str(err.value) and "uv_unit" not in str(err.value)
    with pytest.raises(ValueError) as err:  # every patch stretched alike: the UV unit
        check_stretch(np.array([9.0, 9.5]), names, charts, 2.0, {}, ["torso", "left arm"], None, 9.2)
    assert "the whole garment is stretched 9.2x" in str(err.value) and "garment.uv_unit" in str(err.value)
    check_stretch(np.array([1.0, 1.9]), names, charts, 2.0)  # within the limit: nothing


def test_operators_of_charts_too_small_for_the_image_stay_bounded_and_say_so(blouse):
    # at 64 px the shirt's six charts crowd a few pixels each: the exact correction used to run away (|R| 4e42, a
    # NaN loss at the first step); it keeps its best R and warns, naming the setting
    _, g, _, _ = blouse
    with pytest.warns(UserWarning, match="raise image.whole_resolution"):
        small = build_operators(g, 64, 2)
    assert np.isfinite(small["R_data"]).all() and np.abs(small["R_data"]).max() < 2.0
    assert small["residual"] <= 1.0
    big = build_operators(g, 256, 2)
    assert big["residual"] < 1e-6


def test_inspect_says_which_body_part_each_chart_is_wrapped_on(blouse, capsys):
    _, _, _, gcfg = blouse
    name = "anny" if "anny_tpose" not in str(gcfg.path) else "anny_tpose"
    assert run(["inspect", str(gcfg.path), f"body={name}"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if "; wrapped on the " in line]
    on = sorted(line.split("; wrapped on the ")[1] for line in rows)
    # the two torso panels and the four sleeve halves (each sleeve's front and back is its own chart)
    assert on == ["left arm", "left arm", "right arm", "right arm", "torso", "torso"], on


def test_a_cape_along_the_arms_is_wrapped_on_the_torso(tmp_path):
    # its flaps reach about 150 degrees round the arm, a loose short sleeve over the shoulder 155-265: neither
    # surrounds the arm, both are wrapped on the torso (a refusal could not tell the two apart)
    cfg = load_config(["body=anny"])
    body = body_from_config(cfg.body)
    path = long_sleeve_mhclo(tmp_path / "cape", body, base_mesh_vertices(cfg.body).numpy(), cape=True)
    gcfg = load_config(["garment=mhclo", f"garment.path={path}", "body=anny"]).garment
    g, cage = garment_from_config(gcfg, body)
    x0 = g.vertices.double().numpy()
    region = garment_regions(g.faces.numpy(), cage, x0, body, gcfg.shrinkwrap.min_encircled_deg,
                             gcfg.shrinkwrap.region_smoothing)
    flaps = np.abs(x0[:, 0]) > SLEEVE_X + 0.1
    assert flaps.sum() > 20 and (region[flaps] == 0).all()
    # with the limit lowered below the flaps' reach they go on the arms
    low = garment_regions(g.faces.numpy(), cage, x0, body, 120.0, gcfg.shrinkwrap.region_smoothing)
    assert set(np.unique(low[flaps])) == {1, 2}


@pytest.mark.parametrize("pose", ["anny", "anny_tpose"])
def test_a_cape_along_the_forearms_is_refused_naming_the_arm_and_the_setting(tmp_path, pose):
    """Wrapped on the torso, a cape's flaps along the forearms would be caught by the arms in every drape: the wrap
    refuses in one line naming the forearm and what to set; with that setting lowered the flaps go on the arms and
    the wrap goes through. The long-sleeved shirt itself is not refused."""
    cfg = load_config([f"body={pose}"])
    body = body_from_config(cfg.body)
    base = base_mesh_vertices(cfg.body).numpy()
    path = long_sleeve_mhclo(tmp_path / "cape", body, base, cape=True)
    gcfg = load_config(["garment=mhclo", f"garment.path={path}", f"body={pose}"]).garment
    g, cage = garment_from_config(gcfg, body)
    with pytest.raises(ValueError, match=r"along the body's (left|right) forearm.*min_encircled_deg") as err:
        shrinkwrap(g, cage, body, gcfg)
    assert "\n" not in str(err.value)
    gcfg.shrinkwrap.min_encircled_deg = 120
    g, cage = garment_from_config(gcfg, body)
    _, stats = shrinkwrap(g, cage, body, gcfg)
    assert stats["region_left_arm_vertices"] > 0
    shirt = long_sleeve_mhclo(tmp_path / "shirt", body, base)
    gcfg = load_config(["garment=mhclo", f"garment.path={shirt}", f"body={pose}"]).garment
    shrinkwrap(*garment_from_config(gcfg, body), body, gcfg)


@pytest.mark.parametrize("pose", ["anny", "anny_tpose"])
def test_trousers_as_makehuman_clothes_wrap_their_legs_on_the_legs(tmp_path, pose):
    """pbc's trousers written as MakeClothes writes clothes: each trouser leg is wrapped on its own leg (not the
    other's, not the trunk), the waistband on the trunk, nothing found lying on the garment's own cloth."""
    cfg = load_config([f"body={pose}"])
    body = body_from_config(cfg.body)
    path = trousers_mhclo(tmp_path, body, base_mesh_vertices(cfg.body).numpy())
    gcfg = load_config(["garment=mhclo", f"garment.path={path}", f"body={pose}"]).garment
    g, cage = garment_from_config(gcfg, body)
    x0 = g.vertices.double().numpy()
    emb, stats = shrinkwrap(g, cage, body, gcfg)
    assert stats["patch_stretch_max"] < 1.5 and stats["layer_vertices"] == 0 and emb.lift is None
    region = garment_regions(g.faces.numpy(), cage, x0, body, gcfg.shrinkwrap.min_encircled_deg,
                             gcfg.shrinkwrap.region_smoothing)
    low = x0[:, 1] < np.percentile(x0[:, 1], 40)  # the lower legs of the trousers
    left, right = REGIONS.index("left leg"), REGIONS.index("right leg")
    assert (region[low & (x0[:, 0] > 0.05)] == left).all() and (region[low & (x0[:, 0] < -0.05)] == right).all()
    assert stats["region_torso_vertices"] > 0


def test_garment_fit_drapes_trousers_with_the_trousers_preset(tmp_path):
    """`pbc garment fit` on trousers (a bottom with three openings) takes conf/data/trousers_small (the ankles
    posed, the trousers' contact and fabric) where a skirt takes skirt_small (tests/integration/test_garment_fit);
    a data= of the user's is kept."""
    from pbc.jobs.garment_fit import Fit, garment_overrides, inspect_file  # noqa: PLC0415

    cfg = load_config(["body=anny"])
    body = body_from_config(cfg.body)
    path = trousers_mhclo(tmp_path / "t", body, base_mesh_vertices(cfg.body).numpy())
    fit_cfg = load_config([*garment_overrides(path, []), "body=anny"])
    report = inspect_file(path, fit_cfg, body, tmp_path, wrap=False)
    below = float(fit_cfg.garment.dress_hem_below_hips)
    derived = Fit(path, [], tmp_path / "fit").derived_settings(report, body, below)
    assert "data=trousers_small" in derived and "++garment.shrinkwrap.arm_parts=false" in derived
    mine = Fit(path, ["data=skirt_small"], tmp_path / "fit").derived_settings(report, body, below)
    assert not any(o.startswith("data=") for o in mine)
