"""A retargeted clip fitted to the body it drives: arms that pass through the torso raised out of it.

Retargeting copies joint rotations, so a clip recorded on a slim actor hangs a broader body's arms inside its
torso. The D.3 sampler never draws such a pose (it prunes them); a drape of one pulls the cloth between the
overlapping arm and torso apart, and a model trained on sampled poses never saw one.
"""

from __future__ import annotations

import numpy as np
import torch

from pbc.geometry.body.base import Body
from pbc.sim.poses import SamplingSettings, arm_probes_if_any, clear_arms


def clear_clip_arms(poses: np.ndarray, body: Body, settings) -> tuple[np.ndarray, np.ndarray]:
    """poses (N, J, 3, 3) of `body`'s skeleton -> (the poses with each arm inside the torso raised out of it,
    (N, 2) degrees each arm was raised, left then right). settings: conf/motion/sequence.yaml `clear_arms`
    (step_deg, max_deg; max_deg 0 returns the poses unchanged). Poses of a body without both arm joints, or
    without enough arm vertices to probe, are returned as they are. The probes are the sampler's defaults (53
    an arm, 10 cm from the shoulder, conf/body sampling)."""
    poses = np.asarray(poses)
    none = np.zeros((len(poses), 2))
    if float(settings.max_deg) <= 0 or len(poses) == 0:
        return poses, none
    probe = SamplingSettings()
    probes = arm_probes_if_any(body, probe)
    if probes is None:  # a body without skinned arms to probe (a stand-in): nothing to fit
        return poses, none
    rot = torch.from_numpy(np.ascontiguousarray(poses, np.float32))
    with torch.no_grad():
        out, turned = clear_arms(body, rot, probe, float(settings.step_deg), float(settings.max_deg), probes)
    moved = turned.numpy().any(1)
    cleared = poses.copy()  # frames left alone keep their exact (float64) rotations
    cleared[moved] = out.numpy()[moved]
    return cleared, turned.numpy().astype(np.float64)


def cleared_note(turned: np.ndarray) -> str | None:
    """One line saying what `clear_clip_arms` did to a clip's frames (None when it raised no arm)."""
    moved = (turned > 0).any(1)
    if not moved.any():
        return None
    return (f"arms raised out of the torso in {int(moved.sum())} of {len(turned)} frames, by "
            f"{turned[turned > 0].min():.0f}-{turned.max():.0f} degrees (the clip's actor is slimmer than this body; "
            "conf/motion/sequence.yaml clear_arms)")
