"""The poses a predictor is asked for: a split of its dataset, an ``.npy`` of rotations or a motion clip
(each pose with the person it is on), the bodies posed by them, and the joint-angle range the model was
trained on (the frames of a clip outside it are flagged)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from pbc.core.validate import as_poses
from pbc.data.trimmed import recorded_known_poses, recorded_training_range
from pbc.geometry.body.base import pose_body
from pbc.inference.predictor import ClothPredictor
from pbc.motion.fit import clear_clip_arms, cleared_note
from pbc.motion.known import nearest_known
from pbc.motion.ranges import PoseRange, angle_range, range_from_record
from pbc.motion.retarget import Motion, check_motion_files, motion_settings, poses_from_clip

log = logging.getLogger(__name__)


class PoseSet(NamedTuple):
    """Poses to predict (`read_poses`), with what is known of them."""

    poses: Tensor  # (N, J, 3, 3)
    names: list[str]  # one per pose: the mesh file names
    truth: Tensor | None  # (N, V, 3) the simulated garment (a dataset split), else None
    people: np.ndarray | None  # (N,) int64 each pose's person (a split of a dataset of several people), else None

    def first(self, n) -> PoseSet:
        """The first `n` poses (checked by `check_max_poses`; None = all)."""
        n = check_max_poses(n)
        if n is None:
            return self
        return PoseSet(self.poses[:n], list(self.names)[:n], None if self.truth is None else self.truth[:n],
                       None if self.people is None else self.people[:n])


def read_poses(source: str | Path, dataset) -> PoseSet:
    """Poses to predict: an .npy of (N, J, 3, 3) / (N, J*9) / (J, 3, 3) rotations, or the name of a split of
    `dataset` (train / val / test; with the simulated vertices and, in a dataset of several people, each
    sample's person). Raises ValueError naming what is wrong (shape, non-rotations, no file)."""
    J = int(dataset.poses.shape[1])
    names = tuple(getattr(dataset.body.skeleton, "names", ())) or None
    path = Path(source)
    if path.suffix == ".npy" or path.exists():
        if not path.is_file():
            raise ValueError(f"pose file {path} does not exist")
        if path.stat().st_size == 0:
            raise ValueError(f"pose file {path} is empty (0 bytes): it was not written completely; save the poses "
                             "again with np.save (an (N, J, 3, 3) or (N, J*9) array)")
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:  # EOFError: a header cut short
            raise ValueError(f"pose file {path} is not a complete numpy .npy array ({type(e).__name__}: {e}): "
                             "it is corrupt or truncated, or another format; save the poses again with "
                             "np.save") from None
        rot, _ = as_poses(arr, J, joint_names=names, what=f"pose file {path}")
        return PoseSet(rot, [f"pose_{k:05d}" for k in range(rot.shape[0])], None, None)
    splits = sorted(dataset.manifest.get("splits") or {})
    if str(source) not in splits:
        raise ValueError(f"--poses {source!r} is neither an .npy file nor a split of the dataset {dataset.dir} "
                         f"(its splits: {splits})")
    idx = dataset.split(str(source))
    if len(idx) == 0:
        shipped = (f": a shipped model carries only its {dataset.manifest['trimmed_from']['split']} split; use "
                   "--poses test, or the run's own dataset") if "trimmed_from" in dataset.manifest else ""
        raise ValueError(f"split {source!r} of {dataset.dir} is empty{shipped}")
    poses = torch.from_numpy(np.asarray(dataset.poses[idx])).float()
    people = getattr(dataset, "person", None)
    return PoseSet(poses, [f"{source}_{int(i):05d}" for i in idx], torch.from_numpy(np.asarray(dataset.verts[idx]))
                   .float(), None if people is None else np.asarray(people)[idx].astype(np.int64))


def check_max_poses(n, what: str = "--max") -> int | None:
    """How many poses to predict: None = all; else an integer >= 1 (0 used to mean all, -1 all but one)."""
    if n is None:
        return None
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"{what} {n!r}: give the number of poses to predict, an integer >= 1 (leave it out for "
                         "every pose)")
    return int(n)


def posed_bodies(dataset, poses: Tensor, person=None, chunk: int = 64) -> Tensor:
    """The body under each pose: poses (N, J, 3, 3) -> vertices (N, Vb, 3), each on its person (None: the base
    person; one int; or (N,) one per pose) of a dataset of several people (`ClothDataset.person_body`)."""
    n = len(poses)
    people = np.zeros(n, np.int64) if person is None else np.broadcast_to(np.asarray(person, np.int64), (n,))
    out = torch.empty(n, *dataset.body.vertices.shape, dtype=dataset.body.vertices.dtype)
    for k in np.unique(people):
        rows = torch.from_numpy(np.flatnonzero(people == k))
        body = dataset.body if person is None else dataset.person_body(int(k))
        for i in range(0, len(rows), chunk):
            out[rows[i:i + chunk]] = pose_body(body, poses[rows[i:i + chunk]])
    return out


