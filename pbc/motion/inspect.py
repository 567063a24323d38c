"""What pbc makes of a motion clip, for people (`pbc motion inspect CLIP.bvh`): its dialect, units, height and
rest pose, the match (clip joint -> body joint, and why), its frames and rate, and a figure of the clip's own
skeleton at a frame beside the body posed by it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pbc.geometry.body.base import Body, pose_body
from pbc.motion.bvh import Bvh
from pbc.motion.retarget import Motion, capture_rate, must_drive, posed_heads


def describe(bvh: Bvh, motion: Motion, skeleton) -> list[str]:
    """The report's lines: the clip, the dialect and units, the match table with reasons, what is left out."""
    t = motion.table
    played = capture_rate(bvh, t)[0].frame_time  # the capture's rate where the header carries a converter's
    seconds = (bvh.num_frames - 1) * played
    lines = [f"clip: {bvh.path}: {len(bvh.joints)} joints, {bvh.num_frames} frames at {1 / played:g} fps "
             f"({seconds:.2f} s)",
             f"dialect: {t.dialect or 'unknown'}; units: {motion.units} ({motion.metres_per_unit:g} m per unit); "
             f"skeleton height {motion.height_m:.2f} m; rest pose: {motion.rest_pose}"
             + (f" (frame {motion.rest_frame} stands in for it)" if motion.rest_frame is not None else ""),
             "joint map: " + (f"{t.path}" if t.path is not None else "matched by name and structure (no table; "
                              "--bvh-map FILE.yaml overrides)"),
             f"{'body joint':<12}{'clip joint':<28}why"]
    for j in skeleton.names:
        if j in motion.mapped:
            lines.append(f"{j:<12}{motion.mapped[j]:<28}{t.why.get(j, '')}")
        else:
            lines.append(f"{j:<12}{'-':<28}no clip joint: turns with its parent")
    free = [n for n in bvh.names if n not in set(motion.mapped.values()) and n != bvh.names[0]]
    if free:
        lines.append(f"clip joints driving no body joint ({len(free)}): {', '.join(free)}")
    lines += [f"note: {n}" for n in motion.notes if "stay at rest" not in n and "are ignored" not in n]  # the
    # table above lists those
    undriven = must_drive(skeleton, motion.mapped)
    if undriven:
        lines.append(f"refused by pbc predict / view / data.poses: the body's {', '.join(undriven)} would stay at "
                     "rest; map them with --bvh-map FILE.yaml, or go on with --allow-rest")
    lines.append(sanity_line(motion.sanity))
    return lines


def sanity_line(sanity: dict) -> str:
    """One line of `pbc.motion.retarget.sanity_report`: the measures, and the refusal when it found problems."""
    measures = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sanity.items() if k not in ("problems",))
    if not sanity.get("problems"):
        return f"sanity: stands as a person ({measures})"
    return (f"refused by pbc predict / view / data.poses: {'; '.join(sanity['problems'])} ({measures}); fix its "
            "rest (--rest-frame K) or its joint map (--bvh-map FILE.yaml), or go on with --trust-clip")


def clip_figure(path: str | Path, bvh: Bvh, motion: Motion, body: Body, k: int) -> Path:
    """A PNG: the clip's skeleton at pose k of `motion` (its own forward kinematics, root removed, in the body's
    axes and metres) beside the body posed by it, both seen from the front; the joints that drive the body
    are marked and named on both."""
    import matplotlib  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting
    from matplotlib.collections import PolyCollection  # noqa: PLC0415 - as above: only this figure plots

    frame = int(round(float(motion.source_frames[k])))
    pos = bvh.pelvis_relative(motion.pelvis, slice(frame, frame + 1))[0][0] @ motion.axes.T * motion.metres_per_unit
    index = {n: i for i, n in enumerate(bvh.names)}
    skel = body.skeleton
    fig, (ax_clip, ax_body) = plt.subplots(1, 2, figsize=(11, 6.5))
    for jt_i, jt in enumerate(bvh.joints):
        if jt.parent >= 0:
            seg = pos[[jt.parent, jt_i]]
            ax_clip.plot(seg[:, 0], seg[:, 1], "-", color="0.45", lw=1.5)
    ax_clip.plot(pos[:, 0], pos[:, 1], ".", color="0.3", ms=4)
    colours = plt.get_cmap("tab20")(np.linspace(0, 1, max(len(skel.names), 2)))
    for i, j in enumerate(skel.names):
        if j in motion.mapped:
            p = pos[index[motion.mapped[j]]]
            ax_clip.plot(p[0], p[1], "o", color=colours[i], ms=7, mec="k")
            short = motion.mapped[j].rsplit(":", 1)[-1]  # the namespace ('mixamorig:') is in the report
            ax_clip.annotate(short, p[:2], fontsize=6, xytext=(4, 2), textcoords="offset points")
    ax_clip.set_title(f"the clip's skeleton, frame {frame} (its own forward kinematics)\n"
                      f"{motion.table.dialect or 'unknown'} names, {motion.units}, rest: {motion.rest_pose}"
                      f"{'' if motion.rest_frame is None else f' (frame {motion.rest_frame})'}; "
                      "coloured: joints driving the body", fontsize=9)

    verts = pose_body(body, torch.from_numpy(motion.poses[k:k + 1]).to(body.vertices.dtype))[0].double().numpy()
    tri = verts[body.faces.long().numpy()]  # (F, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    order = np.argsort(tri[:, :, 2].mean(1))  # far faces first: the nearest ends on top (camera at +z)
    shade = 0.35 + 0.6 * np.clip(normal[order] @ np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0]), 0, 1)
    ax_body.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=np.outer(shade, [0.85, 0.72, 0.6]),
                                          edgecolors="none"))
    heads = posed_heads(skel, motion.poses[k:k + 1])[0]
    for i, j in enumerate(skel.names):
        par = skel.parents[i]
        if par >= 0:
            ax_body.plot(heads[[par, i], 0], heads[[par, i], 1], "-", color="0.2", lw=1)
        ax_body.plot(heads[i, 0], heads[i, 1], "o", color=colours[i] if j in motion.mapped else "w", ms=6, mec="k")
        ax_body.annotate(j, heads[i, :2], fontsize=6, xytext=(4, 2), textcoords="offset points")
    ax_body.set_title(f"the body posed by it: {len(motion.mapped)} of {len(skel.names)} joints driven\n"
                      "(same colour: driven by that clip joint; white: turns with its parent)", fontsize=9)
    lo = np.minimum(pos.min(0), verts.min(0))
    hi = np.maximum(pos.max(0), verts.max(0))
    pad = 0.05 * float((hi - lo)[:2].max())
    for ax in (ax_clip, ax_body):
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, the body's left)")
        ax.set_ylabel("y (m, up)")
    fig.suptitle(f"{Path(bvh.path).name}: seen from the front, the pelvis ({bvh.names[motion.pelvis]}) at the origin",
                 fontsize=10)
    fig.tight_layout()
    out = Path(path)
    tmp = out.with_name(out.name + ".part.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(out)
    return out
