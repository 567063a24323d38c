"""Checks at the doors: poses, configs and training identities, each failure one message saying what was
passed and what to pass instead.

On the ground floor (it imports only the run record's model kinds, pbc.core.runs, and where conf/ lies,
pbc.core.paths), so every stage (data, models, inference, the jobs, the CLIs) can call it first thing.

    as_poses(pose, J)           any pose input -> (B, J, 3, 3) float32 tensor, or one clear ValueError/TypeError
    rotation_errors(R)          (..., 3, 3) -> per-matrix orthonormality and det errors (vectorised)
    check_config(cfg)           one ValueError listing every mistyped / out-of-range config value
    check_bounds(cfg)           the sim, image, garment values against conf/bounds.yaml alone (check_config does it too)
    check_motion_settings(s, n, p)  one motion settings file's node against conf/bounds.yaml (its loader calls it)
    training_identity(cfg, fp)  what a resumed run must share with its checkpoint
    identity_diff(a, b)         the differences between two identities, one readable line each
    check_resume(ck, ident, p)  refuse a checkpoint of another training identity, listing the differences
    trainer_options()           the keyword arguments lightning's Trainer takes (check_config's trainer keys)
    suggest_config_key(msg, c)  Hydra's "Could not override 'trainer.max_epoch'" -> the key meant, or None
"""

from __future__ import annotations

import difflib
import functools
import inspect
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, ListConfig, OmegaConf
from torch import Tensor

from pbc.core.paths import CONF_DIR
from pbc.core.runs import ModelKind

# Matrices stored as float32 drift ~1e-6 from orthonormal; 1e-3 (0.06 deg) admits any honest rotation
# and refuses scaled, sheared, reflected or zero matrices by orders of magnitude.
ROTATION_TOL = 1e-3

__all__ = [
    "ROTATION_TOL",
    "as_poses",
    "check_bounds",
    "check_config",
    "check_motion_settings",
    "check_resume",
    "identity_diff",
    "rotation_errors",
    "suggest_config_key",
    "trainer_options",
    "training_identity",
]


# ------------------------------------------------------------------------------------------ poses
def rotation_errors(rot: Tensor) -> tuple[Tensor, Tensor]:
    """Orthonormality and determinant errors of rotation matrices.

    rot (..., 3, 3) -> (ortho (...), det_err (...)): max |R^T R - I| and |det R - 1| per matrix, in float32
    (float64 input stays float64; float32 round-off, ~1e-7, is far below ROTATION_TOL), autocast or not.
    """
    r = rot if rot.dtype == torch.float64 else rot.float()
    # outside autocast: under bf16-mixed the product would be bf16, whose round-off (~4e-3) fails the test
    with torch.autocast(r.device.type, enabled=False):
        eye = torch.eye(3, dtype=r.dtype, device=r.device)
        ortho = (r.transpose(-1, -2) @ r - eye).abs().flatten(-2).amax(-1)
        # det as the triple product of the rows: torch.linalg.det runs an LU per matrix, ~10x slower here
        det = (torch.linalg.cross(r[..., 0, :], r[..., 1, :]) * r[..., 2, :]).sum(-1)
    return ortho, (det - 1.0).abs()


def _describe(x: Any) -> str:
    if isinstance(x, Tensor):
        return f"a torch tensor of shape {tuple(x.shape)} and dtype {x.dtype}"
    if isinstance(x, np.ndarray):
        return f"a numpy array of shape {x.shape} and dtype {x.dtype}"
    return f"a {type(x).__name__}"


