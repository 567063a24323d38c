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

Names are then checked against the skeleton's shape, read with no name (`skeleton_structure`): the trunk is
the chain from the root to the head that the paired branches leave (the legs at the pelvis, the arms at the
chest); a branch is one of two sibling subtrees alike in depth and reach. An automatic match never drives a
body spine, neck or head joint with a joint of such a branch, nor a body limb joint with a joint of the
trunk, nor a body arm with a branch leaving the trunk no higher than the legs' (`check_structure`); a match
that would, or a clip whose names tell nothing (no side, no head), is refused in one line naming the file
and giving the `--bvh-map` table to write with the clip's own joints, as its skeleton chains them.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from pbc.core.paths import CONF_DIR
from pbc.core.validate import check_motion_settings
from pbc.motion.bvh import Bvh, BvhError

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
    """conf/motion/dialects.yaml, read once a process (every joint name asks for it), read-only; its numbers
    held to conf/bounds.yaml (one ValueError naming the file, the key and the range)."""
    cfg = OmegaConf.load(DIALECTS_FILE)
    check_motion_settings("dialects", cfg, DIALECTS_FILE)
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


@dataclass(frozen=True)
class Structure:
    """A clip's skeleton read from its shape alone (no name plays a part; the thresholds are
    conf/motion/dialects.yaml's `structure`). `trunk`: the chain from the root to the head's end that the
    branches leave (joint indices, root first); it ends where its next joint cannot be told (no child, or several
    unpaired children none of which alone carries a pair of limbs). `branches`: each subtree leaving the trunk as
    one of a mirrored pair (two sibling subtrees of one depth in joints and of one reach, within
    pair_reach_ratio: the legs, the arms, the eyes), its joints with the one hanging off the trunk first, and
    `attach` the trunk position it leaves from. `limbs`: how many of those pairs are limbs (limb_depth joints
    deep, reaching limb_reach of the longest path down from the first joint with several children). A joint on
    neither (an unpaired side branch, what lies past the trunk's end) is not classified."""

    trunk: tuple[int, ...]
    branches: tuple[tuple[int, ...], ...]
    attach: tuple[int, ...]  # per branch: its position along `trunk`
    limbs: int

    @property
    def clear(self) -> bool:
        """The trunk carries a pair of limbs: the shape tells the trunk from the arms and legs."""
        return self.limbs > 0

    def place(self, j: int) -> tuple[str, int] | None:
        """("trunk", position along it) or ("branch", branch index) for joint j; None: not classified."""
        if j in self.trunk:
            return "trunk", self.trunk.index(j)
        for b, joints in enumerate(self.branches):
            if j in joints:
                return "branch", b
        return None


def _depth_and_reach(bvh: Bvh, kids) -> tuple[list[int], list[float]]:
    """Per joint: its subtree's depth in joints, and its reach, the rest length of the longest path from its
    parent down through it (its OFFSET, then its children's, or its End Site)."""
    n = len(bvh.joints)
    depth, reach = [1] * n, [0.0] * n
    for j in reversed(range(n)):  # children come after their parents
        jt = bvh.joints[j]
        below = [reach[k] for k in kids[j]] + ([float(np.linalg.norm(jt.end))] if jt.end is not None else [])
        depth[j] = 1 + max((depth[k] for k in kids[j]), default=0)
        reach[j] = (float(np.linalg.norm(jt.offset)) if jt.parent >= 0 else 0.0) + max(below, default=0.0)
    return depth, reach


def _pairs(children: list[int], depth, reach, ratio: float) -> list[tuple[int, int]]:
    """The mirrored pairs among siblings: one depth, reaches within `ratio` of each other, the closest first."""
    scale = max((reach[c] for c in children), default=0.0)
    cands = []
    for i, a in enumerate(children):
        for b in children[i + 1:]:
            if depth[a] != depth[b]:
                continue
            lo, hi = sorted((reach[a], reach[b]))
            if hi <= 1e-9 * max(scale, 1.0):
                cands.append((0.0, a, b))
            elif lo > 0 and hi / lo <= ratio:
                cands.append((float(np.log(hi / lo)), a, b))
    out, used = [], set()
    for _, a, b in sorted(cands):
        if a not in used and b not in used:
            out.append((a, b))
            used |= {a, b}
    return out


