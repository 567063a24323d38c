"""A tiny hand-made body with legs, for unit tests of the legs' pose pruning and the lower-body garments: the
mannequin of conf/body/mannequin.yaml with hips, knees and ankles added (capsule thighs, shins and feet, part of
the torso as on Anny), with Anny's leg frames and limits, meshed coarsely. Nothing here is shipped."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from omegaconf import OmegaConf

from pbc.geometry.body.base import Body
from pbc.geometry.body.mannequin import build_mannequin

MANNEQUIN = Path(__file__).resolve().parents[2] / "conf" / "body" / "mannequin.yaml"
ANNY = Path(__file__).resolve().parents[2] / "conf" / "body" / "anny.yaml"
VOXEL = 0.03  # m: coarse, like the unit tier's mannequin
HIP_X, HIP_Y, KNEE_Y, ANKLE_Y = 0.09, -0.10, -0.52, -0.92
LEGS = {"left_leg": ["l_hip", "l_knee", "l_ankle"], "right_leg": ["r_hip", "r_knee", "r_ankle"]}


def legged_body_config():
    """The mannequin config with legs (a fresh copy each call)."""
    cfg = OmegaConf.load(MANNEQUIN)
    anny = OmegaConf.load(ANNY)
    cfg.mesh.voxel_size = VOXEL
    cfg.frames.left_leg = anny.frames.left_leg
    cfg.frames.right_leg = anny.frames.right_leg
    limits = {str(j.name): j.limits for j in anny.joints}
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        x = sgn * HIP_X
        frame = "left_leg" if side == "l" else "right_leg"
        cfg.joints.append({"name": f"{side}_hip", "parent": "root", "head": [x, HIP_Y, -0.01], "frame": frame,
                           "limits": limits[f"{side}_hip"]})
        cfg.joints.append({"name": f"{side}_knee", "parent": f"{side}_hip", "head": [x, KNEE_Y, 0.0],
                           "frame": frame, "limits": limits[f"{side}_knee"]})
        cfg.joints.append({"name": f"{side}_ankle", "parent": f"{side}_knee", "head": [x, ANKLE_Y, -0.01],
                           "frame": frame, "limits": limits[f"{side}_ankle"]})
        cfg.primitives.append({"name": f"{side}_thigh", "bone": f"{side}_hip", "kind": "capsule",
                               "a": [x, HIP_Y, -0.01], "b": [x, KNEE_Y, 0.0], "radius": [0.085, 0.055],
                               "parts": ["torso"]})
        cfg.primitives.append({"name": f"{side}_shin", "bone": f"{side}_knee", "kind": "capsule",
                               "a": [x, KNEE_Y, 0.0], "b": [x, ANKLE_Y, -0.01], "radius": [0.055, 0.04],
                               "parts": ["torso"]})
        cfg.primitives.append({"name": f"{side}_foot", "bone": f"{side}_ankle", "kind": "capsule",
                               "a": [x, ANKLE_Y - 0.03, -0.01], "b": [x, ANKLE_Y - 0.04, 0.14],
                               "radius": [0.04, 0.03], "parts": ["torso"]})
    cfg.sampling.update({**LEGS, "leg_torso_joints": ["lower_back", "spine", "spine1"]})
    return cfg


@lru_cache(maxsize=1)
def legged_body() -> Body:
    """The legged mannequin, built once per process (about a second); treat as read-only."""
    return build_mannequin(legged_body_config())