def as_poses(
    pose: Any,
    num_joints: int,
    *,
    tol: float = ROTATION_TOL,
    joint_names: Sequence[str] | None = None,
    what: str = "pose",
    check_rotation: bool = True,
) -> tuple[Tensor, bool]:
    """Check a pose input and return it as float32 rotations.

    Accepts a torch tensor or a numpy array (any real dtype) of shape (J, 3, 3), (B, J, 3, 3), (J*9,) or
    (B, J*9) with J = `num_joints`, rows of each 3x3 being the local joint rotation (row-major, joint order
    of conf/body). Every value must be finite and every matrix a rotation (max |R^T R - I| <= tol,
    |det R - 1| <= tol).

    Returns (rot (B, J, 3, 3) float32 on the input's device, batched): `batched` is False for the single
    shapes (J, 3, 3) and (J*9,), so a caller can return one result for one pose.
    Raises TypeError for a wrong container or dtype, ValueError for a wrong shape, non-finite values or
    non-rotations, naming what was passed and what to pass instead.
    """
    J = int(num_joints)
    shapes = f"(J, 3, 3), (B, J, 3, 3), (J*9,) or (B, J*9) with J = {J}, i.e. ({J}, 3, 3) or (B, {J * 9})"
    if isinstance(pose, np.ndarray):
        if pose.dtype == np.bool_ or not (np.issubdtype(pose.dtype, np.floating)
                                          or np.issubdtype(pose.dtype, np.integer)):
            raise TypeError(f"{what}: got {_describe(pose)}; pass real numbers (float32), shape {shapes}")
        x = torch.from_numpy(np.ascontiguousarray(pose))
    elif isinstance(pose, Tensor):
        x = pose
        if x.dtype == torch.bool or x.is_complex():
            raise TypeError(f"{what}: got {_describe(pose)}; pass real numbers (float32), shape {shapes}")
    else:
        raise TypeError(
            f"{what}: got {_describe(pose)}; pass a torch tensor or a numpy array of rotation matrices, "
            f"shape {shapes}"
        )
    s = tuple(x.shape)
    if s == (J, 3, 3) or s == (J * 9,):
        batched = False
    elif (len(s) == 4 and s[1:] == (J, 3, 3)) or (len(s) == 2 and s[1] == J * 9):
        batched = True
    else:
        hint = ""
        if s == (J, 9):
            hint = f" (one row of 9 per joint: reshape it to ({J}, 3, 3))"
        elif len(s) >= 1 and s[-1] % 9 == 0 and len(s) <= 2:
            hint = f" (that is {s[-1] // 9} joints; this model takes {J})"
        elif len(s) >= 3 and s[-2:] == (3, 3):
            hint = f" (that is {s[-3]} joints; this model takes {J})"
        raise ValueError(f"{what}: got shape {s}{hint}; pass {shapes}")
    if batched and s[0] == 0:
        raise ValueError(f"{what}: got an empty batch, shape {s}; pass at least one pose")
    rot = x.reshape(-1, J, 3, 3)
    if not rot.is_floating_point() or rot.dtype != torch.float32:
        rot = rot.float()
    finite = torch.isfinite(rot).flatten(1).all(dim=1)
    if not bool(finite.all()):
        bad = torch.nonzero(~finite).flatten().tolist()
        where = "" if not batched else f" in batch rows {bad[:10]}{' ...' if len(bad) > 10 else ''}"
        raise ValueError(f"{what}: holds NaN or infinite values{where}; pass finite rotation matrices")
    if check_rotation:
        ortho, det = rotation_errors(rot)
        bad = (ortho > tol) | (det > tol)
        if bool(bad.any()):
            b, j = (int(i) for i in torch.nonzero(bad)[0])
            name = f" ({joint_names[j]})" if joint_names is not None and j < len(joint_names) else ""
            at = f"[{b}, {j}]" if batched else f"[{j}]"
            raise ValueError(
                f"{what}{at}{name} is not a rotation: max |R^T R - I| = {float(ortho[b, j]):.3g}, "
                f"|det R - 1| = {float(det[b, j]):.3g} (tolerance {tol:g}); {int(bad.sum())} of {bad.numel()} "
                "matrices fail. Pass proper rotations (orthonormal, det +1), e.g. "
                "scipy.spatial.transform.Rotation.from_euler(...).as_matrix(), not scaled, zero or reflected ones"
            )
    return rot, batched


def moving_joints(poses: Any, names: Sequence[str], tol: float = 1e-6) -> list[str]:
    """The joints whose rotation differs from the rest pose (identity) in any of `poses` (N, J, 3, 3) or
    (N, J * 9): what a dataset poses, in skeleton order. Chunked, so a memory-mapped array is read once."""
    n, out = len(poses), np.zeros(len(names), bool)
    eye = np.eye(3).reshape(1, 1, 3, 3)
    for i in range(0, n, 4096):
        chunk = np.asarray(poses[i:i + 4096], np.float64).reshape(-1, len(names), 3, 3)
        out |= (np.abs(chunk - eye) > tol).any(axis=(0, 2, 3))
    return [name for name, m in zip(names, out, strict=True) if m]


