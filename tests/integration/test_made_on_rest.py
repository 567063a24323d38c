"""`garment.made_on_rest`: a garment made on the body turned to another rest pose (the procedural shirt, whose
straight-out sleeves fit a T-pose) is draped onto the body's own rest (Anny's A-pose) by the simulator before it
is wrapped. Without it the shirt is refused on A-posed Anny (its sleeves 50 degrees off the arms); re-skinning the
sleeves alone (the placement's rest-pose transfer) leaves the wide shirt's sides round the lowered arms, and the
wrap stretches the torso 5x (measured on the starter's shirt)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.cli import exit_code  # noqa: E402
from helpers.ecosystems import ECOSYSTEMS  # noqa: E402

from pbc.cli.garment import main  # noqa: E402
from pbc.core.config import load_config  # noqa: E402
from pbc.data.generate import build_scene, config_mismatch, fingerprint, made_on_body, scene_mirror_map
from pbc.data.mirror import MIRROR, surface_points, symmetrised
from pbc.geometry.body import body_from_config
from pbc.geometry.garment import garment_from_config  # noqa: E402
from pbc.geometry.garment.base import save_garment_obj  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
# the smallest fit (tests/integration/test_garment_fit.py's, the drape's own discard checks on)
TINY = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128", "datamodule.batch_size=4",
        "data.workers=1"]  # a few poses drape in less time than a second worker takes to start
T_POSE = "garment.made_on_rest={arm_angle_deg: 0.0, straight_forearms: true}"
SHIRT_ON_ANNY = ["data=tshirt_tiny", "body=anny", "garment.size_to_body.enabled=true", "data.mirror=true",
                 "data.num_samples=2"]


# inspect's suggestion of a rest with straight forearms: the override (1) and its arm angle (2)
MADE_ON_STRAIGHT = re.compile(r"garment.made_on_rest=(\{arm_angle_deg:(-?\d+),straight_forearms:true\})")


def inspected(tmp_path: Path, capsys, name: str, body: str) -> tuple[Path, str]:
    """tests/helpers/ecosystems.py's garment `name`, written in tmp_path, and `pbc garment inspect`'s report of it
    on `body` (no wrap)."""
    path = tmp_path / f"{name}.obj"
    path.write_text(ECOSYSTEMS[name](), newline="")
    assert exit_code(main, ["inspect", str(path), f"body={body}", "--no-wrap"]) == 0
    return path, capsys.readouterr().out


def mirror_gap(points: np.ndarray, faces: np.ndarray) -> float:
    """The largest distance (m) from a vertex's mirror image to the surface."""
    return float(surface_points(points @ MIRROR, points, faces)[0].max())


@pytest.fixture(scope="module")
def apose_scene():
    return build_scene(load_config([*SHIRT_ON_ANNY, T_POSE]))


def test_the_shirt_made_on_t_posed_anny_is_draped_onto_its_a_pose_and_wraps_there(apose_scene):
    scene, stats = apose_scene
    made = made_on_body(load_config([*SHIRT_ON_ANNY, T_POSE]))
    assert made is not scene.body
    built, _ = garment_from_config(load_config([*SHIRT_ON_ANNY, T_POSE]).garment, made)
    assert scene.garment.num_vertices == built.num_vertices  # the garment as made: its pattern, UVs and cage
    assert np.array_equal(scene.garment.uv.numpy(), built.uv.numpy())
    moved = np.linalg.norm(scene.garment.vertices.numpy() - built.vertices.numpy(), axis=1)
    assert moved.max() > 0.1  # the sleeves came down with the arms
    for side in ("left", "right"):
        assert stats[f"sleeve_{side}_angle_deg"] < 10.0  # along A-posed Anny's arms (50 degrees off as made)
    assert stats["patch_stretch_max"] < 1.6
    faces = scene.garment.faces.numpy()
    assert mirror_gap(scene.garment.vertices.double().numpy(), faces) < 1e-4  # symmetrised: data.mirror holds
    assert scene_mirror_map(load_config([*SHIRT_ON_ANNY, T_POSE]), scene, np.eye(3)[None, None].repeat(
        scene.body.skeleton.num_joints, 1).astype(np.float32)) is not None


def test_without_it_the_shirt_is_refused_on_the_a_pose():
    with pytest.raises(ValueError, match="sleeve is .* degrees off the body's rest arm"):
        build_scene(load_config(SHIRT_ON_ANNY))


