"""The one door from a body config to a Body (conf/body/: `kind` mannequin, the default, or anny).

Every stage (shrink-wrap, pose sampling and pruning, the drape's colliders, skinning of targets, predict,
edit, previews) gets the same Body type: skeleton (names, parents, rest heads, rest frames, limits), rest
mesh, skinning weights (Vb, J+1), part masks, and the inside test (body_sdf over its primitives); posing
is pose_body. None of them asks which kind of body it has.
"""

from __future__ import annotations

from pbc.geometry.anny_body import build_anny_body
from pbc.geometry.body import Body, build_body

BUILDERS = {"mannequin": build_body, "anny": build_anny_body}


def body_from_config(cfg) -> Body:
    """The body of a body config node (cfg.body); deterministic for a config."""
    kind = str(cfg.get("kind", "mannequin"))
    if kind not in BUILDERS:
        raise ValueError(f"body.kind={kind!r} is not a body pbc builds; use body={' or body='.join(BUILDERS)}")
    return BUILDERS[kind](cfg)