def check_pose_joints(poses: Any, names: Sequence[str], read: Sequence[str] | None, where: str) -> None:
    """Refuse a model that would not see joints its data moves: `read` (data.pose_joints; None = all) must
    hold every joint posed in `poses` (N, J, 3, 3), else the cloth would change with poses the model
    cannot tell apart."""
    if read is None:
        return
    missed = [j for j in moving_joints(poses, names) if j not in set(read)]
    if missed:
        raise ValueError(f"{where} poses joints {missed} that the model does not read (data.pose_joints="
                         f"{list(read)}): add them to data.pose_joints, or set data.pose_joints=null to read "
                         "every joint")


# ------------------------------------------------------------------------------------------ config
# What a model predicts: pbc.core.runs.ModelKind decides (the cloth target, pbc.pixels.target, reads it from here)
KINDS = tuple(k.value for k in ModelKind)
SPACES = ("local", "root", "position")
NORMS = ("l1", "l2")


def _get(cfg: Any, dotted: str) -> tuple[bool, Any]:
    """(present, value) of a dotted key in a DictConfig / dict, without resolving siblings."""
    node = cfg
    for part in dotted.split("."):
        if node is None:
            return False, None
        try:
            if part not in node:
                return False, None
            node = node[part]
        except Exception:  # an interpolation that cannot resolve here (${hydra:...}): not ours to judge
            return False, None
    return True, node


def _is_int(v: Any) -> bool:
    # bool is an int subclass: model.patch_id=true must not pass as patch 1
    return isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)


def _is_real(v: Any) -> bool:
    return (_is_int(v) or isinstance(v, float | np.floating)) and np.isfinite(float(v))


def _is_list(v: Any) -> bool:
    return isinstance(v, Sequence) and not isinstance(v, str)


def check_config(cfg: Any, num_patches: int | None = None) -> None:
    """Check the config values pbc reads by type and range; one ValueError listing every problem.

    Only keys present are checked, so any entry point may call it on the root config (pbc.train,
    pbc.evaluate, pbc.generate, pbc.predict). Typed checks catch what Hydra coerces silently from the
    command line: `model.patch_id=3.0` (a float) or `model.patch_id=true` (a bool) is not patch 3 or 1.
    Every sim, image and garment number with a row is held to its range in conf/bounds.yaml (`bounds_problems`).
    `num_patches`, when known (the dataset's cage), bounds patch ids; otherwise they must be >= 0.
    """
    problems: list[str] = []

    def want(key: str, ok, expect: str, optional: bool = False) -> None:
        present, v = _get(cfg, key)
        if not present or (optional and v is None):
            return
        if not ok(v):
            problems.append(f"{key}={v!r} ({type(v).__name__}): expected {expect}")

    def choice(key: str, options: Sequence[str]) -> None:
        want(key, lambda v: isinstance(v, str) and v in options, f"one of {list(options)}")

    pos_int = lambda v: _is_int(v) and v > 0  # noqa: E731
    nonneg_int = lambda v: _is_int(v) and v >= 0  # noqa: E731
    pos_real = lambda v: _is_real(v) and float(v) > 0  # noqa: E731
    nonneg_real = lambda v: _is_real(v) and float(v) >= 0  # noqa: E731

    choice("model.kind", KINDS)
    choice("model.space", SPACES)
    want("model.lr", pos_real, "a positive number, e.g. 1e-3")
    choice("loss.norm", NORMS)
    want("loss.normal_weight", nonneg_real, "a number >= 0")
    want("loss.edge_weight", nonneg_real, "a number >= 0")
    want("datamodule.batch_size", pos_int, "a positive integer")
    want("datamodule.num_workers", nonneg_int, "an integer >= 0")
    want("trainer.max_epochs", lambda v: _is_int(v) and v >= -1, "an integer (-1 = no limit)")
    want("data.num_samples", pos_int, "a positive integer")
    want("data.seed", nonneg_int, "an integer >= 0")
    want("data.workers", pos_int, "a positive integer")
    want("data.num_shards", pos_int, "a positive integer")
    want("seed", nonneg_int, "an integer >= 0")
    choice("garment.made_on_forearms", ("to_rest", "as_made"))
    choice("garment.uvs", ("file", "unwrap"))  # pbc.geometry.garment.unwrap.UV_SOURCES
    problems += made_on_rest_problems(cfg)
    choice("image.method", ("sparse", "gather"))
    problems += bounds_problems(cfg)  # every sim, image and garment number: conf/bounds.yaml
    want("data.pose_joints", lambda v: _is_list(v) and len(v) > 0 and all(isinstance(n, str) for n in v),
         "null (every joint of the body) or a list of joint names, e.g. [lower_back, spine, neck, neck1]",
         optional=True)

    present, shards = _get(cfg, "data.num_shards")
    n_shards = shards if present and _is_int(shards) and shards > 0 else None
    bound = f"an integer in 0..{n_shards - 1}" if n_shards else "an integer >= 0"
    want("data.shard", lambda v: _is_int(v) and v >= 0 and (n_shards is None or v < n_shards),
         f"null or {bound} (< data.num_shards)", optional=True)

    _, kind = _get(cfg, "model.kind")
    if kind == "patch":
        present, pid = _get(cfg, "model.patch_id")
        # the range is the dataset's cage's (28 on the T-shirt), known once the dataset is open
        top = f"in 0..{num_patches - 1} (the cage's {num_patches} patches)" if num_patches else ">= 0"
        example = "e.g. +experiment=patch model.patch_id=3 (the T-shirt also has +experiment=patch_03)"
        if not present or pid is None:
            problems.append(f"model.patch_id is missing: model.kind=patch needs an integer {top}, {example}")
        elif not (_is_int(pid) and pid >= 0 and (num_patches is None or pid < num_patches)):
            problems.append(f"model.patch_id={pid!r} ({type(pid).__name__}): expected an integer {top}, {example}")
    problems += _unknown_trainer_keys(cfg)
    if problems:
        raise ValueError("invalid configuration:\n  - " + "\n  - ".join(problems))
    check_work_bounds(cfg)