def test_the_drape_onto_the_rest_is_in_the_dataset_fingerprint(apose_scene, monkeypatch):
    scene, _ = apose_scene
    fp = fingerprint(load_config([*SHIRT_ON_ANNY, T_POSE]), scene)
    assert fp["garment_made_on_rest"] == {"arm_angle_deg": 0.0, "straight_forearms": True}
    assert fp["garment_forearms_to_rest"] is True  # absent in datasets made before: forearms as made
    as_made = load_config([*SHIRT_ON_ANNY, T_POSE, "garment.made_on_forearms=as_made"])
    assert [line.split(":")[0] for line in config_mismatch(as_made, fp, full=True)] == ["embedding_hash"]
    # a drape worker takes the parent's rested garment and drapes nothing: the same scene, byte for byte
    import pbc.data.generate as generate

    def no_drape(*args):
        raise AssertionError("a worker draped the garment onto the rest again")

    monkeypatch.setattr(generate, "drape_onto_rest", no_drape)
    worker, _ = build_scene(load_config([*SHIRT_ON_ANNY, T_POSE]), scene.garment.vertices.numpy())
    assert fingerprint(load_config([*SHIRT_ON_ANNY, T_POSE]), worker) == fp
    monkeypatch.undo()
    # the cheap check (no scene: the garment as made) and the full one agree with the dataset's manifest
    cfg = load_config([*SHIRT_ON_ANNY, T_POSE])
    assert config_mismatch(cfg, fp) == [] and config_mismatch(cfg, fp, full=True) == []
    other = fingerprint(load_config([*SHIRT_ON_ANNY, "garment.made_on_rest={arm_angle_deg: 5.0}"]), scene)
    assert config_mismatch(cfg, other) == ["garment_made_on_rest.arm_angle_deg: dataset 5.0 vs config 0.0",
                                           "garment_made_on_rest.straight_forearms: dataset '<absent>' vs config True"]
    assert "garment_made_on_rest" not in fingerprint(load_config(["data=tshirt_tiny"]),
                                                      build_scene(load_config(["data=tshirt_tiny"]))[0])


def test_a_body_without_a_rest_to_turn_and_a_discarded_drape_are_one_line_each():
    with pytest.raises(ValueError, match=r"body.kind='mannequin' has none to turn: use body=anny"):
        build_scene(load_config(["data=tshirt_tiny", T_POSE]))
    # every face smaller than its pattern discards: the drape onto the rest cannot be kept
    with pytest.raises(ValueError, match=r"made_on_rest: .* discarded \(area_compressed\)"):
        build_scene(load_config([*SHIRT_ON_ANNY, T_POSE, "sim.discard.max_area_compression=0.0"]))


def test_symmetrised_keeps_a_symmetric_shape_and_mirrors_an_asymmetric_one():
    """Reference: a symmetric strip of vertices (its mirror map is vertex to vertex), checked pair by pair."""
    x = np.linspace(-1, 1, 9)
    rest = np.stack(np.meshgrid(x, [0.0, 0.5], indexing="ij"), -1).reshape(-1, 2)
    rest = np.concatenate([rest, np.zeros((len(rest), 1))], 1)  # (18, 3) in the z = 0 plane
    grid = np.arange(18).reshape(9, 2)
    faces = np.concatenate([np.stack([grid[:-1, 0], grid[1:, 0], grid[1:, 1]], 1),
                            np.stack([grid[:-1, 0], grid[1:, 1], grid[:-1, 1]], 1)])
    assert np.allclose(symmetrised(rest, rest, faces), rest)
    bent = rest + np.random.default_rng(0).normal(0, 0.01, rest.shape)
    sym = symmetrised(bent, rest, faces)
    pair = grid[::-1].reshape(-1)  # vertex i's mirror vertex
    assert np.allclose(sym, sym[pair] @ MIRROR, atol=1e-12)
    assert np.allclose(sym, 0.5 * (bent + bent[pair] @ MIRROR), atol=1e-12)


def test_the_starter_data_config_makes_the_shirt_on_t_posed_anny_and_drapes_it_onto_anny():
    cfg = load_config(["data=tshirt_anny"])
    assert cfg.body.rest.arm_angle_deg is None  # Anny's own A-pose
    assert made_on_body(cfg).skeleton.num_joints == body_from_config(cfg.body).skeleton.num_joints
    assert dict(cfg.garment.made_on_rest) == {"arm_angle_deg": 0.0, "straight_forearms": True}


