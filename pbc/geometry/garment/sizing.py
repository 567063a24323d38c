"""Procedural garments sized to the body they are worn on (`garment.size_to_body.enabled`).

The shirt's and the tie's lengths and placements in conf/garment/ were made for the mannequin. A garment
config with `size_to_body.enabled: true` gets them from the chosen body's own measurements instead
(pbc.geometry.body.measure), so the same preset fits Anny at any phenotype. Each rule keeps the garment's
relation to the body the mannequin values encode: a girth is taken from the body, a position moves with the
body landmark it sits on, a length scales with the body length it spans. The mannequin's own measurements
are the reference (`size_to_body.reference`), so sizing the mannequin changes each value by at most the
measuring rounding.
"""

from __future__ import annotations

import math

from omegaconf import DictConfig, OmegaConf

from pbc.geometry.body.base import Body
from pbc.geometry.body.measure import girth, measurements, torso_mesh
from pbc.geometry.garment.base import garment_kind

UPPER_ARM_FALLBACK = 0.29  # m: the upper arm's length on a body without a forearm joint (the mannequin's)
NECK_SECTION_ABOVE = 0.05  # m above the neck joint: the section is the neck alone (the shoulders end below it)


def landmarks(body: Body) -> dict[str, float]:
    """The measurements the sizing rules read (m, root frame): the chest girth, the shoulder height (arm
    joints' mean y), their mean z, the hips' height, the neck joint's y and z, and the neck's radius (the
    girth of the neck's section NECK_SECTION_ABOVE above the neck joint over 2 pi)."""
    m = measurements(body)
    sk = body.skeleton
    arms = sk.rest_heads[[sk.index("l_arm"), sk.index("r_arm")]]
    neck = sk.rest_heads[sk.index("neck")]
    out = {"chest": m["chest"], "shoulder_height": float(arms[:, 1].mean()), "arm_z": float(arms[:, 2].mean()),
           "hips_at": m["hips_at"], "neck_y": float(neck[1]), "neck_z": float(neck[2]),
           "neck_radius": girth(torso_mesh(body), float(neck[1]) + NECK_SECTION_ABOVE) / (2.0 * math.pi),
           "arm_radius": upper_arm_radius(body)}
    return out


def upper_arm_radius(body: Body, side: str = "l") -> float:
    """Median distance (m) to the upper arm's axis of the vertices the arm joint dominates, over the axis's
    first quarter from the shoulder (where the sleeve's opening sits). The axis runs from the arm joint to
    the forearm joint, or along the rest arm for a body without forearms (the mannequin)."""
    sk = body.skeleton
    head = sk.rest_heads[sk.index(f"{side}_arm")].double()
    if f"{side}_forearm" in sk.names:
        axis = sk.rest_heads[sk.index(f"{side}_forearm")].double() - head
    else:
        axis = sk.frames()[sk.index(f"{side}_arm")][:, 1].double() * UPPER_ARM_FALLBACK
    length = axis.norm()
    axis = axis / length
    v = body.vertices.double()[body.weights[:, 1 + sk.index(f"{side}_arm")] > 0.5] - head
    t = v @ axis
    near = (t > 0) & (t < 0.25 * length)
    if not bool(near.any()):
        raise ValueError(f"sizing: no vertices along the first quarter of joint {side}_arm; the body's arm "
                         "weights are not where its skeleton puts the arm")
    return float((v[near] - t[near, None] * axis).norm(dim=1).median())


def _require(ref: DictConfig, keys) -> None:
    missing = [k for k in keys if k not in ref]
    if missing:
        raise ValueError(f"garment.size_to_body.reference lacks {missing}: give the reference body's values "
                         "(`pbc body show body=mannequin` prints them)")


def size_tshirt(gcfg: DictConfig, m: dict[str, float]) -> dict:
    """The shirt keys set from a body's landmarks `m`: chest girth from the body; the sleeves on its arm
    axis, their opening scaled with the upper arm's radius; the torso length scaled with the shoulder-to-hips
    length."""
    ref = gcfg.size_to_body.reference
    _require(ref, ("chest", "shoulder_height", "arm_z", "hips_at", "arm_radius"))
    span = (m["shoulder_height"] - m["hips_at"]) / (float(ref.shoulder_height) - float(ref.hips_at))
    return {
        "chest_girth": float(gcfg.chest_girth) * m["chest"] / float(ref.chest),
        "shoulder_height": float(gcfg.shoulder_height) + m["shoulder_height"] - float(ref.shoulder_height),
        "center_z": float(gcfg.center_z) + m["arm_z"] - float(ref.arm_z),
        "torso_length": float(gcfg.torso_length) * span,
        "sleeve_opening": float(gcfg.sleeve_opening) * m["arm_radius"] / float(ref.arm_radius),
    }


def size_necktie(gcfg: DictConfig, m: dict[str, float]) -> dict:
    """The tie keys set from a body's landmarks: the collar and the band follow the neck joint and the neck's
    radius, the blade's front the chest girth (a rounder chest pushes it forward)."""
    ref = gcfg.size_to_body.reference
    _require(ref, ("chest", "neck_y", "neck_z", "neck_radius"))
    radius = m["neck_radius"]
    return {
        "collar_height": float(gcfg.collar_height) + m["neck_y"] - float(ref.neck_y),
        "neck_center_z": float(gcfg.neck_center_z) + m["neck_z"] - float(ref.neck_z),
        "neck_radius": float(gcfg.neck_radius) + radius - float(ref.neck_radius),
        "neck_girth": float(gcfg.neck_girth) * radius / float(ref.neck_radius),
        "front_z": float(gcfg.front_z) + m["neck_z"] - float(ref.neck_z)
        + (m["chest"] - float(ref.chest)) / (2.0 * math.pi),
    }


RULES = {"tshirt": size_tshirt, "necktie": size_necktie}


def sized_config(gcfg: DictConfig, body: Body) -> DictConfig:
    """`gcfg` with its size keys taken from `body` (a copy; `gcfg` is unchanged). The committed cage file was
    made for the unsized pattern, so the sized one gets its cage from the garment's own cage rule."""
    kind = garment_kind(gcfg)
    if kind not in RULES:
        raise ValueError(f"garment.size_to_body.enabled=true sizes the procedural garments "
                         f"({', '.join(RULES)}), not garment.kind={kind!r}; set it to false")
    sized = RULES[kind](gcfg, landmarks(body))
    out = OmegaConf.merge(gcfg, sized)
    if kind == "tshirt":
        out.cage = None
    return out


def is_sized_to_body(gcfg: DictConfig) -> bool:
    """Whether building this garment needs the body (its sizes come from it)."""
    # `fit_to_body`: the key's name in configs recorded before it was renamed (sweep dirs of older runs)
    size = gcfg.get("size_to_body") or gcfg.get("fit_to_body")
    return bool(size is not None and size.get("enabled", False))