def made_on_rest_problems(cfg: Any) -> list[str]:
    """`garment.made_on_rest` (the rest pose the garment was made on: keys of `body.rest`, merged into it when
    the garment is made) against the body's `rest` node, one line each: a key the body's rest has not, with the
    key meant ("did you mean"), and a value of another type than that key takes (degrees or null, true or
    false), each named as garment.made_on_rest.KEY. A body with no rest node is refused where the garment is
    made (pbc.data.generate.made_on_body), naming the bodies that have one."""
    present, node = _get(cfg, "garment.made_on_rest")
    has_rest, rest = _get(cfg, "body.rest")
    if not present or node is None or not has_rest or not isinstance(rest, Mapping):
        return []
    if not isinstance(node, Mapping):
        return [f"garment.made_on_rest={_plain(node)!r} ({_type_name(node)}): expected null or a mapping of "
                f"body.rest's keys ({', '.join(map(str, rest))}), e.g. garment.made_on_rest={{arm_angle_deg:0}}"]
    problems = []
    for key, value in node.items():
        if key not in rest:
            close = _closest(str(key), [str(k) for k in rest])
            meant = f"did you mean garment.made_on_rest.{close}? " if close else ""
            problems.append(f"garment.made_on_rest.{key}: unknown key; {meant}(its keys are body.rest's: "
                            f"{', '.join(map(str, rest))})")
        elif isinstance(rest[key], bool) and not isinstance(value, bool):
            problems.append(f"garment.made_on_rest.{key}={_plain(value)!r} ({_type_name(value)}): expected true or "
                            "false")
        elif not isinstance(rest[key], bool) and value is not None and not _is_real(value):
            problems.append(f"garment.made_on_rest.{key}={_plain(value)!r} ({_type_name(value)}): expected a "
                            "number (degrees) or null")
    return problems


# ------------------------------------------------------------------------------------------ bounds
BOUNDS_FILE = CONF_DIR / "bounds.yaml"
CONFIG_SECTIONS = ("sim", "image", "garment")  # the table's other sections are files the motion reader loads

_SPEC = re.compile(r"(?P<kind>int|real|bool)"
                   r"(?:\s*(?P<lb>[\[(])\s*(?P<lo>[^,\s]+)\s*,\s*(?P<hi>[^\])\s]+)\s*(?P<rb>[\])]))?"
                   r"(?:\s+(?P<shape>x\d+|list|set|pair|each)(?=\s|$))?"
                   r"(?P<null>\s+or null(?=\s|$))?\s*(?P<meaning>.*)")
