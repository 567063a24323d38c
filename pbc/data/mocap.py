"""A dataset's poses from motion capture (`data.poses=PATH`): a BVH clip, a folder of clips, or an .npy of
(N, J, 3, 3) rotations; frames picked to cover the clips' pose space, optionally mixed with the D.3 sampler.

Why farthest-point selection, not every n-th frame: a walk spends most of its frames near a few postures,
so a uniform stride spends the drape budget on near-duplicates and misses the rare extremes (a raised arm
for two frames). Farthest-point selection over the joint rotations takes, at each step, the frame farthest
from every frame taken so far; its first k frames are the k most spread, whatever n is.

The distance is the chordal one between rotation matrices, summed over the joints the dataset poses:
sqrt(sum_j |R_j - R'_j|_F^2). Unlike Euler angles it has no wrap-around at +-180 degrees and does not
depend on the Euler order.
"""

from __future__ import annotations

import fnmatch
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pbc.core.validate import as_poses, moving_joints
from pbc.geometry.body.skeleton import Skeleton, xzy_angles
from pbc.motion.fit import clear_clip_arms
from pbc.motion.retarget import motion_settings, poses_from_clip
from pbc.sim.poses import SamplingSettings, sample_poses

CLIP_SUFFIXES = (".bvh", ".npy")
SAMPLED = -1  # the clip index of a pose drawn by the D.3 sampler


@dataclass
class PoseSource:
    """Candidate poses read from `data.poses`: every frame of every clip."""

    poses: np.ndarray  # (N, J, 3, 3) float64, the body's joint order
    clip: np.ndarray  # (N,) int64 index into `clips`
    frame: np.ndarray  # (N,) int64 the frame of its clip
    clips: list[str]  # clip names, relative to data.poses (a file: its name)


ROLES = ("train", "held_out")


def clip_files(path: str | Path, holdout: Sequence[str] = (), role: str = "train") -> list[Path]:
    """The clips `data.poses` names: the file itself, or every .bvh / .npy under a folder (sorted, so the
    order, and with it the selection, never depends on the file system), less those whose name relative to
    the folder matches a glob pattern of `holdout` (`data.poses_holdout`: clips kept out of training, to be
    scored on apart); with ``role="held_out"`` (`data.poses_role`) only those. One ValueError naming the fix."""
    if role not in ROLES:
        raise ValueError(f"data.poses_role={role}: one of {', '.join(ROLES)} (train: every clip but data.poses_holdout;"
                         " held_out: only those)")
    p = Path(path)
    if p.is_file():
        if p.suffix.lower() not in CLIP_SUFFIXES:
            raise ValueError(f"data.poses={p}: a {p.suffix or 'suffix-less'} file is not a pose source; give a .bvh "
                             "clip, an .npy of (N, J, 3, 3) rotations, or a folder of them")
        return [p]
    if p.is_dir():
        found = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in CLIP_SUFFIXES)
        if found and role == "held_out":
            kept = [f for f in found if held_out(str(f.relative_to(p)), holdout)]
            if not kept:
                raise ValueError(f"data.poses={p}: data.poses_role=held_out but data.poses_holdout={list(holdout)} "
                                 "holds out no clip of the folder; name the held-out clips in data.poses_holdout")
            return kept
        if found and holdout:
            found = [f for f in found if not held_out(str(f.relative_to(p)), holdout)]
            if not found:
                raise ValueError(f"data.poses={p}: data.poses_holdout={list(holdout)} holds out every clip of the "
                                 "folder; hold out fewer")
        if not found:
            raise ValueError(f"data.poses={p}: the folder holds no clip (no .bvh or .npy file under it); put the "
                             "motion-capture clips there or point data.poses at a clip")
        return found
    raise ValueError(f"data.poses={p}: no such file or folder; give a .bvh clip, an .npy of (N, J, 3, 3) "
                     "rotations or a folder of them (a relative path is taken from the current folder)")


