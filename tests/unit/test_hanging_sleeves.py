"""Sleeves in any rest pose and dresses: a long-sleeved top modelled with its arms down
beside the torso (tests/helpers/long_sleeves.py posed on Anny with its arms lowered) has its sleeves found and
measured against Anny's rest arms, also under a dress's skirt flaring wider than the sleeves, and inspect names
the rest to make it on; `pbc garment fit` drapes a top whose hem hangs to mid-thigh or lower as a dress (its legs
posed) and a shirt as a shirt. No drapes here."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from helpers.long_sleeves import long_sleeve_shirt, obj_text

from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.garment.checks import LimbCloth, sleeve_axes
from pbc.geometry.garment.placement import hem, openings
from pbc.geometry.inspect import inspect_garment
from pbc.jobs.garment_fit import DRESS_DATA, Fit, is_dress

ARMS_DOWN_DEG = 80.0


@pytest.fixture(scope="module")
def hanging(anny_body):
    """(positions (V, 3), faces (F, 3), uv, face_uv): pbc's long-sleeved shirt with its arms 80 degrees down."""
    cfg = load_config(["body=anny", f"body.rest.arm_angle_deg={ARMS_DOWN_DEG}", "body.rest.straight_forearms=true"])
    return long_sleeve_shirt(body_from_config(cfg.body), "tshirt_coarse")


def flared_skirt(top_y: float, bottom_y: float, top_r: float, bottom_r: float, cols: int = 32, rows: int = 8):
    """(positions (V, 3), faces (F, 3)) of an open cone, a flared skirt's cloth, about the body's vertical axis."""
    a = np.linspace(0.0, 2 * np.pi, cols, endpoint=False)
    t = np.linspace(0.0, 1.0, rows + 1)
    r = top_r + (bottom_r - top_r) * t
    y = top_y + (bottom_y - top_y) * t
    p = np.stack([np.outer(r, np.sin(a)), np.repeat(y[:, None], cols, 1), np.outer(r, np.cos(a))], -1).reshape(-1, 3)
    f = []
    for i in range(rows):
        for j in range(cols):
            a0, a1 = i * cols + j, i * cols + (j + 1) % cols
            f += [(a0, a0 + cols, a1), (a1, a0 + cols, a1 + cols)]
    return p, np.asarray(f)


def test_arms_down_sleeves_are_found_and_measured_against_the_rest_arms(anny_body, hanging):
    p, f, _, _ = hanging
    limb = LimbCloth.from_config(load_config(["body=anny"]).garment.shrinkwrap)
    axes = sleeve_axes(p, f, anny_body, limb)
    assert set(axes) == {"left", "right"}
    for side, a in axes.items():
        assert abs(a["droop_deg"] - ARMS_DOWN_DEG) < 5.0, (side, a["droop_deg"])
        assert a["angle_deg"] > 20.0  # Anny's rest arms are 45-50 degrees down: off by 30 or more


def test_a_skirt_flaring_wider_than_hanging_sleeves_hides_no_sleeve(anny_body, hanging):
    p, f, _, _ = hanging
    skirt, sf = flared_skirt(-0.05, -0.6, 0.2, 0.5)  # its hem reaches 0.5 m out, past the sleeves (0.3)
    assert np.abs(skirt[:, 0]).max() > np.abs(p[:, 0]).max()
    both = np.concatenate([p, skirt])
    faces = np.concatenate([f, sf + len(p)])
    limb = LimbCloth.from_config(load_config(["body=anny"]).garment.shrinkwrap)
    axes = sleeve_axes(both, faces, anny_body, limb)
    assert set(axes) == {"left", "right"}
    assert all(abs(a["droop_deg"] - ARMS_DOWN_DEG) < 5.0 for a in axes.values()), axes


def test_inspect_names_the_rest_to_make_arms_down_sleeves_on(anny_body, hanging, tmp_path):
    p, f, uv, fuv = hanging
    path = tmp_path / "hanging.obj"
    path.write_text(obj_text(p, f, uv, fuv, unit=1.0, header="# arms-down long sleeves, metres on Anny"))
    gcfg = load_config(["body=anny", "garment=obj", f"garment.obj={path}"]).garment
    report = inspect_garment(path, gcfg, anny_body, wrap=False)
    assert "no sleeves found" not in report.suggest_pose
    assert report.suggest_made_on is not None and report.suggest_made_on["arm_angle_deg"] > 55, report.suggest_made_on


def _report(p, f, kind="top"):
    return SimpleNamespace(positions=p, faces=f, placement=SimpleNamespace(kind=kind))


def test_a_top_whose_hem_hangs_to_mid_thigh_is_draped_as_a_dress(anny_body, hanging):
    p, f, _, _ = hanging
    below = float(load_config(["body=anny", "garment=obj", "garment.obj=x"]).garment.dress_hem_below_hips)
    hips = float(anny_body.skeleton.rest_heads[anny_body.skeleton.index("l_hip"), 1])
    assert hem(openings(p, f))["centre"][1] > hips - below  # pbc's shirt: its hem above mid-thigh
    assert not is_dress(_report(p, f), anny_body, below)
    longer = p.copy()
    low = (p[:, 1] < hips) & (np.abs(p[:, 0]) < 0.2)  # the torso's cloth below the hip joints, to the knees
    longer[low, 1] = hips + (p[low, 1] - hips) * 2.5
    assert hem(openings(longer, f))["centre"][1] < hips - below
    assert is_dress(_report(longer, f), anny_body, below)
    assert not is_dress(_report(longer, f, kind="bottom"), anny_body, below)  # a bottom is a skirt or trousers
    fit = Fit.__new__(Fit)
    fit.user = []
    report = SimpleNamespace(suggest_charts={}, suggest_unit="auto", suggest_made_on=None,
                             rows=[SimpleNamespace(area_3d=1.0, centroid=np.array([0.0, 0.2, 0.0]))],
                             positions=longer, faces=f, placement=SimpleNamespace(kind="top"))
    assert DRESS_DATA in fit.derived_settings(report, anny_body, below)
    fit.user = ["data=tshirt_small"]  # the user's own data set is kept
    assert DRESS_DATA not in fit.derived_settings(report, anny_body, below)
    assert load_config(["body=anny", DRESS_DATA]).data.pose_joints[-4:] == ["l_hip", "r_hip", "l_knee", "r_knee"]