_NOUN = {"int": ("an integer", "integers"), "real": ("a number", "numbers"), "bool": ("true or false", "booleans")}


@dataclass(frozen=True)
class Bound:
    """One row of conf/bounds.yaml: what a setting may be (its kind, range, shape, null or not)."""

    kind: str                       # int | real | bool
    lo: str = "-inf"                # the bounds as the table writes them
    hi: str = "inf"
    lo_open: bool = True
    hi_open: bool = True
    shape: str | None = None        # None (one value), xN, list, set, pair, each
    nullable: bool = False
    meaning: str = ""

    @classmethod
    def parse(cls, key: str, spec: str) -> Bound:
        m = _SPEC.fullmatch(str(spec).strip())
        if m is None:
            raise ValueError(f"{BOUNDS_FILE}: {key}: {spec!r} is not KIND [RANGE] [SHAPE] [or null] [meaning]")
        ranged = m["lb"] is not None
        return cls(m["kind"], m["lo"] if ranged else "-inf", m["hi"] if ranged else "inf",
                   m["lb"] != "[", m["rb"] != "]", m["shape"], bool(m["null"]), m["meaning"].strip())

    def scalar_ok(self, v: Any) -> bool:
        if self.kind == "bool":
            return isinstance(v, bool | np.bool_)
        if not (_is_int(v) if self.kind == "int" else _is_real(v)):
            return False
        lo, hi, x = float(self.lo), float(self.hi), float(v)
        return (x > lo if self.lo_open else x >= lo) and (x < hi if self.hi_open else x <= hi)

    def scalar_range(self, plural: bool = False) -> str:
        noun = _NOUN[self.kind][plural]
        if self.kind == "bool":
            return noun
        lo, hi = math.isinf(float(self.lo)), math.isinf(float(self.hi))
        if lo and hi:
            return f"finite {noun}" if plural else f"a finite {noun.split()[-1]}"
        if hi:
            return f"{noun} {'>' if self.lo_open else '>='} {self.lo}"
        if lo:
            return f"{noun} {'<' if self.hi_open else '<='} {self.hi}"
        return f"{noun} in {'(' if self.lo_open else '['}{self.lo}, {self.hi}{')' if self.hi_open else ']'}"

    def describe(self) -> str:
        """What the setting may be, in words: "a number in [1, 240] (frames per simulated second)"."""
        shape = self.shape or ""
        text = {"": self.scalar_range(), "each": self.scalar_range(),
                "list": f"a list of one or more {self.scalar_range(True)}",
                "set": f"a list of one or more distinct {self.scalar_range(True)}",
                "pair": f"[first, last] with first < last, {self.scalar_range(True)}"}.get(
                    shape, f"a list of {shape[1:]} {self.scalar_range(True)}")
        return ("null or " if self.nullable else "") + text + (f" ({self.meaning})" if self.meaning else "")

    def ok(self, v: Any) -> bool:
        """Whether `v` is what this row allows (for `each`: one value of the mapping)."""
        if v is None:
            return self.nullable
        if self.shape in (None, "each"):
            return self.scalar_ok(v)
        if not _is_list(v) or len(v) == 0 or not all(self.scalar_ok(x) for x in v):
            return False
        if self.shape == "set":
            return len(set(v)) == len(v)
        if self.shape == "pair":
            return len(v) == 2 and float(v[0]) < float(v[1])
        return self.shape == "list" or len(v) == int(self.shape[1:])