def skeleton_structure(bvh: Bvh) -> Structure:
    """The clip's trunk and branches from its shape (`Structure`): from the root, each trunk joint's children
    in mirrored pairs are branches; the one unpaired child (else the one unpaired child whose subtree holds a
    pair of limbs) continues the trunk."""
    shape = dialect_settings().structure
    ratio = float(shape.pair_reach_ratio)
    kids = _children(bvh)
    depth, reach = _depth_and_reach(bvh, kids)
    first = 0
    while len(kids[first]) == 1:  # a root on the floor above the pelvis (Bandai Namco's joint_Root)
        first = kids[first][0]
    longest = max((reach[k] for k in kids[first]), default=0.0)  # its OFFSET (a world position there) left out

    def limb(a) -> bool:
        return depth[a] >= int(shape.limb_depth) and reach[a] >= float(shape.limb_reach) * longest

    def carries_limbs(j) -> bool:
        return any(limb(a) for k in _subtree(kids, j) for a, _ in _pairs(kids[k], depth, reach, ratio))

    trunk, branches, attach, limbs = [0], [], [], 0
    while True:
        j = trunk[-1]
        pairs = _pairs(kids[j], depth, reach, ratio)
        for a, b in pairs:
            for c in (a, b):
                sub = _subtree(kids, c)
                branches.append(tuple([c] + sorted(k for k in sub if k != c)))
                attach.append(len(trunk) - 1)
            limbs += limb(a)
        paired = {c for p in pairs for c in p}
        unpaired = [c for c in kids[j] if c not in paired]
        if len(unpaired) > 1:
            unpaired = [c for c in unpaired if carries_limbs(c)]
        if len(unpaired) != 1:
            break
        trunk.append(unpaired[0])
    return Structure(tuple(trunk), tuple(branches), tuple(attach), limbs)


def _main_chain(kids, j) -> list[int]:
    """j and, down its subtree, the child with the largest subtree at each branching."""
    chain = [j]
    while kids[chain[-1]]:
        chain.append(max(kids[chain[-1]], key=lambda k: (len(_subtree(kids, k)), -k)))
    return chain


def clip_chains(bvh: Bvh, structure: Structure | None = None, limit: int = 60) -> str:
    """The clip's joints as its skeleton chains them, for a person writing its joint map: its trunk, then each
    branch's main chain and where it leaves the trunk; a shape that tells nothing: the joint names."""
    st = structure or skeleton_structure(bvh)
    names = bvh.names
    if not st.clear:
        shown = ", ".join(names[:limit])
        return shown + (f" ... ({len(names)} joints)" if len(names) > limit else "")
    kids = _children(bvh)
    parts = [" > ".join(names[j] for j in st.trunk) + " (the trunk, the chain the others branch off)"]
    by_attach: dict[int, list[str]] = {}
    for joints, at in list(zip(st.branches, st.attach, strict=True))[:16]:
        by_attach.setdefault(at, []).append(" > ".join(names[k] for k in _main_chain(kids, joints[0])))
    for at, chains in by_attach.items():
        parts.append(f"{' and '.join(chains)} (branching off at {names[st.trunk[at]]})")
    more = len(st.branches) - 16
    return "; ".join(parts) + (f"; {more} more branches" if more > 0 else "")


def body_joint_roles(cfg=None) -> dict[str, str]:
    """Every pbc body joint (conf/motion/dialects.yaml body: the mannequin's and Anny's) -> "trunk", "arm" or
    "leg", trunk first, in the table's order (spine, neck, head, the left limbs, the right)."""
    body = (cfg or dialect_settings()).body
    out = {str(j): "trunk" for j in [*body.spine, *body.neck, body.head]}
    for side in body.limbs.values():
        for role, j in side.items():
            out[str(j)] = "leg" if role in ("thigh", "shin", "foot") else "arm"
    return out


