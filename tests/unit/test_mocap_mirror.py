"""A dataset's poses from motion capture (data.poses) and left/right mirroring (data.mirror), through the real
generation pipeline on the tiny shirt, with the drape replaced by the skinned garment (the unit tier drapes
no cloth): the selection, the per-sample record, reproducibility, the mirror's split rule, the bad inputs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from helpers.cli import exit_code
from helpers.generate_runs import tiny_cfg
from test_bvh import SKEL, clip_text, random_poses

import pbc.data.generate as gen
from pbc.cli.generate import main as generate_main
from pbc.data.dataset import dataset_fingerprint, load_dataset
from pbc.data.mirror import MIRROR, mirror_map, mirror_poses, mirror_verts
from pbc.data.mocap import SAMPLED, clip_poses, farthest_pose_selection
from pbc.data.subset import originals_and_mirrors, subset_dataset
from pbc.geometry.body.base import pose_body
from pbc.geometry.body.skeleton import swing_twist_angles, xzy_angles
from pbc.geometry.shrinkwrap import embedded_points
from pbc.inference.poses import training_pose_range
from pbc.motion.fit import clear_clip_arms
from pbc.motion.retarget import motion_settings
from pbc.sim.poses import sample_poses, sampling_settings_from_config


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    """The tiny shirt's scene (body, garment, embedding), built once for the module."""
    return gen.build_scene(tiny_cfg(tmp_path_factory.mktemp("scene")))


def skinned(scene, pose: np.ndarray) -> np.ndarray:
    """The garment's cloth pixels on the body posed by pose (J, 3, 3): (V, 3), the drape's start."""
    body_v = pose_body(scene.body, torch.from_numpy(np.array(pose, np.float32))[None])
    return embedded_points(body_v, scene.body.faces, scene.embedding)[0].numpy()


@pytest.fixture
def no_drape(monkeypatch, tiny_scene):
    """Generation with the module's scene and the skinned garment as every sample's (kept) drape."""
    def drape(scene, pose, index=0):
        return {"positions": skinned(scene, pose).astype(np.float32), "ok": True, "reason": "", "residual": 0.0,
                "residual_max": 0.0, "iterations": 0, "t_skin": 0.0, "t_drape": 0.0}

    monkeypatch.setattr(gen, "build_scene", lambda cfg: (dataclasses.replace(tiny_scene[0], sim=cfg.sim),
                                                         tiny_scene[1]))
    monkeypatch.setattr(gen, "drape_pose", drape)
    return tiny_scene[0]