def _rows(node: Any, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for k, v in node.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        out.update(_rows(v, key) if isinstance(v, Mapping) else {key: v})
    return out


@functools.lru_cache(maxsize=1)
def bounds_table() -> tuple[dict[str, Bound], tuple[tuple[str, str], ...]]:
    """conf/bounds.yaml, read once a process: {dotted key: Bound}, and the (first, second) pairs whose first
    may not exceed their second."""
    raw = OmegaConf.to_container(OmegaConf.load(BOUNDS_FILE))
    order = tuple((str(a), str(b)) for a, b in raw.pop("order", None) or ())
    return {key: Bound.parse(key, spec) for key, spec in _rows(raw).items()}, order


def _shown(path: Path) -> Path:
    """A shipped file as conf/..., any other as given."""
    try:
        return path.relative_to(CONF_DIR.parent)
    except ValueError:
        return path


def _type_name(v: Any) -> str:
    return "list" if isinstance(v, ListConfig) else "dict" if isinstance(v, DictConfig) else type(v).__name__


def bounds_problems(root: Any, sections: Sequence[str] = CONFIG_SECTIONS,
                    files: Mapping[str, Path] | None = None) -> list[str]:
    """The values of `root` (a config, or {section: node}) in `sections` of conf/bounds.yaml that are out of
    their range or of another type, one line each: "sim.fps=-5 (int): expected a number in [1, 240] (...)";
    a setting of a section read from a file (`files`: {section: path}) is named by the file and its key there.
    Keys absent from `root` are not judged; a pair of `order` only once both of its values passed."""
    files = files or {}
    table, order = bounds_table()
    problems, bad = [], set()
    for key, bound in table.items():
        section = key.split(".", 1)[0]
        if section not in sections:
            continue
        present, v = _get(root, key)
        if not present:
            continue
        # a file's setting is named as its line there reads: "conf/motion/sequence.yaml: max_frames=0"
        shown = f"{_shown(files[section])}: {key.split('.', 1)[1]}" if section in files else key
        if bound.shape == "each" and not isinstance(v, Mapping):
            problems.append(f"{shown}={_plain(v)!r} ({_type_name(v)}): expected a mapping of names to "
                            f"{bound.scalar_range(True)}")
            bad.add(key)
            continue
        for name, x in [(f"{shown}.{k}", x) for k, x in v.items()] if bound.shape == "each" else [(shown, v)]:
            if not bound.ok(x):
                problems.append(f"{name}={_plain(x)!r} ({_type_name(x)}): expected {bound.describe()}")
                bad.add(key)
    for first, second in order:
        if first.split(".", 1)[0] not in sections or {first, second} & bad:
            continue
        (p1, a), (p2, b) = _get(root, first), _get(root, second)
        if p1 and p2 and a is not None and b is not None and float(a) > float(b):
            problems.append(f"{first}={a!r} is more than {second}={b!r}: expected {first} <= {second}")
    return problems


def check_bounds(cfg: Any) -> None:
    """Refuse a config whose sim, image or garment values leave their range in conf/bounds.yaml (or are of another
    type): one ValueError listing every one, key, value and range. check_config does this and more; this is
    for doors that read the sim and image nodes without training (pbc garment inspect)."""
    problems = bounds_problems(cfg)
    if problems:
        raise ValueError("invalid configuration:\n  - " + "\n  - ".join(problems))


def check_motion_settings(section: str, node: Any, path: Path) -> None:
    """Refuse a motion settings file's `node` (section `motion`: conf/motion/sequence.yaml, `dialects`:
    dialects.yaml, read from `path`) with values out of their range in conf/bounds.yaml: one ValueError listing
    every one, by file, key, value and range. The loaders call it on what they read
    (pbc.motion.retarget.motion_settings, pbc.motion.dialects.dialect_settings)."""
    problems = bounds_problems({section: node}, sections=(section,), files={section: Path(path)})
    if problems:
        raise ValueError("invalid motion settings:\n  - " + "\n  - ".join(problems))


def check_settings_file(section: str, node: Any, path: Path) -> None:
    """Refuse a settings file's `node` (conf/bounds.yaml's `section`, read from `path`: conf/stops.yaml is
    `stops`) with values out of their range: one ValueError listing every one, by file, key, value and range."""
    problems = bounds_problems({section: node}, sections=(section,), files={section: Path(path)})
    if problems:
        raise ValueError(f"invalid settings in {_shown(Path(path))}:\n  - " + "\n  - ".join(problems))


def check_work_bounds(cfg: Any) -> None:
    """Refuse work a typo can ask for (`data.num_samples=2000000`, `image.whole_resolution=65536`): past the
    config's `limits` (conf/config.yaml), one ValueError saying how much it would make and the override that
    goes on. A config without `limits` (composed by hand) is not bounded."""
    present, limits = _get(cfg, "limits")
    if not present or limits is None:
        return
    _, samples = _get(cfg, "data.num_samples")
    top = limits.get("max_samples")
    if top is not None and _is_int(samples) and samples > top:
        raise ValueError(f"data.num_samples={samples} would drape and store {samples:,} samples (one file each while "
                         f"generating), over limits.max_samples={top}: if you meant it, add "
                         f"limits.max_samples={samples}")
    top = limits.get("max_image_resolution")
    for key, channels in (("whole_resolution", 6), ("patch_resolution", 6), ("reference_resolution", 6)):
        _, res = _get(cfg, f"image.{key}")
        if top is not None and _is_int(res) and res > top:
            size = channels * res * res * 4
            raise ValueError(f"image.{key}={res} would make images of {res} x {res} pixels ({size / 2**30:,.1f} GiB "
                             f"a float32 image of {channels} channels; every sample is rendered at it), over "
                             f"limits.max_image_resolution={top}: if you meant it, add "
                             f"limits.max_image_resolution={res}")


# the trainer node's _target_ values whose keys are lightning.Trainer's keyword arguments
TRAINER_TARGETS = ("lightning.pytorch.Trainer", "lightning.Trainer", "lightning.pytorch.trainer.Trainer",
                   "lightning.pytorch.trainer.trainer.Trainer", "pytorch_lightning.Trainer")


@functools.lru_cache(maxsize=1)
def trainer_options() -> tuple[str, ...]:
    """The keyword arguments of ``lightning.pytorch.Trainer.__init__`` (imported here only: ~3 s)."""
    from lightning.pytorch import Trainer  # noqa: PLC0415 - lightning loads in ~3 s; only a trainer key check needs it

    return tuple(n for n, p in inspect.signature(Trainer.__init__).parameters.items()
                 if n != "self" and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD))