def test_a_tee_made_on_t_posed_anny_fits_a_posed_anny_through_the_commands(tmp_path, capsys):
    """The tee as Blender exports it in Anny's frame (tests/helpers/ecosystems.py) sits on A-posed Anny but for its
    sleeves, so placement keeps it as given: `pbc garment inspect` names the rest to make it on, and `pbc garment
    fit` takes it and drapes it there (before: refused at the sleeve check, 50 degrees off)."""
    tee, report = inspected(tmp_path, capsys, "anny_tee", "anny")
    assert "kept as given" in report
    made_on = MADE_ON_STRAIGHT.search(report)
    assert made_on and abs(int(made_on.group(2))) <= 8, report  # its sleeves straight out
    assert exit_code(main, ["inspect", str(tee), "body=anny_tpose", "--no-wrap"]) == 0
    assert "made_on_rest" not in capsys.readouterr().out  # on the body it was made on: nothing to do
    out = tmp_path / "fit"
    env = dict(os.environ, PBC_ROOT=str(tmp_path), PBC_WARP_CACHE=str(ROOT / ".cache" / "warp"),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    res = subprocess.run(["pbc", "garment", "fit", str(tee), "body=anny", *TINY, "--samples", "3", "--epochs", "1",
                          "--until", "data",
                          "--out", str(out)], env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, (res.stdout[-3000:], res.stderr[-3000:])
    assert "garment.made_on_rest={arm_angle_deg:" in (out / "inspect" / "report.txt").read_text()
    stretch = float(res.stdout.split("most stretched patch ")[1].split()[1].rstrip("x"))
    assert stretch < 1.6
    manifest = json.loads((out / "data" / "manifest.json").read_text())
    assert manifest["garment_made_on_rest"]["straight_forearms"] is True
    assert manifest["counts"]["kept"] >= 1


def test_and_back_the_shirt_as_it_lies_on_the_a_pose_goes_onto_t_posed_anny(apose_scene, tmp_path, capsys):
    """The A-posed shirt (the drape above, written as pbc writes a garment) on T-posed Anny: inspect names the
    A-pose to make it on (its sleeves' droop), and the drape raising the arms puts its sleeves on the T-posed
    arms."""
    path = tmp_path / "a_posed.obj"
    save_garment_obj(apose_scene[0].garment, path)
    assert exit_code(main, ["inspect", str(path), "body=anny_tpose", "--no-wrap"]) == 0
    made_on = MADE_ON_STRAIGHT.search(capsys.readouterr().out)
    assert made_on and 35 <= int(made_on.group(2)) <= 60, made_on  # A-posed Anny's arms: 48 degrees down
    _, stats = build_scene(load_config(["data=tshirt_tiny", "garment=obj", f"garment.obj={path}", "body=anny_tpose",
                                        "data.mirror=true", f"garment.made_on_rest={made_on.group(1)}"]))
    for side in ("left", "right"):
        assert stats[f"sleeve_{side}_angle_deg"] < 10.0
    assert stats["patch_stretch_max"] < 1.6


def test_trousers_made_on_a_wider_stance_are_a_bottom_and_drape_onto_the_legs(tmp_path, capsys):
    """Trousers modelled with the thighs 15 degrees apart: their ankles lie farther from the midline than the
    waistband is wide, and they were taken for a top and registered at the neck (half the cloth 2.6 m from the
    body). Their widest opening is on top: a bottom, kept as given. Made on that stance
    (garment.made_on_rest={legs_apart_deg: 15}) and draped with the thighs turned back, they wrap on Anny's legs
    with no patch stretched (1.9x as given)."""
    from helpers.ecosystems import legs_apart_trousers_obj

    from pbc.geometry.garment.placement import top_or_bottom
    from pbc.geometry.meshio import read_obj

    path = tmp_path / "trousers.obj"
    path.write_text(legs_apart_trousers_obj(15.0), newline="")
    mesh = read_obj(path, "garment OBJ", require_uv=False)
    assert top_or_bottom(mesh.vertices, mesh.faces, str(path)) == "bottom"
    base = ["data=trousers_anny", "garment=obj", f"garment.obj={path}", "garment.uv_unit=cm",
            "garment.charts={front:0,back:1}"]
    _, as_given = build_scene(load_config(base))
    _, made_on = build_scene(load_config([*base, "garment.made_on_rest={legs_apart_deg: 15}"]))
    assert made_on["patch_stretch_max"] < 1.2 < as_given["patch_stretch_max"]
    # inspect measures the stance (each trouser leg's axis against the thigh) and names it; the fit takes it
    assert exit_code(main, ["inspect", str(path), "body=anny", "--no-wrap"]) == 0
    stance = re.search(r"garment.made_on_rest=\{legs_apart_deg:(\d+)\}", capsys.readouterr().out)
    assert stance and 12 <= int(stance.group(1)) <= 18, stance
    straight = tmp_path / "straight.obj"
    straight.write_text(legs_apart_trousers_obj(0.0), newline="")
    assert exit_code(main, ["inspect", str(straight), "body=anny", "--no-wrap"]) == 0
    assert "made_on_rest" not in capsys.readouterr().out  # made on Anny's own stance: nothing to do


def test_a_blouse_made_on_bent_elbows_goes_onto_straight_arms_with_its_forearms_turned(tmp_path, capsys):
    """A long-sleeved blouse modelled on Anny's own A-pose, its sleeves bent forward at the elbows as Anny's arms
    are, on T-posed Anny. Its torso sits, so placement keeps it as given (its sleeves had put it out of the
    frame check's reach: registered, then refused as "not surrounding the forearm"). `pbc garment inspect` reads
    the arm angle and the bent forearms off its long sleeves (a long sleeve's axis cannot: it points between the
    upper arm and the forearm) and names them; made there and draped onto the T-pose with each forearm turned
    straight too (garment.made_on_forearms: to_rest), its sleeves lie along the arms to the wrists. With the
    forearms left bent (as_made) the sleeve is 35 degrees off the rest arm and refused (measured, not run here:
    a second drape)."""
    from helpers.long_sleeves import bent_elbow_blouse_obj

    from pbc.geometry.body.skeleton import limb_segments
    from pbc.geometry.meshops import nearest_segment

    path = tmp_path / "blouse.obj"
    path.write_text(bent_elbow_blouse_obj(body_from_config(load_config(["body=anny"]).body)), newline="")
    assert exit_code(main, ["inspect", str(path), "body=anny_tpose", "--no-wrap"]) == 0
    report = capsys.readouterr().out
    assert "kept as given" in report
    made_on = re.search(r"garment.made_on_rest=(\{arm_angle_deg:(\d+),straight_forearms:false\})", report)
    assert made_on and 42 <= int(made_on.group(2)) <= 54, report  # Anny's own arms: 48 degrees down
    scene, stats = build_scene(load_config(["data=tshirt_tiny", "garment=obj", f"garment.obj={path}",
                                            "body=anny_tpose", "data.mirror=true",
                                            f"garment.made_on_rest={made_on.group(1)}"]))
    for side in ("left", "right"):
        assert stats[f"sleeve_{side}_angle_deg"] < 10.0
    assert stats["patch_stretch_max"] < 1.6
    points = scene.garment.vertices.double().numpy()
    for arm in ("l_arm", "r_arm"):
        bone, t, nearest = nearest_segment(points, limb_segments(scene.body.skeleton, arm))
        cuff = (bone == 1) & (t > 0.5)  # the sleeve round the outer half of the straight forearm
        assert cuff.sum() > 20 and np.linalg.norm(points[cuff] - nearest[cuff], axis=1).mean() < 0.06


def test_a_registered_tee_whose_sleeves_placement_turned_down_is_made_on_the_t_pose_instead(tmp_path, capsys):
    """The pattern tool's tee (3x life size in centimetres, the mannequin's T-pose shirt) registered on A-posed
    Anny: placement turns its sleeves 60 degrees down by re-skinning, which leaves the wide shirt's sides round the
    lowered arms, and the wrap stretches the torso 2x: refused. Inspect names the T-pose to make it on instead
    (its sleeves before the turn), and made there and draped onto the A-pose it wraps with no patch stretched."""
    from pbc.geometry.body.skeleton import limb_segments
    from pbc.geometry.meshops import nearest_segment

    tee, report = inspected(tmp_path, capsys, "pattern_tee", "anny")
    assert "placement turned its sleeves" in report
    made_on = MADE_ON_STRAIGHT.search(report)
    assert made_on and abs(int(made_on.group(2))) <= 8, report  # its sleeves straight out
    settings = [line.strip().strip("'") for line in report.split("suggested settings:")[1].splitlines()
                if line.strip().startswith(("'garment.charts", "garment.uv_unit"))]
    base = ["data=tshirt_tiny", "garment=obj", f"garment.obj={tee}", "body=anny", *settings]
    with pytest.raises(ValueError, match=r"shrink-wrap stretches chart"):
        build_scene(load_config(base))
    cfg = load_config([*base, "data.mirror=true", f"garment.made_on_rest={made_on.group(1)}"])
    scene, stats = build_scene(cfg)
    assert stats["patch_stretch_max"] < 1.2
    # the sleeves came down onto the arms: cloth beyond the shoulder joints lies near the upper arms' bones
    points = scene.garment.vertices.double().numpy()
    for arm in ("l_arm", "r_arm"):
        bone = limb_segments(scene.body.skeleton, arm)[:1]
        sleeve = points[np.sign(points[:, 0]) * bone[0, 0, 0] > 0]
        sleeve = sleeve[np.abs(sleeve[:, 0]) > abs(bone[0, 0, 0]) + 0.05]
        gap = np.linalg.norm(sleeve - nearest_segment(sleeve, bone)[2], axis=1)
        assert len(sleeve) > 20 and np.median(gap) < 0.1, (arm, np.median(gap))
