"""`pbc motion limits`: per-joint limits measured from motion clips (pbc.motion.limits), a report of them against
the body's hand-set limits, and the YAML file the sampler takes them from (`+body.limits_file=FILE`,
pbc.geometry.body.joint_limits).

Each clip is read as `pbc predict` and `data.poses` read it (pbc.motion.retarget.poses_from_clip, arms the
retarget hangs inside the torso raised out of it: pbc.motion.fit); a joint the clip leaves at rest (it has no
joint for it) is not measured on that clip's frames. A clip the reader refuses stops the command, naming it,
unless `skip_refused`: then it is named in one line and left out. Everything is checked (the clips exist, the
settings, the output's folder, every clip read) before the one file is written, atomically."""

from __future__ import annotations

import shlex
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.core.io import atomic_path, require_out_dir
from pbc.data.mirror import joints_mirror_map, mirror_poses
from pbc.data.mocap import held_out
from pbc.geometry.body import body_from_config
from pbc.geometry.body.joint_limits import merged_limits, read_limits_file
from pbc.geometry.body.skeleton import AXES
from pbc.motion.fit import clear_clip_arms
from pbc.motion.limits import (
    LimitRow,
    check_limit_settings,
    limit_settings,
    limits_rows,
    limits_table,
    limits_yaml,
    measured_limits,
    outside_box,
)
from pbc.motion.retarget import check_motion_files, motion_settings, poses_from_clip

CLIP_SUFFIX = ".bvh"


@dataclass
class ClipPoses:
    """The frames of the clips read: poses (N, J, 3, 3), the joints each frame drives (N, J) bool, and per clip
    (its name, its frame count)."""

    poses: np.ndarray
    driven: np.ndarray
    clips: list[tuple[str, int]]
    refused: list[tuple[str, str]]


@dataclass
class LimitsResult:
    """What `measure_limits` found: the report's rows, the limits (J, 3, 2) and which joints were measured (J,),
    the share of frames outside each box (hand_set, measured, given), the clips and the file written (or None)."""

    rows: list[LimitRow]
    limits: np.ndarray
    measured: np.ndarray
    outside: dict[str, float]
    clips: ClipPoses
    out: Path | None


def clip_files(inputs: Sequence[str | Path], exclude: Sequence[str] = ()) -> list[tuple[Path, str]]:
    """(clip, its name) for each .bvh input and each .bvh under a folder input (sorted; named relative to that
    folder), less those whose name matches a glob of `exclude`; each clip once. One ValueError naming the input and
    the fix for a missing path, a file that is not .bvh, a folder with no .bvh, or nothing left."""
    if not inputs:
        raise ValueError("give the .bvh clips to measure, or folders of them")
    found: dict[Path, str] = {}
    for raw in inputs:
        p = Path(raw)
        if p.is_dir():
            files = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() == CLIP_SUFFIX)
            if not files:
                raise ValueError(f"{p}: the folder holds no .bvh clip; give a folder of .bvh clips or the clips")
            for f in files:
                found.setdefault(f.resolve(), str(f.relative_to(p)))
        elif p.is_file():
            if p.suffix.lower() != CLIP_SUFFIX:
                raise ValueError(f"{p}: not a .bvh clip; give .bvh motion clips or folders of them")
            found.setdefault(p.resolve(), p.name)
        else:
            raise ValueError(f"{p}: no such file or folder; give .bvh motion clips or folders of them (a relative path "
                             "is taken from the current folder)")
    kept = [(f, name) for f, name in found.items() if not held_out(name, exclude)]
    if not kept:
        raise ValueError(f"--exclude {' '.join(exclude)} leaves none of the {len(found)} clips; exclude fewer")
    return kept


def read_clips(files: Sequence[tuple[Path, str]], body, skip_refused: bool = False,
               say: Callable[[str], None] = print) -> ClipPoses:
    """Every frame of every clip as the body's poses (`ClipPoses`). A clip the reader refuses is one ValueError
    naming it and --skip-refused, unless `skip_refused`: then one line (`say`) names it and why, and it is left
    out; every clip refused is a ValueError."""
    skel = body.skeleton
    clear = motion_settings().clear_arms
    poses, driven, clips, refused = [], [], [], []
    for f, name in files:
        try:
            motion = poses_from_clip(f, skel)
        except ValueError as err:
            if not skip_refused:
                raise ValueError(f"clip {f} is refused by the clip reader ({err}); fix or remove it, or pass "
                                 "--skip-refused to measure the other clips without it") from None
            refused.append((name, str(err)))
            say(f"skipped {name}: {err}")
            continue
        p, _ = clear_clip_arms(motion.poses, body, clear)
        keep = np.array([n not in motion.missing for n in skel.names])
        poses.append(np.asarray(p, np.float64))
        driven.append(np.broadcast_to(keep, (len(p), len(keep))).copy())
        clips.append((name, len(p)))
    if not clips:
        raise ValueError(f"every one of the {len(files)} clips was refused by the clip reader; give clips it reads "
                         "(pbc motion inspect CLIP says why one is refused)")
    return ClipPoses(np.concatenate(poses), np.concatenate(driven), clips, refused)


def limits_box(body_cfg, names: Sequence[str], table: dict) -> np.ndarray:
    """(J, 3, 2) degrees: the body config's limits with a limits file's table merged over them, joints in `names`
    order."""
    joints = {str(j["name"]): j["limits"] for j in merged_limits(body_cfg, table).joints}
    return np.array([[[float(v) for v in joints[n][a]] for a in AXES] for n in names], np.float64)


