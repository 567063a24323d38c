"""Bodies behind one door: ``body_from_config(cfg.body)`` builds the kind the config names (``BUILDERS``).

The body type and its operations are in ``base``; one module per kind (``mannequin``, ``anny``); the
skeleton, measurements and sculpted shape edits each have their own module.
"""

from __future__ import annotations

from pbc.geometry.body.anny import build_anny_body
from pbc.geometry.body.base import Body
from pbc.geometry.body.joint_limits import with_limits_file
from pbc.geometry.body.mannequin import build_mannequin

BUILDERS = {"mannequin": build_mannequin, "anny": build_anny_body}


def body_from_config(cfg) -> Body:
    """The body of a body config node (cfg.body); deterministic for a config. With ``limits_file`` its joints take
    that file's limits (pbc.geometry.body.joint_limits); without it the config is built as it is."""
    kind = str(cfg.get("kind", "mannequin"))
    if kind not in BUILDERS:
        raise ValueError(f"body.kind={kind!r} is not a body pbc builds; use body={' or body='.join(BUILDERS)}")
    return BUILDERS[kind](with_limits_file(cfg))