def write_clips(folder, *sizes, seed=0):
    """Clips of the body's skeleton in the CMU dialect (the test_bvh writer), `sizes` frames each."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, n in enumerate(sizes):
        (folder / f"clip{k}.bvh").write_text(clip_text(random_poses(n, seed + k), seed=seed + k))
    return folder


def make(root, *extra):
    cfg = tiny_cfg(root / "data", "data.workers=1", "body.sampling.block_size=64", *extra)
    return load_dataset(gen.generate(cfg))


# ------------------------------------------------------------------------------------------- selection
def test_farthest_point_selection_covers_the_clip_where_a_stride_repeats_one_posture():
    """95 frames of one posture and 5 others: farthest-point takes all 6 postures in 6 picks, a stride of
    every 16th frame sees only the common one; the first k picks are the selection of k; the seed decides."""
    rng = np.random.default_rng(0)
    rare = random_poses(5, seed=3)
    clip = np.concatenate([np.tile(np.eye(3), (95, SKEL.num_joints, 1, 1)), rare])[rng.permutation(100)]
    pick = farthest_pose_selection(clip, 6, seed=1)
    distinct = {tuple(np.round(p, 6).ravel()) for p in clip[pick]}
    assert len(distinct) == 6
    assert len({tuple(np.round(p, 6).ravel()) for p in clip[::16]}) < 6
    assert np.array_equal(farthest_pose_selection(clip, 3, seed=1), pick[:3])
    assert np.array_equal(farthest_pose_selection(clip, 6, seed=1), pick)


# ---------------------------------------------------------------------------------------- generation
def test_poses_from_a_folder_of_clips_mixed_with_the_sampler_record_their_clip_and_frame(tmp_path, no_drape):
    clips = write_clips(tmp_path / "mocap", 7, 9)
    ds = make(tmp_path, f"data.poses={clips}", "data.num_samples=10", "data.poses_sampled_fraction=0.3")
    src = ds.manifest["pose_source"]
    assert src["clips"] == ["clip0.bvh", "clip1.bvh"]
    assert len(src["clip"]) == len(src["frame"]) == len(ds) == 10
    assert sorted(src["clip"]).count(SAMPLED) == 3
    # each clip row is its clip's frame, retargeted and its arms fitted to the body (pbc.motion.fit); each
    # sampler row is the D.3 sampler's pose of that index
    fit = motion_settings().clear_arms
    frames = {k: clear_clip_arms(clip_poses(clips / name, no_drape.body.skeleton)[0], no_drape.body, fit)[0]
              for k, name in enumerate(src["clips"])}
    settings = sampling_settings_from_config(tiny_cfg(tmp_path, "body.sampling.block_size=64").body.sampling)
    sampled = sample_poses(no_drape.body.skeleton, 3, 0, no_drape.body, settings)[0].numpy()
    for row, (c, f) in enumerate(zip(src["clip"], src["frame"], strict=True)):
        want = sampled[f] if c == SAMPLED else frames[c][f]
        np.testing.assert_allclose(ds.poses[row], want, atol=1e-6)
    assert ds.manifest["poses"]["selected"] == 7 and ds.manifest["poses"]["frames"] == 16
    assert 0 <= ds.manifest["poses"]["arms_raised"]["poses"] <= 7
    # the recorded training range is the range of what was trained on
    train = np.asarray(ds.poses)[ds.split("train")]
    np.testing.assert_allclose(training_pose_range(ds).deg[..., 0], swing_twist_angles(train).min(0), atol=1e-9)
    # reproducible from the seed: the same clips elsewhere make the same data
    again = make(tmp_path / "again", f"data.poses={write_clips(tmp_path / 'copy', 7, 9)}", "data.num_samples=10",
                 "data.poses_sampled_fraction=0.3")
    assert np.array_equal(again.poses, ds.poses) and again.manifest["pose_source"] == src
    # the data trains: its manifest keeps the fingerprint's pose_source beside each row's clip and frame
    cfg = tiny_cfg(tmp_path / "data", "data.workers=1", "body.sampling.block_size=64", f"data.poses={clips}",
                   "data.num_samples=10", "data.poses_sampled_fraction=0.3")
    assert src["files"].keys() == {"clip0.bvh", "clip1.bvh"} and gen.config_mismatch(cfg, ds.manifest) == []
    # a clip held out of training is not read, and the fingerprint says so
    held = gen.config_mismatch(tiny_cfg(tmp_path / "data", "body.sampling.block_size=64", f"data.poses={clips}",
                                        "data.num_samples=10", "data.poses_sampled_fraction=0.3",
                                        "data.poses_holdout=[clip1*]"), ds.manifest)
    assert any("clip1.bvh" in line for line in held)


def test_the_held_out_role_reads_only_the_clips_held_out_of_training(tmp_path, no_drape):
    clips = write_clips(tmp_path / "mocap", 7, 9)
    held = make(tmp_path, f"data.poses={clips}", "data.num_samples=4", "data.poses_holdout=[clip1*]",
                "data.poses_role=held_out")
    assert held.manifest["pose_source"]["clips"] == ["clip1.bvh"]
    assert set(held.manifest["pose_source"]["clip"]) == {0} and list(held.manifest["pose_source"]["files"]) == [
        "clip1.bvh"]
    # the same command again finds its finished data the same (the manifest's rows beside the fingerprint's keys)
    again = make(tmp_path, f"data.poses={clips}", "data.num_samples=4", "data.poses_holdout=[clip1*]",
                 "data.poses_role=held_out")
    assert np.array_equal(again.poses, held.poses)
    # the training role of the same settings reads the other clip only
    train = gen.fingerprint(tiny_cfg(tmp_path, f"data.poses={clips}", "data.poses_holdout=[clip1*]"), no_drape)
    assert list(train["pose_source"]["files"]) == ["clip0.bvh"]
    for role, holdout, msg in (("held_out", "[nothing*]", "holds out no clip"), ("test", "[clip1*]", "one of train")):
        with pytest.raises(ValueError, match=msg):
            gen.fingerprint(tiny_cfg(tmp_path, f"data.poses={clips}", f"data.poses_holdout={holdout}",
                                     f"data.poses_role={role}"), no_drape)


def test_default_keys_keep_the_fingerprint_and_clips_enter_it(tmp_path, no_drape):
    """data.poses null and data.mirror false: the fingerprint has no key of theirs (existing datasets keep
    theirs); a clip, the mirror or a sampler mode each adds one."""
    base = gen.fingerprint(tiny_cfg(tmp_path), no_drape)
    assert not {"pose_source", "mirror", "sampling_modes"} & set(base)
    clips = write_clips(tmp_path / "mocap", 4)
    with_clip = gen.fingerprint(tiny_cfg(tmp_path, f"data.poses={clips}"), no_drape)
    assert with_clip["pose_source"]["files"].keys() == {"clip0.bvh"}
    assert {k: v for k, v in with_clip.items() if k != "pose_source"} == base
    assert "mirror" in gen.fingerprint(tiny_cfg(tmp_path, "data.mirror=true"), no_drape)
    modes = gen.fingerprint(tiny_cfg(tmp_path, "body.sampling.modes.hanging_arms.fraction=0.5"), no_drape)
    assert modes["sampling_modes"]["hanging_arms"]["fraction"] == 0.5


def test_mirror_joins_training_after_the_split(tmp_path, no_drape):
    plain = make(tmp_path / "plain", "data.num_samples=12")
    ds = make(tmp_path / "mirrored", "data.num_samples=12", "data.mirror=true")
    n = len(plain)
    train, val, test = (plain.split(s) for s in ("train", "val", "test"))
    assert ds.manifest["counts"]["mirrored"] == len(train) and len(ds) == n + len(train)
    assert np.array_equal(ds.split("val"), val) and np.array_equal(ds.split("test"), test)
    mirrors = np.arange(n, len(ds))
    assert np.array_equal(ds.split("train"), np.concatenate([train, mirrors]))
    np.testing.assert_array_equal(ds.poses[:n], plain.poses)
    mm = mirror_map([no_drape.body], no_drape.garment.vertices.numpy(), no_drape.garment.faces.numpy(), 0.01,
                    plain.poses[:2])
    np.testing.assert_allclose(ds.poses[n:], mirror_poses(plain.poses[train], mm), atol=1e-6)
    # no held-out pose has its mirror image in the arrays: the mirror rows are the training rows' only
    held = mirror_poses(np.asarray(plain.poses)[np.concatenate([val, test])], mm).reshape(len(val) + len(test), -1)
    rows = np.asarray(ds.poses).reshape(len(ds), -1)
    assert np.abs(held[:, None] - rows[None]).max(-1).min() > 1e-3
    # the mirrored drape is the drape of the mirrored pose: here the skinned garment, to the body's meshing
    gap = np.linalg.norm(ds.verts[n:] - np.stack([skinned(no_drape, p) for p in ds.poses[n:]]), axis=-1)
    assert gap.mean() < 0.003 and gap.max() < 0.015, (gap.mean(), gap.max())


def test_mirror_maths_is_an_involution_that_swaps_the_arms(no_drape):
    body, g = no_drape.body, no_drape.garment
    poses = random_poses(4, seed=5).astype(np.float32)
    mm = mirror_map([body], g.vertices.numpy(), g.faces.numpy(), 0.01, poses)
    names = list(body.skeleton.names)
    assert names[mm.joints[names.index("l_arm")]] == "r_arm" and mm.joints[names.index("spine")] == names.index("spine")
    np.testing.assert_allclose(mirror_poses(mirror_poses(poses, mm), mm), poses, atol=1e-6)
    a, b = xzy_angles(poses), xzy_angles(mirror_poses(poses, mm))
    np.testing.assert_allclose(b[:, names.index("r_arm")], a[:, names.index("l_arm")] * [-1, -1, 1], atol=1e-3)
    np.testing.assert_allclose(b[:, names.index("spine")], a[:, names.index("spine")] * [1, -1, -1], atol=1e-3)
    verts = np.stack([skinned(no_drape, p) for p in poses])
    np.testing.assert_allclose(mirror_verts(mirror_verts(verts, mm), mm), verts, atol=1e-5)
    # the coarse shirt is symmetric vertex for vertex: its rest shape is its own mirror image
    rest = g.vertices.numpy()
    np.testing.assert_allclose(mirror_verts(rest[None], mm)[0], rest, atol=1e-6)
    assert not np.allclose(rest @ MIRROR, rest, atol=1e-3)


# ---------------------------------------------------------------------------------------------- bad input
CAMERA_CLIP = """HIERARCHY
ROOT Camera
{
  OFFSET 0.0 150.0 0.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Lens
  {
    OFFSET 0.0 0.0 10.0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.0 0.0 5.0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 150 0 0 0 0 10 20 30
1 150 0 0 0 0 15 25 35
"""


def refused(tmp_path, capsys, *overrides) -> str:
    """Run `pbc generate` in-process: exit 2, one line on stderr (returned), nothing written."""
    data = tmp_path / "data"
    code = exit_code(generate_main, ["data=tshirt_tiny", f"paths.data_dir={data}", "data.workers=1",
                                     "body.sampling.block_size=64",
                                     f"hydra.run.dir={tmp_path / 'hydra'}", *overrides])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("pbc generate: error: "), err
    assert not [p for p in data.rglob("*") if p.is_file()]
    return err[0]


def test_bad_pose_sources_are_one_line_naming_the_file_and_nothing_is_written(tmp_path, capsys, no_drape):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no clips here\n")
    assert "holds no clip" in refused(tmp_path, capsys, f"data.poses={empty}")
    no_frames = tmp_path / "still.bvh"
    no_frames.write_text(clip_text(random_poses(1)).replace("Frames: 1", "Frames: 0").rsplit("\n", 2)[0] + "\n")
    line = refused(tmp_path, capsys, f"data.poses={no_frames}")
    assert "still.bvh" in line and "no frames" in line
    foreign = tmp_path / "camera.bvh"  # a camera's motion: no joint of it drives the body
    foreign.write_text(CAMERA_CLIP)
    line = refused(tmp_path, capsys, f"data.poses={foreign}")
    assert "camera.bvh" in line and "would stay at rest" in line and "data.poses_joint_map" in line
    assert "data.poses_allow_rest=true" in line and "--" not in line
    wrong = tmp_path / "poses.npy"
    np.save(wrong, np.zeros((5, 3, 3)))
    line = refused(tmp_path, capsys, f"data.poses={wrong}")
    assert "poses.npy" in line and "(5, 3, 3)" in line
    still = tmp_path / "rest.npy"
    np.save(still, np.tile(np.eye(3), (4, SKEL.num_joints, 1, 1)))
    assert "rest.npy drives no body joint" in refused(tmp_path, capsys, f"data.poses={still}")
    few = write_clips(tmp_path / "few", 3)
    assert "3 frames in 1 clip(s), fewer than the 16" in refused(tmp_path, capsys, f"data.poses={few}")


def test_mirror_on_an_asymmetric_garment_is_refused_in_one_line(tmp_path, capsys, monkeypatch, no_drape, tiny_scene):
    g = no_drape.garment
    v = g.vertices.clone()
    v[v[:, 0] > 0.15, 0] += 0.03  # the left sleeve 3 cm longer
    lopsided = dataclasses.replace(no_drape, garment=dataclasses.replace(g, vertices=v))
    monkeypatch.setattr(gen, "build_scene", lambda cfg: (lopsided, tiny_scene[1]))
    line = refused(tmp_path, capsys, "data.mirror=true")
    assert "not left/right symmetric" in line and "data.mirror=false" in line and "mm off its surface" in line


# ------------------------------------------------------------------------------------------ sampler modes
def test_hanging_arms_mode_draws_its_share_and_leaves_the_default_poses_alone(body_cfg, body):
    from omegaconf import OmegaConf

    from pbc.sim.poses import SamplingSettings

    plain = sampling_settings_from_config(body_cfg.sampling)  # the shipped modes, all at fraction 0
    assert plain == SamplingSettings(block_size=plain.block_size) and plain.modes == ()
    on = OmegaConf.merge(body_cfg.sampling, {"modes": {"hanging_arms": {"fraction": 0.5}}})
    hanging = sampling_settings_from_config(on)
    a, _ = sample_poses(body.skeleton, 200, 3, body, plain)
    b, stats = sample_poses(body.skeleton, 200, 3, body, hanging)
    names = list(body.skeleton.names)
    z = xzy_angles(b.numpy())[:, [names.index("l_arm"), names.index("r_arm")], 2]
    low = -80 + 0.15 * 160  # the lowest 15% of the arms' altitude limits [-80, 80]
    share = (z <= low + 1e-3).all(1).mean()
    # half the candidates, less the many the arm-torso pruning removes (a hanging arm touches the torso)
    assert 0.15 < share < 0.75, share
    z_plain = xzy_angles(a.numpy())[:, [names.index("l_arm"), names.index("r_arm")], 2]
    assert (z_plain <= low).all(1).mean() < 0.05
    with pytest.raises(ValueError, match=r"sampling.modes.hanging_arms.range.l_arm.z=\[0.5, 0.2\]"):
        sampling_settings_from_config(OmegaConf.merge(on, {"modes": {"hanging_arms": {"range": {
            "l_arm": {"z": [0.5, 0.2]}}}}}))


def test_a_cone_mode_hangs_the_arms_tilted_any_way_and_twisted_in_its_range(body_cfg, body):
    from omegaconf import OmegaConf

    from pbc.sim.poses import modes_record

    cone = {"joints": ["l_arm", "r_arm"], "around": [0.0, -2.0, 0.0], "half_angle_deg": 30, "twist_deg": [-45, 45]}
    settings = sampling_settings_from_config(OmegaConf.merge(body_cfg.sampling, {"modes": {
        "swinging_arms": {"fraction": 1.0, "cone": cone}}}))
    poses, _ = sample_poses(body.skeleton, 80, 5, body, settings)
    frames = body.skeleton.frames().double().numpy()
    for joint in ("l_arm", "r_arm"):
        j = list(body.skeleton.names).index(joint)
        r = poses.numpy().astype(np.float64)[:, j]
        bone = np.einsum("ij,njk,k->ni", frames[j], r, [0.0, 1.0, 0.0])  # F R e_y: the bone in the root frame
        tilt = np.degrees(np.arccos(np.clip(-bone[:, 1], -1.0, 1.0)))  # from straight down
        assert tilt.max() <= 30.0 + 1e-6 and tilt.max() > 20.0  # inside the cone and spread over it
        forward = bone[:, 2]  # some swung forward, some back (tilted into the torso: pruned)
        assert (forward > 0.2).any() and (forward < -0.2).any()
        twist = swing_twist_angles(r)[:, 1]
        assert twist.min() >= -45.0 - 1e-6 and twist.max() <= 45.0 + 1e-6 and np.ptp(twist) > 45.0
    rec = modes_record(settings)["swinging_arms"]
    assert rec["cone"]["around"] == [0.0, -1.0, 0.0] and rec["cone"]["half_angle_deg"] == 30.0
    assert "clear" not in rec["cone"]
    # clear: an arm the cone tilts into the torso is raised out of it (as a clip's arms are), not pruned
    clearing = sampling_settings_from_config(OmegaConf.merge(body_cfg.sampling, {"block_size": 128, "modes": {
        "swinging_arms": {"fraction": 1.0, "cone": {**cone, "clear": {"step_deg": 5.0, "max_deg": 40.0}}}}}))
    raised, raised_stats = sample_poses(body.skeleton, 80, 5, body, clearing)
    _, pruned_stats = sample_poses(body.skeleton, 80, 5, body, settings)
    assert raised_stats["pruned"] < pruned_stats["pruned"] / 2
    # the raised arms hang lower than the pruned draws reach: the torso's surface, where clips hold them
    j = list(body.skeleton.names).index("l_arm")
    low = swing_twist_angles(raised.numpy().astype(np.float64)[:, j])[:, 2].min()
    assert low < swing_twist_angles(poses.numpy().astype(np.float64)[:, j])[:, 2].min() + 1e-9
    assert modes_record(clearing)["swinging_arms"]["cone"]["clear"] == {"step_deg": 5.0, "max_deg": 40.0}
    # a mode without a cone records none: data sets made before cones keep their fingerprint
    hanging = sampling_settings_from_config(OmegaConf.merge(body_cfg.sampling, {"modes": {
        "hanging_arms": {"fraction": 0.5}}}))
    assert "cone" not in modes_record(hanging)["hanging_arms"]
    for bad, match in (({"half_angle_deg": 0}, r"half_angle_deg=0.0: give the cone's half angle in \(0, 180\]"),
                       ({"around": [0, 0, 0]}, r"around=\[0.0, 0.0, 0.0\]: give the cone's axis"),
                       ({"twist_deg": [40, -40]}, r"twist_deg=\[40.0, -40.0\]"),
                       ({"joints": []}, r"joints: name the joints")):
        with pytest.raises(ValueError, match=rf"sampling.modes.swinging_arms.cone.{match}"):
            sampling_settings_from_config(OmegaConf.merge(body_cfg.sampling, {"modes": {
                "swinging_arms": {"fraction": 0.5, "cone": {**cone, **bad}}}}))


# ------------------------------------------------------------------------------------------- subsets
def test_a_subset_trains_on_the_first_poses_and_their_mirrors_and_tests_as_its_source(tmp_path, no_drape):
    """subset_dataset (a learning curve's sizes): the training split is the first n drapes and, with mirrors,
    exactly their mirror rows; validation and test are the source's; every consumer of "the training split"
    (here the recorded pose range) sees only the n; the source is not touched."""
    ds = make(tmp_path / "mirrored", "data.num_samples=12", "data.mirror=true")
    before = (ds.dir / "manifest.json").read_bytes()
    originals, mirror_of = originals_and_mirrors(ds)
    assert len(originals) == ds.manifest["counts"]["mirrored"] == len(mirror_of)
    sub = load_dataset(subset_dataset(ds, tmp_path / "sub3", 3))
    want = originals[:3] + [mirror_of[i] for i in originals[:3]]
    assert sub.split("train").tolist() == want
    for s in ("val", "test"):
        assert np.array_equal(sub.split(s), ds.split(s))
    np.testing.assert_array_equal(sub.verts, ds.verts)  # linked, not copied or changed
    mm = mirror_map([no_drape.body], no_drape.garment.vertices.numpy(), no_drape.garment.faces.numpy(), 0.01,
                    ds.poses[:2])
    np.testing.assert_allclose(sub.poses[[mirror_of[i] for i in originals[:3]]],
                               mirror_poses(ds.poses[originals[:3]], mm), atol=1e-6)
    assert sub.manifest["subset_of"]["train_poses"] == 3 and sub.manifest["subset_of"]["mirrors"]
    assert dataset_fingerprint(sub)["manifest_hash"] != dataset_fingerprint(ds)["manifest_hash"]
    plain = load_dataset(subset_dataset(ds, tmp_path / "sub3_plain", 3, mirrors=False))
    assert plain.split("train").tolist() == originals[:3]
    np.testing.assert_allclose(training_pose_range(plain).deg,
                               training_pose_range(dataclasses.replace(ds, manifest={
                                   **ds.manifest, "splits": {**ds.manifest["splits"], "train": originals[:3]}})).deg)
    assert (ds.dir / "manifest.json").read_bytes() == before


def test_a_subset_the_source_cannot_give_is_refused_before_anything_is_written(tmp_path, no_drape):
    ds = make(tmp_path / "plain", "data.num_samples=12")
    n = len(ds.split("train"))
    for bad, words in ((0, f"ask for 1..{n}"), (n + 1, f"has {n}")):
        with pytest.raises(ValueError, match=words):
            subset_dataset(ds, tmp_path / "bad", bad, mirrors=False)
    with pytest.raises(ValueError, match="data.mirror=true"):
        subset_dataset(ds, tmp_path / "bad", 2)
    with pytest.raises(ValueError, match="inside its source"):
        subset_dataset(ds, ds.dir / "sub", 2, mirrors=False)
    assert not (tmp_path / "bad").exists() and not (ds.dir / "sub").exists()