def table_to_write(bvh: Bvh, structure: Structure | None = None, chains: bool = True) -> str:
    """The advice ending a refused match: the `--bvh-map` table to write (a YAML mapping, one row per body
    joint, each `...` to fill with one of the clip's joints) and, with `chains`, the clip's joints as its
    skeleton chains them."""
    rows = ", ".join(f"{j}: ..." for j in body_joint_roles())
    return (f"write its joint map and give it with --bvh-map FILE.yaml (--allow-rest does not go on without "
            f"one): joints: {{{rows}}}, each ... the clip joint that drives that body joint (a row the body lacks "
            "is skipped)" + (f", from the clip's joints: {clip_chains(bvh, structure)}" if chains else ""))


def names_tell_nothing(bvh: Bvh, cfg=None) -> bool:
    """No joint's name gives a side or names the head: names cannot tell the arms, the legs and the trunk
    apart."""
    cfg = cfg or dialect_settings()
    heads = set(cfg.synonyms.head)
    return not any(side is not None or base in heads for side, base, _ in (split_name(n, cfg) for n in bvh.names))


def check_structure(bvh: Bvh, table: JointMap, structure: Structure | None = None) -> None:
    """Refuse (BvhError, one line naming the file, the crossed rows and the table to write) an automatic
    joint map that drives a body trunk joint (spine, neck, head) with a joint of a branch of the clip's trunk
    (an arm, a leg), a body arm or leg joint with a joint of the trunk, or a body arm with a branch leaving
    the trunk no higher than the one driving a body leg. A clip whose shape tells nothing (`Structure.clear`)
    passes: the names are all there is."""
    st = structure or skeleton_structure(bvh)
    if not st.clear:
        return
    roles = body_joint_roles()
    index = {n: i for i, n in enumerate(bvh.names)}
    names = bvh.names
    crossed: dict[str, list[str]] = {}  # where the clip joints lie -> the body joints they would drive
    at_branch: dict[str, int] = {}
    for body_joint, clip_joint in table.joints.items():
        if body_joint not in roles or clip_joint not in index:
            continue
        place = st.place(index[clip_joint])
        if place is None:
            continue
        kind, where = place
        if roles[body_joint] == "trunk" and kind == "branch":
            crossed.setdefault(f"a branch leaving its trunk at {names[st.trunk[st.attach[where]]]} (an arm or a leg)",
                               []).append(body_joint)
        elif roles[body_joint] != "trunk" and kind == "trunk":
            crossed.setdefault(f"its trunk ({' > '.join(names[j] for j in st.trunk)})", []).append(body_joint)
        elif kind == "branch":
            at_branch[body_joint] = st.attach[where]
    legs = {j: a for j, a in at_branch.items() if roles[j] == "leg"}
    if legs:
        high = max(legs.values())
        for j, a in at_branch.items():
            if roles[j] == "arm" and a <= high:
                crossed.setdefault(f"a branch leaving its trunk at {names[st.trunk[a]]}, no higher than the legs' "
                                   f"({', '.join(legs)})", []).append(j)
    if crossed:
        how = "name" if table.path is None else f"the rows of {table.path.name}"
        said = "; ".join(f"{', '.join(js)} by {', '.join(table.joints[j] for j in js)}, of {where}"
                         for where, js in crossed.items())
        raise BvhError(f"{bvh.path}:{bvh.joints[0].line}: the joints matched by {how} cross the clip's skeleton: "
                       f"they drive the body's {said}; its names mislead, so no joint of it is matched by them; "
                       f"{table_to_write(bvh, st)}")


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
    match are left out (bvh_to_poses says which the body needs). Raises BvhError, naming the table to write,
    for a clip whose names tell nothing (`names_tell_nothing`) and for a match crossing the skeleton's shape
    (`check_structure`)."""
    cfg = dialect_settings()
    rest = bvh.rest_positions() if rest is None else rest
    names = bvh.names
    structure = skeleton_structure(bvh)
    if names_tell_nothing(bvh, cfg):
        raise BvhError(f"{bvh.path}:{bvh.joints[0].line}: the clip's joint names tell nothing (none names a side or "
                       "the head), so its arms, legs and trunk cannot be told apart and the body would stay at "
                       f"rest: no joint of it is matched (the clip's unmatched joints: {clip_chains(bvh, structure)}); "
                       f"{table_to_write(bvh, structure, chains=False)}")
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
    matched = JointMap("auto", None, joints, tuple(names), why, toward, dialect, units=dialect_units(dialect, cfg))
    check_structure(bvh, matched, structure)
    return matched


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
