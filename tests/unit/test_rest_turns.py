"""Anny's rest turns as a garment made on another rest needs them (pbc.geometry.body.anny): the forearms of one rest
taken to another's bend (`forearms_like`, the drape onto the rest's last turn), and the rest a sleeve's cloth was
made on read back from the cloth alone (`long_sleeves_rest`, what `pbc garment inspect` names). Skin stands in for
tight sleeves: the arms' own vertices on bodies turned to known rests."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.body.anny import forearms_like, long_sleeves_rest, turned_heads
from pbc.geometry.body.skeleton import forward_kinematics
from pbc.geometry.meshops import nearest_segment

ELBOW_REACH = float(load_config(["garment=obj"]).garment.placement.elbow_reach)  # a long sleeve passes the elbow by it


@pytest.fixture(scope="module")
def tpose():
    return body_from_config(load_config(["body=anny_tpose"]).body)


def _turned(body, rest: dict):
    return body_from_config(OmegaConf.merge(body.config, {"rest": rest}))


def _elbow_deg(heads: np.ndarray, names, side: str) -> float:
    arm, fore, hand = (heads[names.index(f"{side}_{n}")] for n in ("arm", "forearm", "hand"))
    u, d = fore - arm, hand - fore
    return float(np.degrees(np.arccos(u @ d / np.linalg.norm(u) / np.linalg.norm(d))))


def _arm_skin(body, reach: float = 1.0) -> np.ndarray:
    """The vertices of both arms past the shoulder joints, out to `reach` m from them (a tight sleeve)."""
    v = body.vertices.double().numpy()
    x0 = float(body.skeleton.rest_heads[body.skeleton.index("l_arm"), 0])
    return v[(np.abs(v[:, 0]) > x0) & (np.abs(v[:, 0]) < x0 + reach) & (v[:, 1] > 0.0)]


def test_forearms_like_bends_straight_forearms_as_anothers_and_leaves_the_rest(tpose):
    bind = _turned(tpose, {"arm_angle_deg": None, "straight_forearms": False})  # Anny's own: forearms bent
    names = list(tpose.skeleton.names)
    rot = forearms_like(tpose.skeleton, bind.skeleton)
    moved = turned_heads(tpose.skeleton, forward_kinematics(tpose.skeleton, rot.float())).numpy()
    for side in ("l", "r"):
        want = _elbow_deg(bind.skeleton.rest_heads.double().numpy(), names, side)
        assert want > 15.0  # the bind pose's bend, which the T-pose straightened
        assert _elbow_deg(tpose.skeleton.rest_heads.double().numpy(), names, side) < 1.0
        assert abs(_elbow_deg(moved, names, side) - want) < 0.5
        hand, fore = names.index(f"{side}_hand"), names.index(f"{side}_forearm")
        assert moved[hand, 2] - moved[fore, 2] > 0.05  # bent forward, as Anny's arms are
    others = [j for j, n in enumerate(names) if not n.endswith("_forearm")]
    assert torch.equal(rot[0, others], torch.eye(3, dtype=rot.dtype).expand(len(others), 3, 3))
    same = forearms_like(bind.skeleton, bind.skeleton)
    assert torch.allclose(same, torch.eye(3, dtype=same.dtype).expand_as(same), atol=1e-6)


@pytest.mark.parametrize("rest", [{"arm_angle_deg": 30.0, "straight_forearms": True},
                                  {"arm_angle_deg": None, "straight_forearms": False}])
def test_long_sleeves_rest_reads_the_rest_a_long_sleeve_was_made_on(tpose, rest):
    made_on = _turned(tpose, rest)
    want = rest["arm_angle_deg"] if rest["arm_angle_deg"] is not None else 48.2  # Anny's bind pose
    got = long_sleeves_rest(tpose, _arm_skin(made_on), ELBOW_REACH)
    assert got["straight_forearms"] is rest["straight_forearms"]
    assert abs(got["arm_angle_deg"] - want) <= 3


def test_a_short_sleeve_is_left_to_its_own_axis(tpose):
    made_on = _turned(tpose, {"arm_angle_deg": None, "straight_forearms": False})  # Anny's own, forearms bent
    assert long_sleeves_rest(tpose, _arm_skin(made_on, reach=0.15), ELBOW_REACH) is None  # a T-shirt's reach


def test_nearest_segment_matches_the_naive_search():
    rng = np.random.default_rng(0)
    segs = rng.normal(size=(3, 2, 3))
    pts = rng.normal(size=(50, 3))
    k, t, q = nearest_segment(pts, segs)
    ts = np.linspace(0.0, 1.0, 20001)
    for n, p in enumerate(pts):
        dense = segs[:, 0][:, None] + ts[None, :, None] * (segs[:, 1] - segs[:, 0])[:, None]  # (S, T, 3)
        d = np.linalg.norm(dense - p, axis=2)
        s, i = np.unravel_index(d.argmin(), d.shape)
        assert k[n] == s and abs(t[n] - ts[i]) < 1e-3 and np.linalg.norm(q[n] - dense[s, i]) < 1e-3