def _closest(word: str, options: Sequence[str]) -> str | None:
    hits = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return hits[0] if hits else None


def _unknown_trainer_keys(cfg: Any) -> list[str]:
    """`+trainer.max_epoch=3` composes (the + adds the key) and only fails when the Trainer is built, as a
    TypeError naming no fix: refuse keys lightning's Trainer does not take, naming the closest one."""
    present, node = _get(cfg, "trainer")
    if not present or not isinstance(node, Mapping) and not hasattr(node, "keys"):
        return []
    try:
        target = node.get("_target_")
    except Exception:  # an unresolvable interpolation: not ours to judge
        return []
    if target not in TRAINER_TARGETS:
        return []
    options = trainer_options()
    out = []
    for key in node.keys():
        key = str(key)
        if key.startswith("_") or key in options:  # _target_, _partial_, _convert_: Hydra's own
            continue
        near = _closest(key, options)
        hint = f"did you mean trainer.{near}?" if near else "see lightning.pytorch.Trainer's arguments"
        out.append(f"trainer.{key}: not an argument of lightning's Trainer; {hint}")
    return out


_OVERRIDE = re.compile(r"Could not override '([^']+)'")
_APPEND = re.compile(r"use \+([^\s=]+)=(\S*)")
_FULL_KEY = re.compile(r"full_key: (\S+)")


def suggest_config_key(exc_message: str, cfg: Any = None) -> str | None:
    """Hydra's composition error for a mistyped key (``Could not override 'trainer.max_epoch'. To append to
    your config use +trainer.max_epoch=3 ... Key 'max_epoch' is not in struct``) -> one line naming the key
    meant: "unknown key trainer.max_epoch; did you mean trainer.max_epochs?". Hydra itself suggests the
    ``+`` form, which then fails when the Trainer is built.

    cfg: the composed config without the failing override (DictConfig or dict) whose keys are the
    candidates; trainer.* also takes lightning's Trainer arguments (a real one the config does not set
    is suggested with its ``+``). Returns None when the message is not such an error or the key exists.
    """
    m = _OVERRIDE.search(exc_message) or _FULL_KEY.search(exc_message)
    if not m:
        return None
    key = m.group(1).lstrip("+~")
    value = next((v for k, v in _APPEND.findall(exc_message) if k == key), None)
    parts = key.split(".")
    node, fixed = cfg, []
    for i, part in enumerate(parts):
        keys = [str(k) for k in node.keys()] if node is not None and hasattr(node, "keys") else []
        trainer = fixed == ["trainer"]
        options = sorted(set(keys) | set(trainer_options() if trainer else ()))
        if part in keys:
            fixed.append(part)
            try:
                node = node[part]
            except Exception:  # an interpolation that cannot resolve here: its children are unknown
                node = None
            continue
        if trainer and part in options:  # a real Trainer argument the preset does not set
            return (f"trainer.{part} is not set by the trainer preset: add it with "
                    f"+trainer.{part}={value if value is not None else '...'}")
        near = _closest(part, [o for o in options if not o.startswith("_")])
        if near is None:
            where = ".".join(fixed) or "the config"
            return f"unknown key {key}: {where} has no key {part!r} (its keys: {', '.join(keys) or 'none'})"
        meant = ".".join([*fixed, near, *parts[i + 1:]])
        tail = f" ({meant}={value})" if value is not None else ""
        return f"unknown key {key}; did you mean {meant}?{tail}"
    return None