def read_motion(path: str | Path, dataset, joint_map: str | Path = "auto", frames: str | None = None,
                fps: float | None = None, allow_rest: bool = False, max_frames: int | None = None,
                rest_frame: int | None = None, trust: bool = False) -> Motion:
    """A motion clip as the dataset's body's poses (Motion.poses (N, J, 3, 3)) through
    `pbc.motion.retarget.poses_from_clip`: its joints matched by `joint_map` (a table of conf/motion or a YAML
    file; "auto": a shipped table knowing every joint, else by name and structure), `frames` a START:STOP:STEP
    slice of its frames, resampled at `fps` (None: as selected); the body's arms, legs or spine left undriven
    refused unless `allow_rest`; more than `max_frames` poses refused (None: conf/motion/sequence.yaml's);
    `rest_frame` the clip frame whose posture is its rest (None: found); a clip failing the sanity check
    (pbc.motion.retarget.sanity_report) refused unless `trust`.
    Arms the retarget hangs inside the torso are raised out of it (`pbc.motion.fit`; a note says so).
    Bad files: one ValueError naming the line and the fix (pbc.motion.bvh); motion settings out of their range
    (conf/bounds.yaml): one ValueError listing them, before the clip is read."""
    check_motion_files()
    motion = poses_from_clip(path, dataset.body.skeleton, joint_map, frames, fps, allow_rest, max_frames,
                             rest_frame, trust)
    motion.poses, turned = clear_clip_arms(motion.poses, dataset.body, motion_settings().clear_arms)
    note = cleared_note(turned)
    if note:
        motion.notes.append(note)
    return motion


def training_pose_range(dataset) -> PoseRange:
    """The per joint and axis [min, max] degrees (swing-twist) over the dataset's training split: the poses a
    run trained on it saw (the run records its dataset; pbc.motion.ranges)."""
    recorded = recorded_training_range(dataset)
    if recorded is not None:  # a shipped model's data holds its training split's range, not its poses
        return recorded
    idx = np.asarray(dataset.split("train"))
    return angle_range(np.asarray(dataset.poses)[idx] if len(idx) else np.asarray(dataset.poses))


def run_pose_range(predictor: ClothPredictor) -> tuple[PoseRange, str, str | None]:
    """The joint-angle range of the poses the predictor's model was trained on, where it came from,
    and a note when it was not the run's own record. The run's record first (RunRecord.pose_range, written by
    pbc.train and carried by pbc pretrained pack): no dataset needed. A run made before runs recorded it falls
    back to its dataset's training split (or a shipped model's data/training.json), saying so."""
    ds = predictor.dataset
    rng = range_from_record(predictor.pose_range_record, ds.body.skeleton.names)
    if rng is not None:
        return unread_joints_free(rng, predictor), f"recorded in the run {predictor.pose_range_run}", None
    where = (f"its shipped data's {ds.dir}/training.json" if recorded_training_range(ds) is not None
             else f"the training split of its dataset {ds.dir}")
    note = (f"the run {predictor.pose_range_run} records no training pose range (made before runs recorded it): "
            f"the range is taken from {where}")
    log.info(note)
    return unread_joints_free(training_pose_range(ds), predictor), where, note


def run_known_poses(predictor: ClothPredictor) -> np.ndarray | None:
    """The poses (M, J, 3, 3) the predictor's model was trained on: a shipped model's recorded ones
    (pbc.data.trimmed.KNOWN_FILE), else its dataset's training split; None for a shipped model packed before
    models carried them (its frames are then judged by the joint-angle range alone)."""
    ds = predictor.dataset
    recorded = recorded_known_poses(ds)
    if recorded is not None:
        return recorded
    if "trimmed_from" in ds.manifest:
        return None
    idx = np.asarray(ds.split("train"))
    return np.asarray(ds.poses)[idx] if len(idx) else None


class KnownPoses(NamedTuple):
    """What a model knows (pbc.motion.known): its training poses, the joints it reads, and the distance (RMS
    degrees over those joints) past which a pose is outside its data."""

    poses: np.ndarray  # (M, J, 3, 3)
    joints: list[int]
    limit_deg: float


def run_known(predictor: ClothPredictor, quantile: float) -> KnownPoses | None:
    """The predictor's `KnownPoses`, the limit the `quantile` of its test split's distances to the training
    poses (its val split's where no test split is at hand); None when its training poses or its held-out poses
    are not at hand."""
    known = run_known_poses(predictor)
    if known is None:
        return None
    ds = predictor.dataset
    held = next((np.asarray(ds.split(s)) for s in ("test", "val") if len(ds.split(s))), None)
    if held is None:
        return None
    joints = [int(j) for j in predictor.read_joints()]
    dist = nearest_known(np.asarray(ds.poses)[held], known, joints).distance_deg
    return KnownPoses(known, joints, float(np.quantile(dist, quantile)))


def unread_joints_free(rng: PoseRange, predictor: ClothPredictor) -> PoseRange:
    """rng with every joint the models do not read (`ClothPredictor.read_joints`) open to any angle
    (-180 to 180): a shirt's data keeps the legs at rest, so a walk's legs would flag every frame and
    the guard would freeze them, though they cannot move the shirt."""
    out = np.array(rng.deg, dtype=np.float64)
    unread = np.setdiff1d(np.arange(len(out)), predictor.read_joints())
    out[unread, :, 0], out[unread, :, 1] = -180.0, 180.0
    return PoseRange(out, rng.chart)