def clip_poses(path: Path, skeleton: Skeleton, joint_map: str = "auto", allow_rest: bool = False
               ) -> tuple[np.ndarray, np.ndarray]:
    """One clip as the body's poses (F, J, 3, 3) float64 and each pose's frame (F,) int64, every frame at the
    clip's own rate. A .bvh goes through pbc.motion's one door (`poses_from_clip`); its refusals name the
    clip, the line and the fix, in this command's keys."""
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as err:
            raise ValueError(f"data.poses: {path} is not a readable numpy array ({type(err).__name__}: {err}); "
                             "save the poses again with np.save as an (N, J, 3, 3) array") from None
        if arr.ndim == 4 and arr.shape[0] == 0:
            raise ValueError(f"data.poses: {path} holds no poses (shape {arr.shape}); save at least one pose")
        rot, _ = as_poses(arr, skeleton.num_joints, joint_names=skeleton.names, what=f"data.poses file {path}")
        return rot.double().numpy(), np.arange(len(rot), dtype=np.int64)
    try:
        motion = poses_from_clip(path, skeleton, joint_map, allow_rest=allow_rest)
    except ValueError as err:  # BvhError included: the message is pbc.motion's, its options are pbc predict's
        msg = str(err)
        for option, key in CLIP_OPTIONS.items():
            msg = msg.replace(option, key)
        raise ValueError(f"data.poses: {msg}") from None
    return motion.poses, np.rint(motion.source_frames).astype(np.int64)


# pbc.motion's refusals name pbc predict's options; generation's keys for the same settings
CLIP_OPTIONS = {"--bvh-map ": "data.poses_joint_map=", "--bvh-map": "data.poses_joint_map",
                "--allow-rest": "data.poses_allow_rest=true", "--max-frames": "(conf/motion/sequence.yaml max_frames)"}


def held_out(name: str, holdout: Sequence[str]) -> bool:
    """Whether clip `name` (relative to data.poses) matches a glob pattern of `holdout`."""
    return any(fnmatch.fnmatch(name, pat) or fnmatch.fnmatch(Path(name).name, pat) for pat in holdout)


def read_pose_source(path: str | Path, skeleton: Skeleton, posed_joints=(), joint_map: str = "auto",
                     allow_rest: bool = False, holdout: Sequence[str] = (), role: str = "train") -> PoseSource:
    """Every frame of every clip under `path` as the body's poses; joints outside `posed_joints` (the
    garment's own joint set, `sampling.posed_joints`; () = all) are put back at rest, as the sampler keeps
    them. A clip that moves none of the posed joints is refused, naming it. `holdout`, `role`: `clip_files`."""
    files = clip_files(path, holdout, role)
    root = Path(path)
    keep = np.ones(skeleton.num_joints, bool)
    if posed_joints:
        keep[:] = False
        keep[skeleton.indices(posed_joints, "sampling.posed_joints")] = True
    poses, clip, frame, names = [], [], [], []
    for k, f in enumerate(files):
        p, fr = clip_poses(f, skeleton, joint_map, allow_rest)
        p = p.copy()
        p[:, ~keep] = np.eye(3)
        if not moving_joints(p, skeleton.names):
            which = f" of the posed joints {list(posed_joints)}" if posed_joints else ""
            raise ValueError(f"data.poses: clip {f} drives no body joint{which} (every frame is the rest pose); "
                             "remove it, or give a clip whose mapped joints move")
        poses.append(p)
        clip.append(np.full(len(p), k, np.int64))
        frame.append(fr)
        names.append(f.name if f == root else str(f.relative_to(root)))
    return PoseSource(np.concatenate(poses), np.concatenate(clip), np.concatenate(frame), names)


def source_files_hash(path: str | Path, holdout: Sequence[str] = (), role: str = "train") -> dict[str, str]:
    """{clip name: sha256 of its bytes, 16 hex}: what the dataset's fingerprint keeps of `data.poses` (its
    content, not where it lies: a moved copy of the clips makes the same data)."""
    root = Path(path)
    out = {}
    for f in clip_files(root, holdout, role):
        out[f.name if f == root else str(f.relative_to(root))] = hashlib.sha256(f.read_bytes()).hexdigest()[:16]
    return out


