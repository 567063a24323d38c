"""The drape on a real motion-capture frame (a CMU walk, arms hanging): it settles.

With the arms down, the mannequin's upper arm sinks into the torso, so the sleeve (which collides with
the arm only, D.6) and the side panel (torso only) are each held on the wrong side of the other. Style3D's
untangling force then pulls at a crossing it can never undo and the armpits chatter for good: every
such drape ran to sim.max_frames and was discarded as not converged. conf/sim/style3d.yaml turns that
force off; this test drapes the full shirt on one walk frame with and without it (and the soft shear of
before), and once more with the frame's arms fitted to the body, as pbc takes a clip: then it is kept.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from pbc.core.config import load_config
from pbc.data.generate import build_scene
from pbc.geometry.body.base import pose_body
from pbc.geometry.shrinkwrap import embedded_points
from pbc.motion.bvh import read_bvh
from pbc.motion.fit import clear_clip_arms
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, motion_settings, parse_frames
from pbc.sim.drape import check_garment_result, drape_garment

WALK = Path(__file__).resolve().parents[1] / "data" / "bvh" / "cmu_mb_02_01_walk.bvh"
FRAMES = 100  # the fix settles these frames in 59-74 (docs/results/real_motion_drapes); chatter never does


@pytest.fixture(scope="module")
def walk_frame():
    """The default data config's scene and the skinned start of the walk's first motion frame."""
    cfg = load_config(["data=tshirt_small", f"sim.max_frames={FRAMES}"])
    scene, _ = build_scene(cfg)
    bvh = read_bvh(WALK)
    pose = np.asarray(bvh_to_poses(bvh, scene.body.skeleton, choose_joint_map(bvh, "auto"), parse_frames("1:2")).poses)
    posed = pose_body(scene.body, torch.from_numpy(pose).float())
    start = embedded_points(posed, scene.body.faces, scene.embedding)[0].numpy()
    return cfg, scene, start, posed[0].numpy()


def test_hanging_arms_settle_without_untangling(walk_frame):
    cfg, scene, start, body_vertices = walk_frame
    assert float(cfg.sim.self_collision_stiffness.untangle) == 0.0
    new = drape_garment(scene.garment, start, body_vertices, scene.body, scene.embedding, cfg.sim)
    assert new.converged and new.iterations < FRAMES, (new.iterations, new.residual)
    assert np.isfinite(new.positions).all()

    old_cfg = load_config(["data=tshirt_small", f"sim.max_frames={FRAMES}", "sim.fps=20",
                           "sim.self_collision_stiffness.untangle=1.0", "sim.stretch_ke=[100.0,100.0,10.0]"])
    old = drape_garment(scene.garment, start, body_vertices, scene.body, scene.embedding, old_cfg.sim)
    # the chatter: 5% of the vertices still move faster than the tolerance after every frame
    assert not old.converged and old.residual > 2 * float(cfg.sim.tolerance), (old.iterations, old.residual)


def test_the_walk_frame_with_its_arms_fitted_to_the_body_is_kept(walk_frame):
    """The frame as every door takes a clip (its arm raised out of the torso, pbc.motion.fit) passes the D.6
    check with the config's drape; as retargeted, the arm inside the torso pulls the cloth at the shoulder past
    twice its pattern area (docs/results/real_motion_drapes: 0 of 18 kept that way, 18 of 18 fitted)."""
    cfg, scene, _, _ = walk_frame
    bvh = read_bvh(WALK)
    pose = np.asarray(bvh_to_poses(bvh, scene.body.skeleton, choose_joint_map(bvh, "auto"), parse_frames("1:2")).poses)
    fitted, raised = clear_clip_arms(pose, scene.body, motion_settings().clear_arms)
    assert raised.max() > 0
    posed = pose_body(scene.body, torch.from_numpy(fitted).float())
    start = embedded_points(posed, scene.body.faces, scene.embedding)[0].numpy()
    res = drape_garment(scene.garment, start, posed[0].numpy(), scene.body, scene.embedding, cfg.sim)
    assert check_garment_result(res, scene.garment, cfg.sim) == (True, "")


def test_a_sleeve_fold_snapping_through_at_the_stop_is_judged_once_it_has_settled(walk_frame):
    """Walk frame 5: where the speed rule first holds, a sleeve's underside fold is mid-snap (one face at 0.14 of
    its pattern area, still moving) and the drape would be discarded; run on (sim.fold_frames) until it holds
    again with every face inside the limits, the fold has opened and the drape is kept
    (docs/results/real_motion_drapes). At 20 frames a second, where it was found: at 10 (the config) this frame's
    fold has opened by the first stop."""
    _, scene, _, _ = walk_frame
    cfg = load_config(["data=tshirt_small", f"sim.max_frames={FRAMES}", "sim.fps=20"])
    bvh = read_bvh(WALK)
    pose = np.asarray(bvh_to_poses(bvh, scene.body.skeleton, choose_joint_map(bvh, "auto"), parse_frames("5:6")).poses)
    fitted, _ = clear_clip_arms(pose, scene.body, motion_settings().clear_arms)
    posed = pose_body(scene.body, torch.from_numpy(fitted).float())
    start = embedded_points(posed, scene.body.faces, scene.embedding)[0].numpy()
    args = (scene.garment, start, posed[0].numpy(), scene.body, scene.embedding)
    at_first_stop = load_config(["data=tshirt_small", f"sim.max_frames={FRAMES}", "sim.fps=20",
                                 "sim.fold_frames=0"]).sim
    early = drape_garment(*args, at_first_stop)
    assert check_garment_result(early, scene.garment, at_first_stop) == (False, "area_compressed")
    late = drape_garment(*args, cfg.sim)
    assert check_garment_result(late, scene.garment, cfg.sim) == (True, "")
    assert early.iterations < late.iterations <= early.iterations + int(cfg.sim.fold_frames)