def body_for_limits(body_name: str):
    """(the config, the Body) of `--body NAME`; one ValueError for a body whose rest is turned (its poses are
    relative to the turned rest, the limits files' to the bind pose)."""
    root = load_config([f"body={body_name}"])
    cfg = root.body
    rest = OmegaConf.to_container(cfg.get("rest") or {})
    if any(v not in (None, False) for v in rest.values()):
        raise ValueError(f"--body {body_name}: its rest pose is turned (rest: {rest}); limits are relative to the bind "
                         "pose, which the turned body re-expresses (pbc.geometry.body.anny.rested_limits): measure on "
                         "the body with the bind rest (--body anny)")
    return root, body_from_config(cfg)


def measure_limits(inputs: Sequence[str | Path], body_name: str = "anny", out: str | Path | None = None,
                   skip_refused: bool = False, exclude: Sequence[str] = (), against: str | Path | None = None,
                   percentiles: Sequence[float] | None = None, notes: Sequence[str] = (),
                   command: Sequence[str] = (), say: Callable[[str], None] = print) -> LimitsResult:
    """Measure the limits of the clips under `inputs` on body `body_name` (conf/body), print the report (`say`),
    and write the limits YAML to `out` (None: nothing written). `against`: a limits file whose box the report also
    scores the frames against. `percentiles`: (low, high) instead of conf/motion/sequence.yaml's. `notes`: lines
    added to the file's header, after the command (`command`, as typed) and the clips."""
    check_motion_files()
    settings = limit_settings(motion_settings().limits)
    if percentiles is not None:
        settings = replace(settings, percentiles=tuple(float(v) for v in percentiles))
        check_limit_settings(settings, where="--percentiles")
    files = clip_files(inputs, exclude)
    if out is not None:
        out = Path(out)
        if out.suffix.lower() not in (".yaml", ".yml"):
            raise ValueError(f"--out {out}: give a .yaml file name")
        require_out_dir(out.parent, holds_file=True)
    given_table = read_limits_file(against) if against is not None else None
    cfg, body = body_for_limits(body_name)
    skel = body.skeleton
    hand = skel.limits_deg.double().numpy()
    given = limits_box(cfg.body, skel.names, given_table) if given_table is not None else None
    clips = read_clips(files, body, skip_refused, say)
    poses, driven = clips.poses, clips.driven
    if settings.mirrored:
        mm = joints_mirror_map(skel, float(cfg.data.mirror_tolerance))
        mirrored = np.empty_like(driven)
        mirrored[:, mm.joints] = driven
        poses, driven = np.concatenate([poses, mirror_poses(poses, mm)]), np.concatenate([driven, mirrored])
    limits, measured = measured_limits(poses, hand, settings, driven)
    rows = limits_rows(skel.names, clips.poses, hand, limits, measured, given)
    boxes = {"hand_set": hand, "measured": limits, **({"given": given} if given is not None else {})}
    outside = {k: float(outside_box(clips.poses, b)[1].mean()) for k, b in boxes.items()}
    say(limits_table(rows))
    frames = len(clips.poses)
    say(f"{len(clips.clips)} clips, {frames} frames ({len(clips.refused)} refused); frames with a joint outside the "
        f"hand-set limits: {100 * outside['hand_set']:.1f}%, outside the measured ones: "
        f"{100 * outside['measured']:.1f}%"
        + (f", outside {against}'s: {100 * outside['given']:.1f}%" if given is not None else "")
        + f" (percentiles {settings.percentiles[0]:g} / {settings.percentiles[1]:g}, at least "
        f"{settings.min_width_deg:g} degrees wide, {'with' if settings.mirrored else 'without'} mirror images)")
    if out is not None:
        header = limits_header(body_name, clips, settings, command, notes, skel.names, measured)
        with atomic_path(out) as tmp:
            tmp.write_text(limits_yaml(skel.names, limits, measured, header))
        say(f"limits: {out} (use: +body.limits_file={out})")
    return LimitsResult(rows, limits, measured, outside, clips, out)


def limits_header(body_name: str, clips: ClipPoses, settings, command: Sequence[str], notes: Sequence[str],
                  names: Sequence[str], measured: np.ndarray) -> list[str]:
    """The comment lines of a limits file: what it is, the command, the settings, the clips, the notes."""
    lines = [f"Joint limits of body={body_name} measured from motion (pbc motion limits; pbc.motion.limits): degrees, "
             "the body's Euler angles x, y, z about each joint's bind rest frame, as conf/body's joints' limits.",
             "Generated data: edit the clips or the settings and run the command again, not this file. Use: "
             "+body.limits_file=<this file>.",
             f"percentiles {settings.percentiles[0]:g} / {settings.percentiles[1]:g}, at least "
             f"{settings.min_width_deg:g} degrees wide, holding the rest (0), rounded outward to whole degrees, "
             f"{'on the frames and their mirror images' if settings.mirrored else 'on the frames alone'}."]
    if command:
        lines.append("command: " + shlex.join(["pbc", "motion", "limits", *command]))
    undriven = [n for n, m in zip(names, measured, strict=True) if not m]
    if undriven:
        lines.append(f"not driven by any clip, so not listed (the body's own limits hold): {', '.join(undriven)}")
    lines.append(f"clips ({len(clips.clips)}, {sum(n for _, n in clips.clips)} frames): "
                 + ", ".join(f"{name} ({n})" for name, n in clips.clips))
    if clips.refused:
        lines.append("refused by the clip reader and left out: " + ", ".join(name for name, _ in clips.refused))
    lines += list(notes)
    return lines
