"""``pbc predict``'s job: the predictor's meshes of a set of poses (OBJ/PLY, the posed bodies, a contact
sheet, ``predict.json``) or of a motion clip (the video, the animated GLB, a contact sheet of frames spread
over it; a mesh per frame when asked)."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from pbc.core.io import (
    human_bytes,
    naming_full_disk,
    require_free_space,
    require_writable_dir,
    save_npy,
    write_json,
)
from pbc.core.validate import as_poses
from pbc.geometry.meshio import write_garment_mesh, write_mesh
from pbc.inference.poses import posed_bodies, run_known, run_pose_range
from pbc.inference.predictor import ClothPredictor, predict_poses
from pbc.jobs.writers import (
    FrameObjWriter,
    VideoWriter,
    camera,
    contact_sheet,
    garment_gltf_vertices,
    render_frames,
    write_glb,
)
from pbc.motion.known import nearest_known, pull_towards_known
from pbc.motion.ranges import clamp_to_range, range_report, range_summary
from pbc.motion.retarget import Motion, motion_settings

OUT_FULL_FIX = ("free space there or give another output folder (--out DIR); every file already written is "
                "complete (each is written whole, then renamed)")
WHAT = "prediction output directory"


def require_room_for_frames(out: Path, first_mesh: Path, count: int, arrays: int) -> None:
    """Refuse before writing the rest when `count` more meshes the size of `first_mesh` (the first one, just
    written) and `arrays` bytes of .npy will not fit: DiskFull naming `out`, the bytes and OUT_FULL_FIX."""
    require_free_space(out, first_mesh.stat().st_size * count + arrays, WHAT, OUT_FULL_FIX)


def predict_to_dir(predictor: ClothPredictor, poses: Tensor, names: Sequence[str], out: Path, fmt: str = "obj",
                   body: bool = False, sheet: int = 12, batch_size: int = 16, model: str | None = None,
                   truth: Tensor | None = None, info: dict | None = None, person=None) -> dict:
    """Predict every pose and write, under `out`: meshes/<name>.<fmt> (garment with UVs and normals;
    <name>_body.<fmt> with `body`), vertices.npy (N, V, 3) float32 metres, poses.npy (N, J, 3, 3),
    contact_sheet.png (the first `sheet` poses), predict.json (what was run, files, and with `truth`
    the vertex error against it). person: whose body each pose is on, in a dataset of several people (None:
    the base person; one int; or (N,)); the garment and the body meshes follow it. Returns predict.json's
    content."""
    t0 = time.time()
    model = predictor.check_model(model)  # before the output dir is made
    predictor.check_person(person)
    out = require_writable_dir(out, "prediction output directory")
    mended: list[dict] = []
    verts = predict_poses(predictor, poses, batch_size, model, person=person, mend_stats=mended)
    ds = predictor.dataset
    bodies = posed_bodies(ds, poses, person) if body or sheet else None
    # a full disk: one DiskFull naming the folder; the room for every mesh is checked once the first is written
    with naming_full_disk(out, WHAT, OUT_FULL_FIX):
        for k, name in enumerate(names):
            write_garment_mesh(out / "meshes" / f"{name}.{fmt}", ds.garment, verts[k],
                               header=[f"{name}: predicted by pbc.predict ({model}"
                                       + (f", {predictor.method} seams)" if model == "patches" else ")")])
            if body:
                write_mesh(out / "meshes" / f"{name}_body.{fmt}", bodies[k], ds.body.faces)
            if k == 0:
                require_room_for_frames(out, out / "meshes" / f"{name}.{fmt}", (len(names) - 1) * (1 + body),
                                        verts.numel() * 4 + poses.numel() * 4)
        save_npy(out / "vertices.npy", verts.numpy().astype(np.float32))
        save_npy(out / "poses.npy", poses.numpy().astype(np.float32))
        result = dict(info or {}, model=model, method=predictor.method if model == "patches" else None,
                      num_poses=len(names), num_vertices=int(verts.shape[1]), format=fmt,
                      files={"meshes": f"meshes/<name>.{fmt}", "vertices": "vertices.npy", "poses": "poses.npy"},
                      names=list(names), mend=mend_report(predictor, mended))
        if person is not None:
            result["person"] = np.broadcast_to(np.asarray(person, np.int64), (len(names),)).tolist()
        titles = list(names)
        if truth is not None:
            err = (verts - truth).norm(dim=-1).mean(1) * 100.0
            result["vertex_error_cm"] = float(err.mean())
            result["per_pose_vertex_error_cm"] = [round(float(e), 4) for e in err]
            titles = [f"{t}: {float(e):.2f} cm" for t, e in zip(titles, err, strict=True)]
        if sheet:
            m = min(int(sheet), len(names))
            contact_sheet(out / "contact_sheet.png", ds.garment.faces.numpy(), verts[:m].numpy(), titles[:m],
                          bodies[:m].numpy(), ds.body.faces.numpy())
            result["files"]["contact_sheet"] = "contact_sheet.png"
        result["seconds"] = round(time.time() - t0, 2)
        write_json(out / "predict.json", result)
        return result


GUARDS = ("nearest", "range", "none")  # conf/motion/sequence.yaml guard


def mend_report(predictor: ClothPredictor, stats: Sequence[dict]) -> dict:
    """What predict.json records of the mend (`ClothPredictor.mend_frames`'s per-frame stats): the settings,
    the frames mended (an edge past the cap), the longest edge against its usual length before and after."""
    if predictor.mend is None:
        return {"on": False, "note": "--no-mend: the models' output as is"}
    hit = [k for k, st in enumerate(stats) if st["stretched"]]
    return {"on": True, "stretch_cap": predictor.mend.stretch_cap, "frames_mended": hit, "num_mended": len(hit),
            "longest_edge_before": round(max((st["ratio_before"] for st in stats), default=0.0), 3),
            "longest_edge_after": round(max((st["ratio_after"] for st in stats), default=0.0), 3),
            "moved_mm_max": round(max((st["moved_mm"] for st in stats), default=0.0), 2)}


def mend_summary(report: dict, frames: int) -> str:
    """One line of what the mend did, for the command's output."""
    if not report.get("on"):
        return "mend: off (--no-mend), the models' output as is"
    if not report["num_mended"]:
        return f"mend: no edge past {report['stretch_cap']:g}x its usual length in {frames} frames"
    return (f"mend: {report['num_mended']} of {frames} frames had an edge past {report['stretch_cap']:g}x its usual "
            f"length (longest {report['longest_edge_before']:.2f}x, {report['longest_edge_after']:.2f}x after; "
            f"vertices moved up to {report['moved_mm_max']:.0f} mm); --no-mend leaves them")


def guard_frames(predictor: ClothPredictor, poses: np.ndarray, guard: str | None = None) -> tuple[np.ndarray, dict]:
    """A clip's poses (N, J, 3, 3) as the model is asked for them, and what predict.json records of them.

    Each frame is judged by how far it is from the poses the model was trained on (`run_known`, over the joints
    it reads): flagged past the limit its own test poses set (conf/motion/sequence.yaml known). `guard`
    (None: conf's): `nearest` turns each flagged frame towards its nearest training pose until it is at the
    limit (pbc.motion.known.pull_towards_known), then clamps each joint into the training poses' joint-angle
    range (a pose near a training pose overall may still bend one joint past every one: the trousers on a
    Bandai Namco walk, a knee); `range` clamps only; `none` leaves them. A model without its training poses at
    hand flags by the joint-angle range, and its `nearest` guard clamps to that range. The joint-angle range
    report is kept either way."""
    settings = motion_settings()
    guard = str(settings.guard) if guard is None else guard
    if guard not in GUARDS:
        raise ValueError(f"--guard {guard!r}: one of {', '.join(GUARDS)} (conf/motion/sequence.yaml guard)")
    names = list(predictor.dataset.body.skeleton.names)
    rng, range_source, range_note = run_pose_range(predictor)
    tol = float(settings.range_tolerance_deg)
    report = range_report(poses, rng, names, tol)
    known = run_known(predictor, float(settings.known.quantile))
    out = np.asarray(poses, np.float64)
    if known is not None:
        near = nearest_known(out, known.poses, known.joints)
        flagged = near.distance_deg > known.limit_deg
        report["known"] = {
            "measure": "RMS angle over the joints the model reads to the nearest training pose (pbc.motion.known)",
            "limit_deg": round(known.limit_deg, 3), "quantile_of_test_poses": float(settings.known.quantile),
            "training_poses": int(len(known.poses)), "read_joints": [names[j] for j in known.joints],
            "distance_deg": [round(float(d), 3) for d in near.distance_deg],
            "flagged": np.flatnonzero(flagged).tolist(), "num_flagged": int(flagged.sum())}
        if guard == "nearest":
            out = pull_towards_known(out, known.poses, known.joints, near, known.limit_deg)
    else:
        report["known"] = None
    if guard in ("range", "nearest"):
        out = clamp_to_range(out, rng, tol)
    report["guard"] = guard if known is not None or guard != "nearest" else "range (no training poses at hand)"
    report["clamped"] = guard != "none"
    report["source"], report["note"] = range_source, range_note
    return out, report


def clip_summary(motion: Motion, report: dict) -> str:
    """What pbc predict and pbc view print of a clip: its notes, how it was read (dialect, units, rest, rate,
    frames) and its frames past the model's data with the guard taken (`guard_frames`'s report)."""
    rest = motion.rest_pose + ("" if motion.rest_frame is None else f", frame {motion.rest_frame} standing in")
    read = (f"clip: {motion.table.dialect or motion.table.name} names, {motion.units}, rest {rest}, "
            f"{motion.fps:g} fps, {len(motion.poses)} frames")
    return "\n".join([*motion.notes, read, range_summary(report)])


def sheet_frames(count: int, sheet: int) -> list[int]:
    """The frames of a clip's contact sheet: `sheet` of its `count` frames spread evenly over it, first and
    last included (all of them when it has fewer)."""
    if sheet <= 0 or count <= 0:
        return []
    return np.unique(np.linspace(0, count - 1, min(int(sheet), count)).round().astype(np.int64)).tolist()


def frame_mesh_bytes(ds, verts: Tensor, bodies: Tensor, fmt: str, body: bool) -> int:
    """The bytes one frame's meshes take (the garment's, + the body's with `body`), measured by writing the first
    frame's with the same writers into a scratch folder."""
    with tempfile.TemporaryDirectory() as scratch:
        garment = Path(scratch) / f"garment.{fmt}"
        if fmt == "obj":
            FrameObjWriter(ds.garment, garment, verts[0])
        else:
            write_garment_mesh(garment, ds.garment, verts[0])
        size = garment.stat().st_size
        if body:
            size += write_mesh(Path(scratch) / f"body.{fmt}", bodies[0], ds.body.faces).stat().st_size
    return size


def clip_output_bytes(ds, verts: Tensor, bodies: Tensor, poses: Tensor, fmt: str, meshes: bool, body: bool,
                      video: str | None, video_frames: int, video_size: tuple[int, int], glb: bool) -> dict[str, int]:
    """What a clip's outputs will take, file (or folder) -> bytes, before any is written: the meshes measured on
    the first frame (`frame_mesh_bytes`) times the frames, the arrays and the GLB from their shapes (the GLB: a
    morph target of every glTF vertex per frame, and the N x N weights of its animation), the video from its
    frames' pixels (conf/motion/sequence.yaml outputs.mp4_bytes_per_pixel, gif_bytes_per_pixel)."""
    n, v = int(verts.shape[0]), int(verts.shape[1])
    sizes = {"vertices.npy": n * v * 12 + 128, "poses.npy": int(poses.numel()) * 4 + 128}
    if meshes:
        sizes["meshes/"] = n * frame_mesh_bytes(ds, verts, bodies, fmt, body)
    if glb:
        g = len(garment_gltf_vertices(ds.garment)[0])
        sizes["garment.glb"] = n * (g * 12 + n * 4 + 4 + 300) + g * 20 + int(ds.garment.faces.shape[0]) * 12
    if video:
        per_pixel = float(motion_settings().outputs[f"{video}_bytes_per_pixel"])
        sizes[f"motion.{video}"] = int(video_frames * video_size[0] * video_size[1] * per_pixel)
    return sizes


def size_warning(sizes: dict[str, int], out: Path, meshes: bool) -> str:
    """The line said before a clip's outputs pass outputs.warn_bytes: how much, where, the largest parts, and how
    to write less."""
    parts = ", ".join(f"{name} {human_bytes(b)}" for name, b in sorted(sizes.items(), key=lambda kv: -kv[1]))
    less = ["fewer frames (--frames START:STOP:STEP, --fps 30 or --max N)"]
    if meshes:
        less.insert(0, "no per-frame meshes (drop --obj, --format and --body)")
    if "garment.glb" in sizes:
        less.append("--no-glb")
    return (f"this writes about {human_bytes(sum(sizes.values()))} in all to {out} ({parts}); to write less: "
            f"{', '.join(less)} (outputs.warn_bytes of conf/motion/sequence.yaml sets when this is said)")


def predict_sequence(predictor: ClothPredictor, motion: Motion, out: Path, fmt: str = "obj", video: str | None = "mp4",
                     glb: bool = True, body: bool = False, guard: str | None = None, batch_size: int = 32,
                     model: str | None = None, info: dict | None = None, progress: bool = True,
                     person: int | None = None, meshes: bool = False, sheet: int = 12) -> dict:
    """A clip's frames through the model in batches, written under `out`: motion.<video> (body + garment, fixed
    front camera at conf/motion/sequence.yaml's video.height, every k-th frame for at most video.max_fps; None:
    none), garment.glb (the garment animated, UVs; with `glb`), contact_sheet.png (`sheet` frames spread over the
    clip, each titled with its index; 0: none), vertices.npy (N, V, 3), poses.npy (N, J, 3, 3), predict.json (the
    mapping, the frames past the model's data and the guard taken against them (`guard_frames`; the flags are
    taken before it), the seconds of each stage), and with `meshes` meshes/frame_NNNNN.<fmt> (garment with UVs
    and normals; + _body with `body`). Before anything is written the outputs' size is estimated
    (`clip_output_bytes`): a folder without room for it is refused (DiskFull naming it and the fix), and past
    outputs.warn_bytes one line says how much and how to write less. person: the dataset's person k the clip is
    played on (None: the base person). Returns predict.json's content."""
    t0 = time.time()
    model = predictor.check_model(model)
    predictor.check_person(person)
    settings = motion_settings()
    ds = predictor.dataset
    names = list(ds.body.skeleton.names)
    poses_np, report = guard_frames(predictor, motion.poses, guard)
    range_source, range_note = report.pop("source"), report.pop("note")
    poses, _ = as_poses(poses_np.astype(np.float32), len(names), joint_names=names, what="motion poses")
    out = require_writable_dir(out, "prediction output directory")
    stages = {"read": round(t0 - (info or {}).get("started", t0), 3)} if info and "started" in info else {}
    t = time.time()
    mended: list[dict] = []
    verts = predict_poses(predictor, poses, batch_size, model, progress, person, mend_stats=mended)
    stages["predict"] = round(time.time() - t, 3)
    frame_names = [f"frame_{k:05d}" for k in range(len(poses))]
    t = time.time()
    bodies = posed_bodies(ds, poses, person)
    stages["pose_body"] = round(time.time() - t, 3)
    v = settings.video
    cam = camera(torch.cat([verts.reshape(-1, 3), bodies.reshape(-1, 3)]), int(v.height), float(v.margin))
    every = max(1, round(motion.fps / float(v.max_fps)))
    shown = torch.arange(0, len(poses), every)
    sizes = clip_output_bytes(ds, verts, bodies, poses, fmt, meshes, body, video, len(shown), (cam[3], cam[4]), glb)
    require_free_space(out, sum(sizes.values()), WHAT, OUT_FULL_FIX)
    if sum(sizes.values()) > float(settings.outputs.warn_bytes):
        print(size_warning(sizes, out, meshes), flush=True)
    t = time.time()
    with naming_full_disk(out, WHAT, OUT_FULL_FIX):
        files = {"vertices": "vertices.npy", "poses": "poses.npy"}
        head = f"predicted by pbc.predict from {motion.table.name} motion ({model} model)"
        if meshes:
            files["meshes"] = f"meshes/frame_NNNNN.{fmt}"
            if fmt == "obj":
                writer = FrameObjWriter(ds.garment, out / "meshes" / f"{frame_names[0]}.obj", verts[0],
                                        header=[f"{frame_names[0]}: {head}"])
                for k in range(1, len(poses)):
                    writer.write(out / "meshes" / f"{frame_names[k]}.obj", verts[k],
                                 header=[f"{frame_names[k]}: {head}"])
            else:
                for k, name in enumerate(frame_names):
                    write_garment_mesh(out / "meshes" / f"{name}.{fmt}", ds.garment, verts[k],
                                       header=[f"{name}: {head}"])
            if body:
                for k, name in enumerate(frame_names):
                    write_mesh(out / "meshes" / f"{name}_body.{fmt}", bodies[k], ds.body.faces)
            stages["meshes"] = round(time.time() - t, 3)
        if video:
            t = time.time()
            vw = VideoWriter(out / f"motion.{video}", motion.fps / every, int(v.crf))
            try:
                for i in shown.split(8):
                    # the garment's back faces culled as the body's: the body fills its openings, so its inside
                    # hardly shows, and culling halves the faces to draw
                    vw.append(render_frames([(bodies[i], ds.body.faces, list(v.body_colour), 0.0, True),
                                             (verts[i], ds.garment.faces, list(v.garment_colour),
                                              float(v.garment_lift), True)], cam, list(v.light), list(v.background)))
            except BaseException as e:
                vw.close(e)
                raise
            vw.close()
            files["video"] = f"motion.{video}"
            files["video_frames"] = {"count": len(shown), "every": every, "fps": round(motion.fps / every, 4),
                                     "height": cam[3], "width": cam[4]}
            stages["video"] = round(time.time() - t, 3)
        if glb:
            t = time.time()
            write_glb(out / "garment.glb", ds.garment, verts.numpy(), motion.times)
            files["glb"] = "garment.glb"
            stages["glb"] = round(time.time() - t, 3)
        on_sheet = sheet_frames(len(poses), sheet)
        if on_sheet:
            t = time.time()
            contact_sheet(out / "contact_sheet.png", ds.garment.faces.numpy(), verts[on_sheet].numpy(),
                          [f"frame {k}" for k in on_sheet], bodies[on_sheet].numpy(), ds.body.faces.numpy())
            files["contact_sheet"] = "contact_sheet.png"
            files["contact_sheet_frames"] = on_sheet
            stages["contact_sheet"] = round(time.time() - t, 3)
        save_npy(out / "vertices.npy", verts.numpy().astype(np.float32))
        save_npy(out / "poses.npy", poses.numpy().astype(np.float32))
        result = dict({k: v for k, v in (info or {}).items() if k != "started"}, model=model,
                      method=predictor.method if model == "patches" else None, num_poses=len(poses),
                      num_vertices=int(verts.shape[1]), format=fmt if meshes else None, files=files,
                      names=frame_names, motion=motion.summary(),
                      notes=list(motion.notes) + ([range_note] if range_note else []),
                      pose_range=report, pose_range_source=range_source, estimated_bytes=sizes,
                      mend=mend_report(predictor, mended))
        if person is not None:
            result["person"] = int(person)
        result["seconds_by_stage"] = stages
        result["seconds"] = round(time.time() - t0, 2)
        write_json(out / "predict.json", result)
        return result
