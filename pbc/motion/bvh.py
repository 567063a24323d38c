"""BVH motion capture files: a small, strict reader and the joints' rotations (pure numpy + scipy).

Tried first: PyPI's `pybvh` (0.9.0, maintained): it reads good files, but a frame line cut short fails
inside numpy.loadtxt ("number of columns changed ... at row 3": a row of the data, not the file's line) and
NaN channels pass through. `bvh` (0.3, 2017) and `bvhio` (PyGLM objects, no line numbers) do not report
line numbers either. Every refusal here names the file's line and the fix, so the reader is pbc's own.

Conventions (the BVH format): a joint's local transform is translate(OFFSET) then its rotation channels,
applied in the order its CHANNELS line lists them as intrinsic rotations: "Zrotation Xrotation Yrotation"
with values (a, b, c) is R = Rz(a) @ Rx(b) @ Ry(c); each joint keeps its own order (orders differ within one real
CMU file). The global rotation of joint j is G_parent @ R_j. The rest pose (all channels zero) is the
OFFSETs' layout, every joint frame aligned with the file's world axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

# channel names as the format spells them; files in the wild vary the case ("XROTATION"), read alike
CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CHANNEL_BY_LOWER = {c.lower(): c for c in CHANNELS}


class BvhError(ValueError):
    """A BVH file pbc cannot read: the message names the file, the line, the problem and the fix."""


@dataclass(frozen=True)
class BvhJoint:
    name: str
    parent: int  # index into Bvh.joints, -1 for the root
    offset: np.ndarray  # (3,) rest offset from the parent, file units
    channels: tuple[str, ...]  # e.g. ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    first_channel: int  # column of its first channel in a frame line
    line: int  # the file line of its ROOT / JOINT keyword
    end: np.ndarray | None = None  # (3,) its End Site offset, when it has one

    @property
    def rotation_order(self) -> str:
        """The rotation channels' axes in file order, e.g. "ZXY" ("" for none)."""
        return "".join(c[0] for c in self.channels if c.endswith("rotation"))