def farthest_pose_selection(poses: np.ndarray, n: int, seed: int) -> np.ndarray:
    """(n,) int64 indices into poses (N, J, 3, 3), farthest-point order: the first is drawn from `seed`, each
    next one is the pose farthest (chordal distance over all joints) from those taken. n <= N."""
    feats = np.asarray(poses, np.float64).reshape(len(poses), -1)
    if not 0 <= n <= len(feats):
        raise ValueError(f"cannot select {n} of {len(feats)} poses")
    if n == 0:
        return np.zeros(0, np.int64)
    chosen = np.empty(n, np.int64)
    chosen[0] = np.random.default_rng(seed).integers(len(feats))
    gap = ((feats - feats[chosen[0]]) ** 2).sum(1)
    for i in range(1, n):
        chosen[i] = int(gap.argmax())
        gap = np.minimum(gap, ((feats - feats[chosen[i]]) ** 2).sum(1))
    return chosen


def motion_capture_poses(path: str | Path, n: int, sampled_fraction: float, seed: int, skeleton: Skeleton,
                         body, settings: SamplingSettings, joint_map: str = "auto", allow_rest: bool = False,
                         holdout: Sequence[str] = (), role: str = "train") -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """n dataset poses: round(n * (1 - sampled_fraction)) clip frames by farthest-point selection (arms inside
    the torso raised out of it: `pbc.motion.fit`), then the rest from the D.3 sampler (`sample_poses`, the same
    seed).

    Returns poses (n, J, 3, 3) float32, their Euler angles (n, J, 3) float32 degrees, the pose stats (as
    `sample_poses`'s, plus the clip counts) and the per-pose source {"clips": names, "clip": (n,) clip index
    (SAMPLED for a sampler pose), "frame": (n,) the clip's frame (the sampler's pose index)}.
    """
    if not 0.0 <= float(sampled_fraction) <= 1.0:
        raise ValueError(f"data.poses_sampled_fraction={sampled_fraction}: give a fraction in [0, 1] of the poses "
                         "to draw from the D.3 sampler (0: every pose from the clips)")
    n_sampled = int(round(n * float(sampled_fraction)))
    n_clip = n - n_sampled
    src = read_pose_source(path, skeleton, settings.posed_joints, joint_map, allow_rest, holdout, role)
    if n_clip > len(src.poses):
        raise ValueError(f"data.poses={path}: {len(src.poses)} frames in {len(src.clips)} clip(s), fewer than the "
                         f"{n_clip} poses asked of them (data.num_samples={n} x (1 - data.poses_sampled_fraction="
                         f"{sampled_fraction})); lower data.num_samples, raise data.poses_sampled_fraction or add "
                         "clips")
    pick = farthest_pose_selection(src.poses, n_clip, seed)
    chosen, turned = clear_clip_arms(src.poses[pick], body, motion_settings().clear_arms)
    poses = [torch.from_numpy(chosen).float()]
    clip, frame = src.clip[pick].tolist(), src.frame[pick].tolist()
    stats = {"requested": n, "source": "motion capture", "clips": len(src.clips), "frames": int(len(src.poses)),
             "selected": n_clip, "sampled": n_sampled,
             "arms_raised": {"poses": int((turned > 0).any(1).sum()) if len(turned) else 0,
                             "max_deg": float(turned.max()) if turned.size else 0.0}}
    if n_sampled:
        sampled, sampler_stats = sample_poses(skeleton, n_sampled, seed, body, settings)
        sampler_stats.pop("angles_deg")
        stats["sampler"] = sampler_stats
        poses.append(sampled)
        clip += [SAMPLED] * n_sampled
        frame += list(range(n_sampled))
    out = torch.cat(poses).numpy().astype(np.float32)
    angles = xzy_angles(out).astype(np.float32)
    return out, angles, stats, {"clips": src.clips, "clip": clip, "frame": frame}