# ------------------------------------------------------------------------------------------ identity
# Keys a resumed run must share with its checkpoint. trainer.max_epochs is deliberately absent: extending
# the schedule is what resuming is for.
IDENTITY_PATHS = {
    "model": "model",
    "loss": "loss",
    # the optimiser class configured (model.optimizer, a _partial_ node; ClothModule falls back to Adam
    # only when the node is absent, recorded then as None)
    "optimizer.name": "model.optimizer._target_",
    "optimizer.lr": "model.lr",
    "batch_size": "datamodule.batch_size",
    "image": "image",
    "seed": "seed",
    "precision": "trainer.precision",
    "accumulate_grad_batches": "trainer.accumulate_grad_batches",
}


# image.whole_sides / whole_rows of the full square image, both sides: what a config without the keys means
# (pbc.pixels.operators.image_sizes), and what every run had before they existed, so left out of the training
# identity and those runs still resume
FULL_IMAGE_WINDOW = {"whole_sides": (0, 1), "whole_rows": (0.0, 1.0)}


def _plain(v: Any) -> Any:
    if isinstance(v, DictConfig | ListConfig):
        return OmegaConf.to_container(v, resolve=True)
    return v


def training_identity(cfg: Any, data_fingerprint: Mapping | None) -> dict:
    """What a run resumed with `ckpt_path=last` must match: model, loss, optimiser, batch, image sizes,
    seed, precision and the dataset fingerprint (pbc.data.dataset.dataset_fingerprint).

    Pure: reads `cfg` (DictConfig or dict), returns a JSON-able dict to store in the checkpoint's
    hyper-parameters / metrics.json and compare with `identity_diff`.
    """
    out: dict[str, Any] = {}
    for name, key in IDENTITY_PATHS.items():
        present, v = _get(cfg, key)
        head, _, leaf = name.rpartition(".")
        (out.setdefault(head, {}) if head else out)[leaf] = _plain(v) if present else None
    image = out.get("image")
    if isinstance(image, dict):  # the full square image, both sides: what every run before the window had
        for key, full in FULL_IMAGE_WINDOW.items():
            if key in image and [float(v) for v in image[key]] == list(full):
                del image[key]
    out["data"] = dict(data_fingerprint) if data_fingerprint is not None else None
    return out


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, Mapping):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        if not d and prefix:
            out[prefix] = {}
        return out
    return {prefix: d}


def identity_diff(a: Mapping, b: Mapping, names: tuple[str, str] = ("checkpoint", "this run")) -> list[str]:
    """The differences between two training identities, one line per differing leaf key, sorted.

    Empty list = same identity. Lines read "loss.norm: checkpoint 'l1' vs this run 'l2'".
    """
    fa, fb = _flatten(a), _flatten(b)
    lines = []
    for k in sorted(set(fa) | set(fb)):
        va, vb = fa.get(k, "<absent>"), fb.get(k, "<absent>")
        if va != vb:
            lines.append(f"{k}: {names[0]} {va!r} vs {names[1]} {vb!r}")
    return lines


def check_resume(checkpoint_identity: Mapping | None, identity: Mapping, path: Any) -> None:
    """Refuse to resume from checkpoint `path` whose training identity differs from this run's.

    One ValueError listing every difference (identity_diff) and the two ways out. A checkpoint written
    before identities were recorded (None) is refused too: nothing says it is the same training.
    """
    if checkpoint_identity is None:
        raise ValueError(
            f"refusing to resume from {path}: it records no training identity (written by an older pbc); "
            "start a new run (ckpt_path=null), or load its weights explicitly if you know it matches"
        )
    diff = identity_diff(checkpoint_identity, identity)
    if diff:
        raise ValueError(
            f"refusing to resume from {path}: it was trained with other settings\n  - " + "\n  - ".join(diff)
            + "\nresume with the checkpoint's settings (drop those overrides), or start a new run (ckpt_path=null)"
        )