@dataclass(frozen=True)
class Bvh:
    path: str
    joints: tuple[BvhJoint, ...]  # parents before children (file order)
    frame_time: float  # seconds per frame
    motion: np.ndarray  # (F, C) float64 channel values, C = sum of the joints' channels
    lines: tuple[int, int]  # the file lines of the MOTION keyword and of the first frame

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    def rest_positions(self) -> np.ndarray:
        """(J, 3) joint positions at rest (all channels zero), file units, relative to the root's OFFSET."""
        pos = np.zeros((len(self.joints), 3))
        for j, jt in enumerate(self.joints):
            if jt.parent >= 0:
                pos[j] = pos[jt.parent] + jt.offset
        return pos

    def root_relative_positions(self, frames=slice(None)) -> np.ndarray:
        """(F, J, 3) joint positions by the file's own forward kinematics with the root's rotation and
        translation removed (file units, the root's axes). Position channels of other joints are ignored:
        files that carry them on every joint (Bandai Namco) repeat the OFFSET there."""
        return self._positions(self.root_relative_rotations(frames))

    def _positions(self, rot: np.ndarray) -> np.ndarray:
        """(F, J, 3) joint positions from the joints' root-relative rotations rot (F, J, 3, 3): each OFFSET
        turned by its parent's rotation, summed down the tree."""
        pos = np.zeros(rot.shape[:2] + (3,))
        for j, jt in enumerate(self.joints):
            if jt.parent >= 0:
                pos[:, j] = pos[:, jt.parent] + rot[:, jt.parent] @ jt.offset
        return pos

    def pelvis_relative(self, pelvis: int, frames=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """((F, J, 3) positions, (F, J, 3, 3) global rotations) of every joint by the file's forward kinematics,
        both in the frame of joint `pelvis` at that frame (its position the origin, its rotation removed), file
        units. `pelvis` 0 is `root_relative_positions` / `root_relative_rotations`; another joint leaves out
        what lies above it (Bandai Namco's joint_Root on the floor, whose child Hips carries the body's turn
        and an OFFSET that is a world position)."""
        rot = self.root_relative_rotations(frames)
        pos = self._positions(rot)
        turn = rot[:, pelvis]  # (F, 3, 3)
        rel_pos = np.einsum("fba,fjb->fja", turn, pos - pos[:, pelvis:pelvis + 1])
        return rel_pos, np.swapaxes(turn, -1, -2)[:, None] @ rot

    def local_rotations(self, frames=slice(None)) -> np.ndarray:
        """(F, J, 3, 3) float64 local rotations of the chosen frames, each joint's Euler order its own."""
        m = self.motion[frames]
        out = np.tile(np.eye(3), (m.shape[0], len(self.joints), 1, 1))
        by_order: dict[str, list[int]] = {}
        for j, jt in enumerate(self.joints):
            if jt.rotation_order:
                by_order.setdefault(jt.rotation_order, []).append(j)
        for order, joints in by_order.items():  # one scipy call per Euler order over all frames
            cols = [[self.joints[j].first_channel + k for k, c in enumerate(self.joints[j].channels)
                     if c.endswith("rotation")] for j in joints]
            angles = m[:, np.asarray(cols)]  # (F, n, len(order)) degrees
            # upper case = intrinsic: R = R_first @ R_second @ R_third, the BVH convention
            rot = Rotation.from_euler(order, angles.reshape(-1, len(order)), degrees=True).as_matrix()
            out[:, joints] = rot.reshape(m.shape[0], len(joints), 3, 3)
        return out

    def root_relative_rotations(self, frames=slice(None)) -> np.ndarray:
        """(F, J, 3, 3) each joint's global rotation with the root's own rotation removed: G_root^-1 G_j
        (the root's entry is the identity), in the file's world axes."""
        local = self.local_rotations(frames)
        glob = np.empty_like(local)
        for j, jt in enumerate(self.joints):
            glob[:, j] = np.eye(3) if jt.parent < 0 else glob[:, jt.parent] @ local[:, j]
        return glob


def _fail(path: str, line: int, problem: str, fix: str) -> BvhError:
    return BvhError(f"{path}:{line}: {problem}; {fix}")


class _Tokens:
    """The hierarchy's tokens with their line numbers; running out is a truncated file."""

    def __init__(self, lines: list[str], path: str):
        self.items = [(tok, n) for n, line in enumerate(lines, 1) for tok in line.split()]
        self.i, self.path, self.last = 0, path, len(lines)

    def peek(self) -> tuple[str, int]:
        if self.i >= len(self.items):
            raise _fail(self.path, self.last, "the file ends inside the HIERARCHY (truncated)",
                        "it was cut short: export or copy the clip again")
        return self.items[self.i]

    def next(self) -> tuple[str, int]:
        tok = self.peek()
        self.i += 1
        return tok

    def expect(self, word: str) -> int:
        tok, n = self.next()
        if tok != word:
            raise _fail(self.path, n, f"expected {word!r}, found {tok!r}",
                        "the HIERARCHY is malformed there: fix that line or export the clip again")
        return n

    def number(self, what: str) -> float:
        tok, n = self.next()
        try:
            v = float(tok)
        except ValueError:
            raise _fail(self.path, n, f"{what}: {tok!r} is not a number", "write a decimal number there") from None
        if not math.isfinite(v):
            raise _fail(self.path, n, f"{what} is {tok}", "write a finite number there")
        return v


def _parse_joint(toks: _Tokens, joints: list[BvhJoint], parent: int, name: str, line: int, column: int) -> int:
    """Read one joint's braces (its OFFSET, CHANNELS, children, End Site); returns the next free column."""
    toks.expect("{")
    toks.expect("OFFSET")
    offset = np.array([toks.number(f"OFFSET of {name}") for _ in range(3)])
    channels: tuple[str, ...] = ()
    if toks.peek()[0] == "CHANNELS":
        _, n = toks.next()
        count = toks.number(f"CHANNELS count of {name}")
        if count != int(count) or not 0 <= count <= 6:
            raise _fail(toks.path, n, f"joint {name}: CHANNELS count {count:g}", "give 0 to 6 channels")
        names = []
        for _ in range(int(count)):
            tok, m = toks.next()
            if tok.lower() not in _CHANNEL_BY_LOWER:
                raise _fail(toks.path, m, f"joint {name}: unknown channel name {tok!r}",
                            f"channels are {', '.join(CHANNELS)}; fix the CHANNELS line")
            names.append(_CHANNEL_BY_LOWER[tok.lower()])
        channels = tuple(names)
    me = len(joints)
    joints.append(BvhJoint(name, parent, offset, channels, column, line))
    column += len(channels)
    while True:
        tok, n = toks.next()
        if tok == "}":
            return column
        if tok == "JOINT":
            child, m = toks.next()
            column = _parse_joint(toks, joints, me, child, m, column)
        elif tok == "End":
            toks.expect("Site")
            toks.expect("{")
            toks.expect("OFFSET")
            end = np.array([toks.number(f"End Site OFFSET of {name}") for _ in range(3)])
            toks.expect("}")
            j = joints[me]
            joints[me] = BvhJoint(j.name, j.parent, j.offset, j.channels, j.first_channel, j.line, end)
        else:
            raise _fail(toks.path, n, f"joint {name}: unexpected {tok!r}",
                        "a joint holds OFFSET, CHANNELS, JOINT, End Site and '}': fix that line")


def parse_bvh(text: str, path: str = "<bvh>") -> Bvh:
    """Read BVH text. Raises BvhError (a ValueError) naming the line and the fix for a truncated file, an
    unknown channel name, a NaN / non-numeric channel value, a frame line with the wrong number of values
    or a frame count that disagrees with MOTION's Frames: line."""
    lines = text.splitlines()
    try:
        motion_at = next(n for n, line in enumerate(lines) if line.strip().upper().startswith("MOTION"))
    except StopIteration:
        motion_at = None
    toks = _Tokens(lines[:motion_at] if motion_at is not None else lines, path)
    if not toks.items or toks.items[0][0] != "HIERARCHY":
        first = toks.items[0][1] if toks.items else 1
        raise _fail(path, first, "not a BVH file (it does not start with HIERARCHY)", "give a .bvh motion file")
    toks.next()
    tok, n = toks.next()
    if tok != "ROOT":
        raise _fail(path, n, f"expected ROOT, found {tok!r}", "the HIERARCHY starts with ROOT <name>")
    name, n = toks.next()
    joints: list[BvhJoint] = []
    channels = _parse_joint(toks, joints, -1, name, n, 0)
    if toks.i < len(toks.items):
        tok, n = toks.items[toks.i]
        raise _fail(path, n, f"{tok!r} after the ROOT joint's closing brace",
                    "one ROOT per file; remove the extra lines (or a stray brace)")
    if motion_at is None:
        raise _fail(path, len(lines), "the file ends before MOTION (truncated)", "export or copy the clip again")
    seen: dict[str, BvhJoint] = {}
    for jt in joints:  # a name is how a joint map and the match find a joint: two alike cannot be told apart
        if jt.name in seen:
            raise _fail(path, jt.line, f"joint name {jt.name!r} is used twice (also line {seen[jt.name].line})",
                        "rename one of them (a joint map finds joints by name)")
        seen[jt.name] = jt
    # MOTION, Frames: N, Frame Time: t, then one line of `channels` numbers per frame
    header: dict[str, tuple[str, int]] = {}
    k = motion_at + 1
    while len(header) < 2:
        if k >= len(lines):
            raise _fail(path, len(lines), "the file ends inside the MOTION header (truncated)",
                        "it needs 'Frames: N' and 'Frame Time: seconds' lines; export or copy the clip again")
        key, _, value = lines[k].partition(":")
        key = " ".join(key.split()).lower()
        if key in ("frames", "frame time"):
            header[key] = (value.strip(), k + 1)
        elif lines[k].strip():
            raise _fail(path, k + 1, f"expected 'Frames:' and 'Frame Time:', found {lines[k].strip()[:40]!r}",
                        "MOTION is followed by 'Frames: N' and 'Frame Time: seconds'")
        k += 1
    try:
        declared = int(header["frames"][0])
        frame_time = float(header["frame time"][0])
    except ValueError:
        bad = "frames" if not header["frames"][0].isdigit() else "frame time"
        raise _fail(path, header[bad][1], f"'{bad}: {header[bad][0]}' is not a number",
                    "write 'Frames: <count>' and 'Frame Time: <seconds>'") from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise _fail(path, header["frame time"][1], f"Frame Time {frame_time:g}", "give the seconds per frame (> 0)")
    rows, first_row = [], None
    for n in range(k, len(lines)):
        values = lines[n].split()
        if not values:
            continue
        first_row = first_row or n + 1
        if len(values) != channels:
            last = all(not s.strip() for s in lines[n + 1:])
            problem = (f"frame {len(rows)} has {len(values)} values, the HIERARCHY declares {channels} channels"
                       + (" (the file ends there: truncated)" if last and len(values) < channels else ""))
            raise _fail(path, n + 1, problem, "export or copy the clip again" if last else
                        "each frame is one line with a value per channel: fix that line")
        try:
            row = np.array(values, dtype=np.float64)
        except ValueError:
            col = next(i for i, s in enumerate(values) if not _is_number(s))
            raise _fail(path, n + 1, f"frame {len(rows)}: {values[col]!r} ({_channel_name(joints, col)}) is not a "
                        "number", "write a decimal number there") from None
        if not np.isfinite(row).all():
            col = int(np.flatnonzero(~np.isfinite(row))[0])
            raise _fail(path, n + 1, f"frame {len(rows)}: {_channel_name(joints, col)} is {values[col]}",
                        "every channel value must be finite: repair or drop that frame (and fix Frames:)")
        rows.append(row)
    if len(rows) != declared:
        raise _fail(path, header["frames"][1], f"'Frames: {declared}' but the file holds {len(rows)} frame lines"
                    + (" (truncated)" if len(rows) < declared else ""),
                    f"write 'Frames: {len(rows)}'" + (", or export or copy the clip again" if len(rows) < declared
                                                      else ""))
    if not rows:
        raise _fail(path, header["frames"][1], "the clip has no frames", "give a clip with at least one frame")
    return Bvh(path, tuple(joints), frame_time, np.stack(rows), (motion_at + 1, first_row))


def check_skeleton(bvh: Bvh) -> None:
    """A skeleton pbc can retarget: more than one joint, and a rest skeleton of some length. Raises BvhError
    naming the file, the joints and the fix."""
    root = bvh.joints[0]
    if len(bvh.joints) < 2:
        raise _fail(bvh.path, root.line, f"the clip has one joint ({root.name}): it moves a point, not a body",
                    "give a clip of a whole skeleton (a root with a spine, arms and legs)")
    if not np.abs(bvh.rest_positions()).max() > 0 and all(
            j.end is None or not np.abs(j.end).any() for j in bvh.joints):
        raise _fail(bvh.path, bvh.joints[1].line, f"every OFFSET of the {len(bvh.joints)} joints "
                    f"({', '.join(bvh.names[:6])}{' ...' if len(bvh.joints) > 6 else ''}) is zero: the rest skeleton "
                    "has no length, so no bone has a direction", "export the clip with its skeleton's offsets")


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _channel_name(joints: list[BvhJoint], col: int) -> str:
    for j in joints:
        if j.first_channel <= col < j.first_channel + len(j.channels):
            return f"{j.name} {j.channels[col - j.first_channel]}"
    return f"column {col}"


def read_bvh(path: str | Path) -> Bvh:
    """Read a .bvh file (see parse_bvh); a missing or unreadable file is a ValueError naming it."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"BVH file {p} does not exist")
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise ValueError(f"BVH file {p} cannot be read: {e.strerror}") from None
    return parse_bvh(text, str(p))
