"""``pbc outfit predict``'s job: an outfit's pieces (one model each, on one body) predicted and composed as layers
(pbc.inference.outfit) over a motion clip or the pieces' own test splits, written under one folder: motion.mp4
(the body and every piece, each its own colour), garment_<piece>.glb, vertices_<piece>.npy (composed) and
predicted_<piece>.npy (each model's own output), contact_sheet.png and outfit.json (the order and how it was
found, each layer's penetration before and after, the time per frame)."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw

from pbc.core.io import atomic_path, naming_full_disk, require_writable_dir, save_npy, write_json
from pbc.core.validate import as_poses
from pbc.inference.outfit import OutfitPredictor, OutfitResult
from pbc.inference.poses import read_motion, read_poses
from pbc.jobs.predict import OUT_FULL_FIX, guard_frames, sheet_frames
from pbc.jobs.writers import SHEET_COLUMNS, VideoWriter, camera, render_frames, write_glb
from pbc.motion.retarget import Motion, motion_settings

WHAT = "outfit output directory"


class OutfitPoses:
    """The poses an outfit is predicted on: `body` (N, J, 3, 3) the body's, `pieces` each piece's own copy (its
    model's guard applied to a clip), `names` (N,), `times` (N,) seconds, `truth` piece -> (rows (M,), its drapes
    (M, V, 3)) where the poses are its own test split, `guards` piece -> guard report, `motion` (a clip) or None."""

    def __init__(self, body, pieces, names, times, truth=None, guards=None, motion: Motion | None = None,
                 source: str = ""):
        self.body, self.pieces, self.names, self.times = body, pieces, list(names), np.asarray(times, np.float64)
        self.truth, self.guards, self.motion, self.source = truth or {}, guards or {}, motion, source


def split_poses(outfit: OutfitPredictor, split: str, max_poses: int | None) -> OutfitPoses:
    """Each piece's own `split` (its first `max_poses`, None: all), one after the other, every piece predicted on
    all of them as they are (no guard: a split is the model's own data); each piece's drapes kept for its rows."""
    poses, names, truth, at = [], [], {}, 0
    for name in outfit.predictors:
        chosen = read_poses(split, outfit.predictors[name].dataset).first(max_poses)
        poses.append(chosen.poses)
        names += [f"{name}_{n}" for n in chosen.names]
        truth[name] = (np.arange(at, at + len(chosen.poses)), chosen.truth.numpy())
        at += len(chosen.poses)
    body = torch.cat(poses)
    fps = float(motion_settings().video.max_fps)
    return OutfitPoses(body, {n: body for n in outfit.predictors}, names, np.arange(len(body)) / fps, truth,
                       source=f"the {split} split of each piece ({', '.join(outfit.predictors)}), one after the other")


def clip_poses(outfit: OutfitPredictor, motion: Motion, guard: str | None = None) -> OutfitPoses:
    """A clip's frames: each piece's copy guarded by its own model (`guard_frames`); the body posed, joint by
    joint, as the model reading that joint asks (the innermost's where several read it), the clip's elsewhere."""
    names = list(outfit.dataset.body.skeleton.names)
    pieces, guards = {}, {}
    body = np.asarray(motion.poses, np.float64).copy()
    for name in reversed(outfit.order):  # outer first: the innermost's joints written last
        p = outfit.predictors[name]
        guarded, report = guard_frames(p, motion.poses, guard)
        report.pop("source", None), report.pop("note", None)
        pieces[name], _ = as_poses(guarded.astype(np.float32), len(names), joint_names=names,
                                   what=f"{name}'s guarded poses")
        body[:, p.read_joints()] = guarded[:, p.read_joints()]
        guards[name] = {"guard": report["guard"],
                        "flagged": None if report["known"] is None else report["known"]["num_flagged"]}
    body_poses, _ = as_poses(body.astype(np.float32), len(names), joint_names=names, what="the body's poses")
    return OutfitPoses(body_poses, pieces, [f"frame_{k:05d}" for k in range(len(body))], motion.times, None, guards,
                       motion, source="clip")


def outfit_layers(outfit: OutfitPredictor, vertices: Mapping[str, np.ndarray], bodies: np.ndarray, rows,
                  video) -> list[tuple]:
    """render_frames' layers of frames `rows`: the posed body, then every piece innermost first, each in its
    layer's colour (conf/outfit.yaml colours), each lifted over the skin by the video's garment_lift (not over each
    other: a piece inside the one under it shows through it)."""
    faces = torch.as_tensor(outfit.body_faces)
    layers = [(torch.from_numpy(np.asarray(bodies[rows])), faces, list(video.body_colour), 0.0, True)]
    for i, name in enumerate(outfit.order):
        layers.append((torch.from_numpy(np.asarray(vertices[name][rows], np.float32)),
                       torch.as_tensor(outfit.meshes[name].faces), list(outfit.settings.colour(i)),
                       float(video.garment_lift), True))
    return layers


def outfit_camera(outfit: OutfitPredictor, vertices: Mapping[str, np.ndarray], bodies: np.ndarray, height: int):
    """One fixed front camera over every frame's body and pieces (`camera`)."""
    pts = torch.from_numpy(np.concatenate([np.asarray(bodies).reshape(-1, 3)]
                                          + [np.asarray(v, np.float32).reshape(-1, 3) for v in vertices.values()]))
    return camera(pts, height, float(motion_settings().video.margin))


def outfit_sheet(path: Path, outfit: OutfitPredictor, vertices, bodies, frames: Sequence[int],
                 titles: Sequence[str]) -> Path:
    """contact_sheet.png: front views of `frames` (body and every piece in its colour), SHEET_COLUMNS a row, each
    titled."""
    video = motion_settings().video
    cam = outfit_camera(outfit, {n: v[frames] for n, v in vertices.items()}, bodies[frames], int(video.height) // 2)
    imgs = render_frames(outfit_layers(outfit, vertices, bodies, frames, video), cam, list(video.light),
                         list(video.background))
    cols = min(len(frames), SHEET_COLUMNS)
    rows = -(-len(frames) // cols)
    h, w = imgs.shape[1:3]
    sheet = Image.new("RGB", (cols * w, rows * (h + 16)), tuple(int(255 * c) for c in video.background))
    draw = ImageDraw.Draw(sheet)
    for k, (img, title) in enumerate(zip(imgs, titles, strict=True)):
        x, y = (k % cols) * w, (k // cols) * (h + 16)
        sheet.paste(Image.fromarray(img), (x, y + 16))
        draw.text((x + 4, y + 2), title, fill=(0, 0, 0))
    with atomic_path(path) as tmp:
        sheet.save(tmp, format="PNG")
    return path


def vertex_errors(result: OutfitResult, truth: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    """Each piece's mean vertex error (cm) against its own drapes on its rows, alone (its model's output) and
    composed."""
    out = {}
    for name, (rows, drapes) in truth.items():
        err = {k: float(np.linalg.norm(v[name][rows] - drapes, axis=-1).mean() * 100.0)
               for k, v in (("alone", result.predicted), ("composed", result.vertices))}
        out[name] = {"poses": len(rows), "alone_cm": round(err["alone"], 4), "composed_cm": round(err["composed"], 4)}
    return out


def predict_outfit(outfit: OutfitPredictor, poses: OutfitPoses, out: Path, video: str | None = "mp4",
                   glb: bool = True, sheet: int = 12, info: dict | None = None) -> dict:
    """The outfit over `poses`, written under `out` (see the module's doc). Returns outfit.json's content."""
    t0 = time.time()
    out = require_writable_dir(out, WHAT)
    result = outfit(poses.body, poses.pieces)
    settings = motion_settings().video
    files: dict = {}
    stages = dict(result.seconds)
    with naming_full_disk(out, WHAT, OUT_FULL_FIX):
        for name in outfit.order:
            save_npy(out / f"vertices_{name}.npy", result.vertices[name].astype(np.float32))
            save_npy(out / f"predicted_{name}.npy", result.predicted[name].astype(np.float32))
        files["vertices"] = {n: f"vertices_{n}.npy" for n in outfit.order}
        files["predicted"] = {n: f"predicted_{n}.npy" for n in outfit.order}
        save_npy(out / "poses.npy", poses.body.numpy().astype(np.float32))
        files["poses"] = "poses.npy"
        fps = poses.motion.fps if poses.motion is not None else float(settings.max_fps)
        if video:
            t = time.time()
            cam = outfit_camera(outfit, result.vertices, result.bodies, int(settings.height))
            every = max(1, round(fps / float(settings.max_fps)))
            shown = np.arange(0, len(poses.names), every)
            vw = VideoWriter(out / f"motion.{video}", fps / every, int(settings.crf))
            try:
                for i in np.array_split(shown, max(1, -(-len(shown) // 8))):
                    vw.append(render_frames(outfit_layers(outfit, result.vertices, result.bodies, i, settings), cam,
                                            list(settings.light), list(settings.background)))
            except BaseException as e:
                vw.close(e)
                raise
            vw.close()
            files["video"] = f"motion.{video}"
            files["video_frames"] = {"count": len(shown), "every": every, "fps": round(fps / every, 4)}
            stages["video"] = round(time.time() - t, 3)
        if glb:
            t = time.time()
            for name in outfit.order:
                write_glb(out / f"garment_{name}.glb", outfit.predictors[name].dataset.garment, result.vertices[name],
                          poses.times)
            files["glb"] = {n: f"garment_{n}.glb" for n in outfit.order}
            stages["glb"] = round(time.time() - t, 3)
        on_sheet = sheet_frames(len(poses.names), sheet)
        if on_sheet:
            t = time.time()
            outfit_sheet(out / "contact_sheet.png", outfit, result.vertices, result.bodies, on_sheet,
                         [poses.names[k] for k in on_sheet])
            files["contact_sheet"] = "contact_sheet.png"
            files["contact_sheet_frames"] = on_sheet
            stages["contact_sheet"] = round(time.time() - t, 3)
        per_frame = {name: {key: [f[i][key] for f in result.frames] for key in
                            ("inside_under_before", "inside_under_after", "inside_body_before", "inside_body_after")}
                     for i, name in enumerate(outfit.order)}
        report = dict(
            {k: v for k, v in (info or {}).items()}, order=outfit.order, order_source=outfit.order_source,
            order_inferred=outfit.inferred, order_pairs=outfit.pairs,
            order_rule="where two pieces overlap on the rest body, the one farther from the body is outer",
            pieces={n: {"vertices": outfit.meshes[n].num_vertices, "layer": i + 1}
                    for i, n in enumerate(outfit.order)},
            composition={"outfit": {k: v for k, v in asdict(outfit.settings).items() if k != "colours"},
                         "mend": {k: getattr(outfit.mend, k) for k in ("margin", "push_weight", "push_band", "anchor",
                                                                       "iterations", "candidates")}},
            metric="% of each layer's vertices inside the layers under it (off their rim, within push_band deep) "
                   "and inside the posed body, before the push-out (each model's output) and after",
            poses=poses.source, num_frames=len(poses.names), names=poses.names, layers=result.layers,
            per_frame=per_frame, files=files)
        if poses.truth:
            report["vertex_error"] = vertex_errors(result, poses.truth)
        if poses.motion is not None:
            report["motion"] = poses.motion.summary()
            report["guards"] = poses.guards
        stages["total"] = round(time.time() - t0, 3)
        report["seconds"] = stages
        report["seconds_per_frame"] = round((result.seconds["predict"] + result.seconds["compose"])
                                            / max(1, len(poses.names)), 4)
        write_json(out / "outfit.json", report)
    return report


def layer_lines(report: dict) -> list[str]:
    """One line per layer of outfit.json: its penetration before and after, and what it moved."""
    lines = []
    for i, layer in enumerate(report["layers"]):
        under = ", ".join(report["order"][:i]) or "none"
        lines.append(f"layer {layer['layer']} {layer['piece']} (over {under}): inside the layers under it "
                     f"{layer['inside_under_before_pct']:.2f}% -> {layer['inside_under_after_pct']:.2f}% of its "
                     f"vertices, inside the body {layer['inside_body_before_pct']:.2f}% -> "
                     f"{layer['inside_body_after_pct']:.2f}%, moved up to {layer['moved_mm_max']:.0f} mm")
    for name, err in report.get("vertex_error", {}).items():
        lines.append(f"{name} on its {err['poses']} own poses: {err['alone_cm']:.3f} cm alone, "
                     f"{err['composed_cm']:.3f} cm composed (vertex error vs its drapes)")
    return lines


def read_outfit_clip(outfit: OutfitPredictor, path: str | Path, max_frames: int | None = None, **kw) -> Motion:
    """A clip read onto the outfit's body (`read_motion`, kw as it takes), its first `max_frames` (None: all)."""
    motion = read_motion(path, outfit.dataset, **kw)
    if max_frames is None:
        return motion
    return replace(motion, poses=motion.poses[:max_frames], times=motion.times[:max_frames],
                   source_frames=motion.source_frames[:max_frames])
