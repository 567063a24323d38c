"""Which joint of a motion clip drives which body joint, without a table: names normalised, then read as the
skeleton's structure (conf/motion/dialects.yaml).

Names alone mislead across dialects: CMU's 3ds Max release calls the upper arm `LeftShoulder`, where Mixamo's
`LeftShoulder` is the clavicle; Mixamo's `LeftLeg` is the shin; Blender's Rigify calls the neck `spine.004`.
So a name only anchors a chain. A limb is the subtree of sided joints hanging off the trunk; its main chain
runs from where it attaches to its end (through the largest child at each branch, twist and roll helpers
skipped). On an arm's chain the joint named forearm (else the parent of the joint named hand, else the
middle of the two longest consecutive links) fixes the rest: the upper arm is its parent, the clavicle the
parent of that, the hand its child. Legs likewise from the shin (else the foot). The trunk is read from the
structure only: the spine is the chain from the root to the joint the arms hang from, the neck the joints
from there to the head, and they are spread over the body's own spine and neck joints, lowest on lowest
and highest on highest. Each match keeps its reason (`JointMap.why`), which `pbc motion inspect` prints.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from pbc.core.paths import CONF_DIR
from pbc.motion.bvh import Bvh

DIALECTS_FILE = CONF_DIR / "motion" / "dialects.yaml"
_WORDS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")


@dataclass(frozen=True)
class JointMap:
    """A joint map: which clip joint drives each body joint. `path` is the table's file (None: matched by
    `match_joints`), `why` the reason per body joint, `toward` the clip joint whose position gives a
    mapped joint's bone direction when the body joint's own child is not mapped (e.g. the upper arm of a
    body without forearms points at the clip's forearm)."""

    name: str
    path: Path | None
    joints: dict[str, str]  # body joint -> clip joint (null rows dropped)
    bones: tuple[str, ...]  # every bone of the dialect
    why: dict[str, str] = field(default_factory=dict)
    toward: dict[str, str] = field(default_factory=dict)
    dialect: str = ""
    frame_time: tuple[float, float] | None = None  # (the header's, the capture's): a converter's default rate
    units: str | None = None  # the dialect's length unit (conf/motion/sequence.yaml units), None: unknown

    def known(self) -> set[str]:
        return set(self.bones) | set(self.joints.values())


@functools.lru_cache(maxsize=1)
def dialect_settings():
    """conf/motion/dialects.yaml, read once a process (every joint name asks for it), read-only."""
    cfg = OmegaConf.load(DIALECTS_FILE)
    OmegaConf.set_readonly(cfg, True)
    return cfg


def split_name(name: str, cfg=None) -> tuple[str | None, str, str]:
    """A clip joint's name -> (side "l" / "r" / None, base name, digits): 'mixamorig7:LeftForeArm' ->
    ('l', 'forearm', ''); 'UpperArm_L' -> ('l', 'upperarm', ''); 'Bip01 R Calf' -> ('r', 'calf', '');
    'spine.004' -> (None, 'spine', '004')."""
    cfg = cfg or dialect_settings()
    bare = name.rsplit(":", 1)[-1]
    for prefix in sorted(cfg.prefixes, key=len, reverse=True):
        if bare.lower().startswith(prefix) and len(bare) > len(prefix) and not bare[len(prefix)].isalnum():
            bare = bare[len(prefix):]
            break
    low = [w.lower() for w in _WORDS.findall(bare)]
    side = None
    for s, spellings in cfg.sides.items():
        for pos in (0, -1):
            if len(low) > 1 and low[pos] in spellings and side is None:
                side = str(s)
                low = low[1:] if pos == 0 else low[:-1]
    base = "".join(w for w in low if not w.isdigit())
    digits = "".join(w for w in low if w.isdigit())
    return side, base, digits


def guess_dialect(names, cfg=None) -> str:
    """The first dialect of conf/motion/dialects.yaml whose pattern matches one of `names`, else 'unknown'."""
    cfg = cfg or dialect_settings()
    for d in cfg.dialects:
        if any(re.search(str(d.pattern), n) for n in names):
            return str(d.name)
    return "unknown"


def dialect_units(dialect: str, cfg=None) -> str | None:
    """The length unit conf/motion/dialects.yaml gives `dialect` (None: none given)."""
    cfg = cfg or dialect_settings()
    return next((str(d.units) for d in cfg.dialects if str(d.name) == dialect and d.get("units")), None)


def _children(bvh: Bvh) -> list[list[int]]:
    kids: list[list[int]] = [[] for _ in bvh.joints]
    for j, jt in enumerate(bvh.joints):
        if jt.parent >= 0:
            kids[jt.parent].append(j)
    return kids


def _subtree(kids, j) -> list[int]:
    out, stack = [], [j]
    while stack:
        k = stack.pop()
        out.append(k)
        stack.extend(kids[k])
    return out


def _spread(n_file: int, n_body: int, single: int) -> list[tuple[int, int]]:
    """(file index, body index) pairs spreading n_file joints over n_body, lowest on lowest, highest on
    highest; one file joint goes on body joint `single` (the spine's: the highest, where the arms hang; the
    neck's: the lowest, where the neck leaves the chest)."""
    if n_file == 0 or n_body == 0:
        return []
    if n_file == 1:
        return [(0, single % n_body)]
    if n_file >= n_body:
        return [(int(round(b * (n_file - 1) / max(n_body - 1, 1))), b) for b in range(n_body)]
    return [(f, int(round(f * (n_body - 1) / (n_file - 1)))) for f in range(n_file)]


def match_joints(bvh: Bvh, rest: np.ndarray | None = None) -> JointMap:
    """Match the clip's joints to pbc's body joints (conf/motion/dialects.yaml's `body`) by name and structure.
    rest (J, 3): the positions to measure links with (default: the file's rest). Body joints it cannot
    match are left out (bvh_to_poses says which the body needs)."""
    cfg = dialect_settings()
    rest = bvh.rest_positions() if rest is None else rest
    names = bvh.names
    parts = [split_name(n, cfg) for n in names]
    kids = _children(bvh)
    helpers = set(cfg.helpers)
    syn = {k: set(v) for k, v in cfg.synonyms.items()}

    def is_helper(j):
        return any(h in parts[j][1] for h in helpers) and j != 0

    # the trunk: the head (a joint named head, the shallowest), the chain from the root to it
    depth = [0] * len(names)
    for j, jt in enumerate(bvh.joints):
        depth[j] = 0 if jt.parent < 0 else depth[jt.parent] + 1
    heads = [j for j, (s, b, _) in enumerate(parts) if s is None and b in syn["head"]]
    if heads:
        head = min(heads, key=lambda j: depth[j])
    else:  # the deepest joint reached through unsided joints only (Rigify's spine.006)
        unsided = [j for j in range(len(names)) if all(parts[k][0] is None for k in ancestors(bvh, j))]
        head = max(unsided, key=lambda j: (depth[j], -j))
    centre = list(reversed(ancestors(bvh, head)))  # root ... head

    # the limbs: subtrees of sided joints whose parent is unsided, by side; arm or leg by their names, else
    # by where they hang (from the root's level: a leg)
    limbs: dict[tuple[str, str], list[int]] = {}
    for j, (side, _, _) in enumerate(parts):
        par = bvh.joints[j].parent
        if side is None or par < 0 or parts[par][0] == side:
            continue
        if par in centre and centre.index(par) >= centre.index(head):
            continue  # eyes, ears: hang from the head
        tree = _subtree(kids, j)
        words = {parts[k][1] for k in tree}
        arm = len(words & syn["arm_words"]) > len(words & syn["leg_words"])
        leg = len(words & syn["leg_words"]) > len(words & syn["arm_words"])
        kind = "arm" if arm else "leg" if leg else ("leg" if par == 0 or par not in centre[:-1] else "arm")
        if len(tree) > len(limbs.get((side, kind), ())):
            limbs[(side, kind)] = [j] + [k for k in tree if k != j]

    joints: dict[str, str] = {}
    why: dict[str, str] = {}
    toward: dict[str, str] = {}
    body = cfg.body

    def chain_of(first: int) -> list[int]:
        chain, j = [first], first
        while kids[j]:
            j = max(kids[j], key=lambda k: (len(_subtree(kids, k)), -k))
            chain.append(j)
        return [k for k in chain if not is_helper(k)]

    def link(chain, i) -> float:
        if i + 1 < len(chain):
            return float(np.linalg.norm(rest[chain[i + 1]] - rest[chain[i]]))
        end = bvh.joints[chain[i]].end
        return 0.0 if end is None else float(np.linalg.norm(end))

    for (side, kind), tree in sorted(limbs.items()):
        chain = chain_of(tree[0])
        mid_role, end_role = ("forearm", "hand") if kind == "arm" else ("shin", "foot")
        top_role = "upper_arm" if kind == "arm" else "thigh"
        named_mid = [i for i, k in enumerate(chain) if parts[k][1] in syn[mid_role]]
        named_end = [i for i, k in enumerate(chain) if parts[k][1] in syn[end_role]]
        if named_mid and named_mid[0] >= 1:
            k, reason = named_mid[0], f"named {mid_role.replace('_', ' ')}"
        elif named_end and named_end[0] >= 2:
            k, reason = named_end[0] - 1, f"the parent of the {end_role} (named {end_role})"
        elif len(chain) >= 3:  # no telling name: the middle of the two longest consecutive links
            sums = [link(chain, i) + link(chain, i + 1) for i in range(len(chain) - 1)]
            k, reason = int(np.argmax(sums)) + 1, "the two longest links of the chain"
            k = max(k, 1)
        else:
            continue
        roles = {top_role: k - 1, mid_role: k}
        if k + 1 < len(chain):
            roles[end_role] = k + 1
        if kind == "arm" and k >= 2:
            roles["clavicle"] = k - 2
        limb = body.limbs[side]
        for role, i in roles.items():
            j = chain[i]
            joints[str(limb[role])] = names[j]
            why[str(limb[role])] = (reason if role == mid_role else
                                    f"{'parent' if i == k - 1 else 'grandparent' if i == k - 2 else 'child'} of "
                                    f"{names[chain[k]]} ({reason}) on the {'left' if side == 'l' else 'right'} "
                                    f"{kind}'s chain")
            if i + 1 < len(chain):
                toward[names[j]] = names[chain[i + 1]]

    # the trunk: the pelvis is where the legs and the spine meet (the clip's root, or below it a joint like
    # Bandai Namco's Hips under a joint_Root on the floor); the spine runs from above it to the joint the arms
    # hang from; the neck from there to the head
    leg_roots = [bvh.joints[t[0]].parent for (_, kind), t in limbs.items() if kind == "leg"]
    pelvis = lowest_common_ancestor(bvh, [*leg_roots, head]) if leg_roots else 0
    base = centre.index(pelvis) if pelvis in centre else 0
    arm_roots = [bvh.joints[t[0]].parent for (_, kind), t in limbs.items() if kind == "arm"]
    on_centre = [centre.index(a) for a in arm_roots if a in centre and centre.index(a) > base]
    if on_centre:
        top = max(on_centre)
        spine = centre[base + 1:top + 1]
        neck = centre[top + 1:-1]
        top_reason = f"the arms hang from {names[centre[top]]}"
    else:  # no arms: the joints named neck start the neck
        necks = [i for i, j in enumerate(centre) if parts[j][1].startswith("neck") and i > base]
        cut = necks[0] if necks else len(centre) - 1
        spine, neck = centre[base + 1:cut], centre[cut:-1]
        top_reason = "no arms: the spine ends below the first joint named neck"
    for what, file_chain, single in (("spine", spine, -1), ("neck", neck, 0)):
        body_chain = list(body[what])
        for f, b in _spread(len(file_chain), len(body_chain), single):
            j = file_chain[f]
            joints[body_chain[b]] = names[j]
            why[body_chain[b]] = (f"{what} joint {f + 1} of {len(file_chain)} from the root to the head "
                                  f"({top_reason})")
    if head != 0:
        joints[str(body.head)] = names[head]
        why[str(body.head)] = "named head" if heads else "the end of the trunk's chain"
    for i, j in enumerate(centre[:-1]):
        toward.setdefault(names[j], names[centre[i + 1]])
    dialect = guess_dialect(names, cfg)
    return JointMap("auto", None, joints, tuple(names), why, toward, dialect, units=dialect_units(dialect, cfg))


def lowest_common_ancestor(bvh: Bvh, joints: list[int]) -> int:
    """The deepest joint that is `joints`' every member or an ancestor of it (the root for none)."""
    if not joints:
        return 0
    common = set(ancestors(bvh, joints[0]))
    for j in joints[1:]:
        common &= set(ancestors(bvh, j))
    return next(k for k in ancestors(bvh, joints[0]) if k in common)


def ancestors(bvh: Bvh, j: int) -> list[int]:
    """j, its parent, ..., the root (indices into bvh.joints)."""
    out = [j]
    while bvh.joints[out[-1]].parent >= 0:
        out.append(bvh.joints[out[-1]].parent)
    return out
