"""Per-joint limits measured from motion (pbc.motion.limits, `pbc motion limits`) and the sampler taking them
(`+body.limits_file`, pbc.geometry.body.joint_limits): known angles come back as limits (percentiles, the floor,
rounding outward), the command writes a file the body config takes, a bad input is one line naming the fix and
writes nothing, and without the option every shipped config resolves as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.cli import exit_code
from omegaconf import OmegaConf

from pbc.cli import motion as motion_cli
from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.body.joint_limits import LIMITS_DIR, read_limits_file, resolved_limits, with_limits_file
from pbc.motion.limits import (
    LimitSettings,
    box_angles,
    limit_settings,
    limits_rows,
    limits_table,
    limits_yaml,
    measured_limits,
    outside_box,
)
from pbc.motion.retarget import motion_settings
from pbc.sim.poses import euler_xzy_to_matrix

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "tests" / "data" / "bvh" / "cmu_mb_02_01_walk.bvh"
WIDE = np.tile(np.array([[-170.0, 170.0], [-170.0, 170.0], [-85.0, 110.0]]), (2, 1, 1))  # (J=2, 3, 2)


def _poses(angles: np.ndarray) -> np.ndarray:
    """(N, J, 3, 3) rotations of Euler angles (N, J, 3) degrees (the sampler's chart)."""
    return euler_xzy_to_matrix(np.asarray(angles, np.float64)).numpy()


def _angles(n: int = 1000) -> np.ndarray:
    """(n, 2, 3): joint 0 x spread over [-10.3, 30.2], y at 5, z at 1; joint 1 all 0."""
    a = np.zeros((n, 2, 3))
    a[:, 0, 0] = np.linspace(-10.3, 30.2, n)
    a[:, 0, 1] = 5.0
    a[:, 0, 2] = 1.0
    return a


def test_known_angles_come_back_rounded_outward_holding_the_rest_and_the_floor():
    limits, measured = measured_limits(_poses(_angles()), WIDE, LimitSettings((0.0, 100.0), 4.0))
    # x: the extremes, rounded outward; y: [0, 5] holds the rest; z: [0, 1] widened to 4 about 0.5, rounded out
    assert limits[0].tolist() == [[-11.0, 31.0], [0.0, 5.0], [-2.0, 3.0]]
    assert measured.tolist() == [True, True]
    assert limits[1].tolist() == [[-2.0, 2.0]] * 3  # a joint always at rest: the floor about 0
    no_floor, _ = measured_limits(_poses(_angles()), WIDE, LimitSettings((0.0, 100.0), 0.0))
    assert no_floor[0, 2].tolist() == [0.0, 1.0]


def test_the_percentiles_leave_rare_frames_out():
    a = np.zeros((1000, 2, 3))
    a[:996, 0, 0] = np.linspace(0.0, 20.0, 996)
    a[996:, 0, 0] = 80.0  # 4 frames in 1000: above the 99.5th percentile
    limits, _ = measured_limits(_poses(a), WIDE, LimitSettings((0.5, 99.5), 4.0))
    assert limits[0, 0].tolist() == [0.0, 20.0]
    every, _ = measured_limits(_poses(a), WIDE, LimitSettings((0.0, 100.0), 4.0))
    assert every[0, 0].tolist() == [0.0, 80.0]
    axes, frames = outside_box(_poses(a), limits)
    assert int(axes[:, 0, 0].sum()) == 4 and int(frames.sum()) == 4


def test_a_joint_no_frame_drives_keeps_the_reference_and_is_left_out_of_the_file():
    driven = np.ones((1000, 2), bool)
    driven[:, 1] = False
    limits, measured = measured_limits(_poses(_angles()), WIDE, LimitSettings((0.0, 100.0), 4.0), driven)
    assert measured.tolist() == [True, False] and np.array_equal(limits[1], WIDE[1])
    text = limits_yaml(["a", "b"], limits, measured, ["made by a test"])
    assert yaml.safe_load(text) == {"joints": [{"name": "a", "limits": {"x": [-11, 31], "y": [0, 5], "z": [-2, 3]}}]}
    rows = limits_rows(["a", "b"], _poses(_angles()), WIDE, limits, measured)
    assert len(rows) == 6 and rows[0].outside_hand_set == 0.0 and "(not driven)" in limits_table(rows)


def test_an_arm_raised_past_z_90_reads_in_the_decomposition_the_box_holds():
    a = np.array([[[10.0, 5.0, 100.0], [0.0, 0.0, 0.0]]])
    assert np.allclose(box_angles(_poses(a), WIDE), a, atol=1e-6)
    limits, _ = measured_limits(_poses(a), WIDE, LimitSettings((0.0, 100.0), 4.0))
    assert limits[0].tolist() == [[0.0, 10.0], [0.0, 5.0], [0.0, 100.0]]


@pytest.mark.parametrize("pct", [(-1.0, 99.0), (5.0, 101.0), (50.0, 50.0), (90.0, 10.0)])
def test_a_percentile_out_of_range_is_refused(pct):
    with pytest.raises(ValueError, match=r"give two percentiles 0 <= low < high <= 100"):
        measured_limits(_poses(_angles(10)), WIDE, LimitSettings(pct, 4.0))


def test_the_shipped_settings_and_limits_file_load():
    s = limit_settings(motion_settings().limits)
    assert 0.0 <= s.percentiles[0] < s.percentiles[1] <= 100.0
    table = read_limits_file("anny_cmu")
    names = [str(j["name"]) for j in load_config(["body=anny"]).body.joints]
    assert set(table) <= set(names) and all(set(v) == {"x", "y", "z"} for v in table.values())
    assert (LIMITS_DIR / "anny_cmu.yaml").read_text().count("CMU") >= 2  # its header names the clips' source


# ------------------------------------------------------------------------------------ the sampler's option
def test_without_the_option_every_shipped_body_resolves_as_it_is():
    for body in sorted(p.stem for p in (ROOT / "conf" / "body").glob("*.yaml")):
        cfg = load_config([f"body={body}"])
        assert "limits_file" not in cfg.body
        assert with_limits_file(cfg.body) is cfg.body
        plain = OmegaConf.to_container(cfg.body, resolve=True)
        assert resolved_limits(cfg.body) == {j["name"]: {a: [float(v) for v in j["limits"][a]] for a in "xyz"}
                                             for j in plain["joints"]}
    from pbc.data.generate import _cheap_fingerprint
    from pbc.geometry.garment import garment_from_config

    cfg = load_config(["data=tshirt_tiny"])
    garment = garment_from_config(cfg.garment, None)[0]
    assert "joint_limits" not in _cheap_fingerprint(cfg, garment)


def test_a_limits_file_replaces_the_limits_it_lists_and_enters_the_fingerprint(tmp_path):
    f = tmp_path / "arms.yaml"
    f.write_text("joints:\n  - {name: l_arm, limits: {x: [-10, 20], z: [-30, 40]}}\n")
    plain = load_config(["data=tshirt_tiny"])
    cfg = load_config(["data=tshirt_tiny", f"+body.limits_file={f}"])
    body, base = body_from_config(cfg.body), body_from_config(plain.body)
    j = body.skeleton.index("l_arm")
    assert body.skeleton.limits_deg[j].tolist() == [[-10.0, 20.0], base.skeleton.limits_deg[j, 1].tolist(),
                                                    [-30.0, 40.0]]
    others = [k for k in range(body.skeleton.num_joints) if k != j]
    assert np.array_equal(body.skeleton.limits_deg[others], base.skeleton.limits_deg[others])
    from pbc.data.generate import _cheap_fingerprint
    from pbc.geometry.garment import garment_from_config

    garment = garment_from_config(cfg.garment, None)[0]
    assert _cheap_fingerprint(cfg, garment)["joint_limits"]["l_arm"]["x"] == [-10.0, 20.0]


@pytest.mark.parametrize("text, match", [
    ("joints:\n  - {name: l_ankle, limits: {x: [-1, 1]}}\n", r"names joints \['l_ankle'\] that body.kind='mannequin'"),
    ("joints:\n  - {name: l_arm, limits: {x: [5, -5]}}\n", r"is not \[min, max\]"),
    ("joints:\n  - {name: l_arm, limits: {w: [0, 1]}}\n", r"joints\[0\]"),
    ("limits: []\n", r"has no 'joints:' list"),
])
def test_a_bad_limits_file_is_one_line_naming_the_layout(tmp_path, text, match):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(ValueError, match=match):
        body_from_config(load_config([f"+body.limits_file={f}"]).body)
    with pytest.raises(ValueError, match=r"no such limits file; give a \.yaml file"):
        body_from_config(load_config(["+body.limits_file=nope"]).body)


# --------------------------------------------------------------------------------------------- the command
def test_the_command_on_a_clip_writes_limits_the_body_config_takes(tmp_path, capsys):
    out = tmp_path / "limits" / "walk.yaml"
    assert motion_cli.run(["limits", str(CLIP), "--out", str(out), "--note", "a test clip"]) == 0
    printed = capsys.readouterr().out
    assert "% out hand-set" in printed and "l_knee" in printed and "1 clips, 16 frames (0 refused)" in printed
    text = out.read_text()
    assert "# command: pbc motion limits" in text and "cmu_mb_02_01_walk.bvh (16)" in text and "a test clip" in text
    table = read_limits_file(out)
    cfg = load_config(["body=anny", f"+body.limits_file={out}"]).body
    merged = resolved_limits(cfg)
    assert all(merged[name] == axes for name, axes in table.items())
    # mirrored: the right side's limits are the left's, x and y negated
    assert table["r_arm"]["x"] == [-v for v in table["l_arm"]["x"][::-1]] and table["r_arm"]["z"] == \
        table["l_arm"]["z"]
    assert list(out.parent.iterdir()) == [out]  # no temporary file left


def _bad(tmp_path, argv, capsys) -> str:
    out = tmp_path / "out" / "limits.yaml"
    assert exit_code(motion_cli.main, ["limits", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.parent.exists() or not any(out.parent.iterdir())
    return err


def test_bad_inputs_are_one_line_naming_the_fix_and_write_nothing(tmp_path, capsys):
    assert "no such file or folder; give .bvh motion clips" in _bad(tmp_path, [str(tmp_path / "gone.bvh")], capsys)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no clip here")
    assert "the folder holds no .bvh clip" in _bad(tmp_path, [str(empty)], capsys)
    assert "--percentiles=[0.5, 120.0]: give two percentiles" in _bad(
        tmp_path, [str(CLIP), "--percentiles", "0.5", "120"], capsys)
    broken = tmp_path / "clips" / "broken.bvh"
    broken.parent.mkdir()
    broken.write_text("HIERARCHY\nROOT Hips\n{\n")
    err = _bad(tmp_path, [str(broken.parent), str(CLIP)], capsys)
    assert f"clip {broken} is refused by the clip reader" in err and "--skip-refused" in err
    out = tmp_path / "skipped.yaml"
    assert motion_cli.run(["limits", str(broken.parent), str(CLIP), "--skip-refused", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "skipped broken.bvh:" in printed and "(1 refused)" in printed
    assert "refused by the clip reader and left out: broken.bvh" in out.read_text()
