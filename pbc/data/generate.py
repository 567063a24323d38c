"""Make a dataset of (pose -> draped garment) pairs: resumable, shardable, parallel, reproducible from a seed.

Pipeline: build the body, read (or make) the garment and its cage, shrink-wrap the garment onto the body,
sample all poses up front from the seed, then drape every pose independently and keep the ones that pass
the distortion check (appendix D.6).

Why it survives SIGKILL: every drape result goes to `work/samples/NNNNNN.npz` via a temp file and a rename, so
a sample is either complete or absent. A re-run skips the samples that exist. Pose i depends only on the seed,
and the drape is deterministic (in a worker's reused model too: a drape there depends on its pose alone), so
the merged arrays are byte-identical to an uninterrupted run. Shards (`data.shard=i data.num_shards=n`) take
every n-th pose; the merge (any run with `data.shard=null`) collects them. With `sim.batch_size=k > 1` poses
are draped k at a time in one model (`pbc.sim.batched`): fixed batches of k consecutive poses are the unit of
resume and of sharding. Timings go to `timings.json`, apart from the manifest, so that the manifest is byte-
identical too.
"""

from __future__ import annotations

import ast
import contextlib
import json
import logging
import math
import multiprocessing as mp
import re
import shutil
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from pbc.core import stops
from pbc.core.io import (
    DiskFull,
    LockHeld,
    atomic_path,
    dir_lock,
    hash_arrays,
    load_npz,
    naming_full_disk,
    read_json,
    require_free_space,
    save_npy,
    write_json,
)
from pbc.core.validate import check_config, identity_diff, moving_joints
from pbc.data.dataset import FORMAT_VERSION, ClothDataset, save_embedding
from pbc.data.mirror import MirrorMap, mirror_map, mirror_poses, mirror_verts, symmetrised
from pbc.data.mocap import motion_capture_poses, source_files_hash
from pbc.data.shapes import BodyShapes, person_of, sample_phenotypes, save_shapes, shape_bodies, shapes_hash
from pbc.geometry.body import body_from_config
from pbc.geometry.body.base import Body, pose_body, save_body
from pbc.geometry.body.joint_limits import LIMITS_KEY, resolved_limits
from pbc.geometry.body.skeleton import xzy_angles
from pbc.geometry.cage.base import Cage, save_cage
from pbc.geometry.garment import garment_from_config, garment_needs_body
from pbc.geometry.garment.base import Garment, save_garment_obj
from pbc.geometry.garment.checks import SLEEVE_OFF_DEG, body_region, chart_names_from_cage
from pbc.geometry.meshops import face_areas, face_charts
from pbc.geometry.shrinkwrap import Embedding, shrinkwrap, start_points
from pbc.motion.retarget import check_motion_files, motion_settings
from pbc.sim.poses import modes_record, sample_poses, sampling_settings_from_config

log = logging.getLogger(__name__)


@dataclass
class Scene:
    """Everything a worker needs to drape any pose; built once per process."""
    body: Body
    garment: Garment
    cage: Cage
    embedding: Embedding
    sim: DictConfig
    # the worker's `pbc.sim.batched.BatchedDrape`, built on its first batch (or drape, with sim.reuse_model)
    batched: object | None = None
    made: Garment | None = None  # with garment.made_on_rest: the garment as made, before its drape onto the rest
    # `data.body_shape`: the K people (full bodies, for the drapes' collisions) and their rest shapes
    people: list[Body] | None = None
    shapes: BodyShapes | None = None

    def body_for(self, i: int) -> Body:
        """The body generation sample i is draped on: person i mod K, or the one body."""
        return self.body if self.people is None else self.people[person_of(i, self.shapes)]


def dataset_dir(cfg: DictConfig) -> Path:
    return Path(cfg.data.dir)


def fingerprint(cfg: DictConfig, scene: Scene) -> dict:
    """What makes two runs produce the same dataset. A directory made with another one is refused."""
    fp = {
        **_cheap_fingerprint(cfg, scene.made or scene.garment),  # the drape onto the rest is the embedding's
        "body_hash": hash_arrays(scene.body.vertices, scene.body.faces, scene.body.weights, scene.body.parts),
        # the rest-pose embedding and collision parts: a change to the shrink-wrap changes the data
        "embedding_hash": hash_arrays(scene.embedding.face, scene.embedding.bary, scene.embedding.part,
                                      *([] if scene.embedding.lift is None else [scene.embedding.lift])),
    }
    if _shapes(scene) is not None:  # only then: a single-body manifest keeps its bytes
        fp["shapes_hash"] = shapes_hash(scene.shapes)
    return fp


def _cheap_fingerprint(cfg: DictConfig, garment: Garment) -> dict:
    """The fingerprint keys that need no body or shrink-wrap (the garment is rebuilt in ~0.1 s)."""
    fp = {
        "format_version": FORMAT_VERSION,
        "seed": int(cfg.data.seed),
        "num_samples": int(cfg.data.num_samples),
        "garment_hash": hash_arrays(garment.vertices, garment.faces, garment.uv),
        "sim": sim_fingerprint(cfg.sim),
    }
    people = sample_phenotypes(cfg)
    if people is not None:  # only with data.body_shape: single-body datasets keep their fingerprint
        fp["body_shapes"] = {"keys": list(people[0]), "values": people[1].tolist()}
    # each key below only when its setting is away from its default: existing datasets keep their fingerprint
    data = cfg.data
    if data.get("poses") is not None:  # the clips' content (not where they lie) and how they are mixed
        role = str(data.get("poses_role") or "train")
        fp["pose_source"] = {"files": source_files_hash(data.poses, list(data.get("poses_holdout") or ()), role),
                             "sampled_fraction": float(data.get("poses_sampled_fraction") or 0.0),
                             "joint_map": str(data.get("poses_joint_map") or "auto"),
                             "allow_rest": bool(data.get("poses_allow_rest")),
                             "clear_arms": OmegaConf.to_container(motion_settings().clear_arms)}
    if data.get("mirror"):
        fp["mirror"] = {"tolerance": float(data.mirror_tolerance)}
    if cfg.garment.get("made_on_rest") is not None:  # the garment hash is the made garment's, before its drape
        fp["garment_made_on_rest"] = OmegaConf.to_container(cfg.garment.made_on_rest)
        if forearms_to_rest(cfg.garment):  # datasets made before kept the forearms as made
            fp["garment_forearms_to_rest"] = True
    modes = modes_record(sampling_settings_from_config(cfg.body.sampling))
    if modes:  # the sampler's extra ranges (hanging arms, walking legs) change the poses
        fp["sampling_modes"] = modes
    if cfg.body.get(LIMITS_KEY) is not None:  # limits from a file (+body.limits_file): their values, not the path
        fp["joint_limits"] = resolved_limits(cfg.body)
    return fp


def sim_fingerprint(sim: DictConfig) -> dict:
    """The simulation settings that change the data: machine-specific keys (where kernels are cached,
    which device) and how often the host polls do not."""
    keys = {k: v for k, v in OmegaConf.to_container(sim, resolve=True).items()
            if k not in ("kernel_cache_dir", "device", *_unfingerprinted_batch_keys(sim))}
    if not keys.get("fold_frames"):  # off: the stop rule datasets were made with before it existed
        keys.pop("fold_frames", None)
    return keys


def config_mismatch(cfg: DictConfig, manifest: dict, full: bool = False) -> list[str]:
    """Generation keys of `cfg` that disagree with a dataset's manifest, one line each (empty: they agree).

    Cheap by default (seed, sample count, sim settings, format version, garment hash); full=True builds the
    whole scene as generation does and compares every fingerprint key (seconds).
    """
    want = (fingerprint(cfg, build_scene(cfg)[0]) if full
            else _cheap_fingerprint(cfg, garment_from_config(cfg.garment, _body_if_needed(cfg))[0]))
    recorded = {k: manifest.get(k) for k in want}
    if isinstance(recorded.get("pose_source"), dict):  # the manifest's also holds each row's clip and frame
        recorded["pose_source"] = {k: recorded["pose_source"].get(k) for k in want["pose_source"]}
    return identity_diff(recorded, want, names=("dataset", "config"))


def check_matches_config(cfg: DictConfig, data: ClothDataset, full: bool = False) -> None:
    """Refuse to train on a dataset made with other generation settings than `cfg` (see config_mismatch)."""
    diff = config_mismatch(cfg, data.manifest, full=full)
    if diff:
        raise ValueError(
            f"dataset {data.dir} was made with other settings than this config:\n  - " + "\n  - ".join(diff)
            + "\nDrop those overrides to train on it, or set data.dir to a new directory (data.name=...) so that "
            "`python -m pbc.generate` makes the data the config asks for."
        )


def batch_size(sim: DictConfig) -> int:
    """Poses draped at once (`sim.batch_size`, 1 = the single-world drape)."""
    k = int(sim.get("batch_size", 1) or 1)
    if k < 1:
        raise ValueError(f"sim.batch_size must be >= 1, got {k}")
    return k


def batch_worlds(sim: DictConfig) -> int:
    """Worlds in the batched model (`sim.batch_worlds`, default the batch size)."""
    return min(batch_size(sim), int(sim.get("batch_worlds") or batch_size(sim)))


def reuses_model(sim: DictConfig) -> bool:
    """Whether single drapes go through the process's one reused model (`sim.reuse_model`; absent, as in
    the configs of datasets made before it existed: the per-drape model)."""
    return batch_size(sim) == 1 and bool(sim.get("reuse_model", False))


def _unfingerprinted_batch_keys(sim: DictConfig) -> tuple[str, ...]:
    """With batch_size 1 no batch key changes the data, so a single-world dataset keeps the
    fingerprint (and manifest bytes) it had before batching existed. In a batched run they all do,
    to rounding: which poses share the model and when a stopped world takes the next one.
    `reuse_model` counts only when it is on and drapes are single (batches always reuse their model),
    so a dataset made before it existed matches `sim.reuse_model=false`."""
    if batch_size(sim) == 1:
        return ("batch_size", "batch_worlds", "batch_check_every", "batch_world_spacing",
                *(() if reuses_model(sim) else ("reuse_model",)))
    return ("reuse_model",)


def _body_if_needed(cfg: DictConfig) -> Body | None:
    """The body the garment is built on, only for a garment built from it (sized to it): the cheap fingerprint
    stays cheap otherwise."""
    return made_on_body(cfg) if garment_needs_body(cfg.garment) else None


def made_on_body(cfg: DictConfig, body: Body | None = None) -> Body:
    """The body the garment is made on: `body` (built when None) or, with ``garment.made_on_rest``, the
    body turned to that rest pose (keys of ``body.rest``)."""
    made_on = cfg.garment.get("made_on_rest")
    if made_on is None:
        return body if body is not None else body_from_config(cfg.body)
    if "rest" not in cfg.body:
        raise ValueError(f"garment.made_on_rest={OmegaConf.to_container(made_on)} turns the body's rest pose, and "
                         f"body.kind={cfg.body.get('kind', 'mannequin')!r} has none to turn: use body=anny, or "
                         "garment.made_on_rest=null")
    turned = OmegaConf.merge(cfg.body, {"rest": made_on})
    return body_from_config(turned)


def forearms_to_rest(gcfg: DictConfig) -> bool:
    """Whether the drape onto the rest (``garment.made_on_rest``) also turns each forearm to the body's rest
    elbow (``garment.made_on_forearms: to_rest``, conf/garment/tshirt.yaml's) or leaves it as made (``as_made``,
    and a run's config recorded before the key: its data was made so)."""
    return gcfg.get("made_on_rest") is not None and gcfg.get("made_on_forearms", "as_made") == "to_rest"


def drape_onto_rest(cfg: DictConfig, garment: Garment, cage: Cage, made_on: Body, body: Body) -> Garment:
    """The garment made on `made_on` (the body turned to ``garment.made_on_rest``) as it lies on `body`'s
    own rest pose: embedded on `made_on`, its arms turned to `body`'s rest arm angle, its forearms to `body`'s rest
    elbow (``garment.made_on_forearms``) and its thighs back by the legs' difference (``legs_apart_deg``), and
    draped there by the simulator; made left/right symmetric again with ``data.mirror``. A re-rest a person would
    do by putting the shirt on and lowering the arms: the armpits fold as cloth does, where re-skinning the sleeves
    alone leaves a wide shirt's sides round the lowered arms. One ValueError when the drape is discarded."""
    from pbc.geometry.body.anny import arm_angle_deg, forearms_like, rest_turn  # noqa: PLC0415 - only Anny re-rests

    embedding, _ = shrinkwrap(garment, cage, made_on, cfg.garment.shrinkwrap)
    legs = (cfg.body.rest.get("legs_apart_deg") or 0.0, cfg.garment.made_on_rest.get("legs_apart_deg"))
    legs_back = None if legs[1] is None else float(legs[0]) - float(legs[1])
    pose = rest_turn(made_on.skeleton, arm_angle_deg(body.skeleton), legs_back)
    if forearms_to_rest(cfg.garment):  # each joint is turned by one of the two at most: their product is both
        pose = pose @ forearms_like(made_on.skeleton, body.skeleton)
    pose = pose[0].float().numpy()
    t0 = time.perf_counter()
    rec = drape_pose(Scene(made_on, garment, cage, embedding, cfg.sim), pose)
    if not rec["ok"]:
        raise ValueError(f"garment.made_on_rest: the garment made on the body's rest turned to "
                         f"{OmegaConf.to_container(cfg.garment.made_on_rest)} was draped onto the body's own rest "
                         f"and the drape was discarded ({rec['reason']}): make it on a rest nearer the body's "
                         "(garment.made_on_rest) or without it (garment.made_on_rest=null)")
    x = rec["positions"].astype(np.float64)
    if cfg.data.get("mirror"):
        x = symmetrised(x, garment.vertices.double().numpy(), garment.faces.numpy())
    log.info("garment made on the body turned to %s, draped onto its own rest in %d frames (%.1f s)",
             OmegaConf.to_container(cfg.garment.made_on_rest), rec["iterations"], time.perf_counter() - t0)
    return replace(garment, vertices=torch.from_numpy(x).to(garment.vertices.dtype))


def scene_garment(cfg: DictConfig, body: Body, rested: np.ndarray | None = None
                  ) -> tuple[Garment, Cage, Garment | None]:
    """The garment and its cage on `body`'s rest pose: built on it, or made on the turned body of
    ``garment.made_on_rest`` and draped onto it (`drape_onto_rest`; `rested` (V, 3): that drape's positions, made
    already); and the garment as made (None: the same)."""
    made_on = made_on_body(cfg, body)
    garment, cage = garment_from_config(cfg.garment, made_on)
    if made_on is body:
        return garment, cage, None
    if rested is not None:
        return replace(garment, vertices=torch.as_tensor(rested, dtype=garment.vertices.dtype)), cage, garment
    return drape_onto_rest(cfg, garment, cage, made_on, body), cage, garment


def build_scene(cfg: DictConfig, rested: np.ndarray | None = None) -> tuple[Scene, dict]:
    """Body, garment, cage and rest-pose embedding from the config (`rested`: see `scene_garment`). Returns the
    scene and wrap stats."""
    sample_phenotypes(cfg)  # a bad data.body_shape is refused before any body is built
    body = body_from_config(cfg.body)
    garment, cage, made = scene_garment(cfg, body, rested)
    embedding, wrap_stats = shrinkwrap(garment, cage, body, cfg.garment.shrinkwrap)
    # the garment and its embedding are the base body's; the people share its mesh, so the embedding holds
    people, shapes = shape_bodies(cfg, body)
    return Scene(body, garment, cage, embedding, cfg.sim, people=people, shapes=shapes, made=made), wrap_stats


def drape_pose(scene: Scene, pose: np.ndarray, index: int = 0) -> dict:
    """Skin the embedded garment onto the posed body (of generation sample `index`'s person, when the data
    spans several) and drape it, in the scene's reused one-world model with `sim.reuse_model` (built on the
    first call), else in a model built for this drape. Returns the per-sample record."""
    if reuses_model(scene.sim):
        return drape_batch(scene, pose[None], [index])[0]
    t0 = time.perf_counter()
    body = scene.body_for(index)
    rot = torch.from_numpy(pose)[None].float()
    body_v = pose_body(body, rot)  # (1, Vb, 3)
    start = start_points(body_v, body.faces, scene.embedding, float(scene.sim.thickness))[0]
    t1 = time.perf_counter()
    from pbc.sim.drape import drape_garment  # noqa: PLC0415 - the simulator only to drape: pbc.train imports this module

    res = drape_garment(scene.garment, start, body_v[0], body, scene.embedding, scene.sim)
    t2 = time.perf_counter()
    return _drape_record(scene, res, t1 - t0, t2 - t1)


def _drape_record(scene: Scene, res, t_skin: float, t_drape: float) -> dict:
    """What a worker reports of one drape: the positions, the keep/discard decision and the costs."""
    from pbc.sim.drape import check_garment_result  # noqa: PLC0415 - the simulator only to judge a drape

    ok, reason = check_garment_result(res, scene.garment, scene.sim)
    return {
        "positions": res.positions.astype(np.float32),
        "ok": ok,
        "reason": reason,
        "residual": float(res.residual),
        "residual_max": float(res.residual_max),
        "iterations": int(res.iterations),
        "t_skin": t_skin,
        "t_drape": t_drape,
    }


def drape_batch(scene: Scene, poses: np.ndarray, indices=None) -> list[dict]:
    """`drape_pose` for B poses (B, J, 3, 3) at once in the worker's batched model (built on the first
    call, reused after); `indices` (B,): their generation sample ids (whose person drapes them; None: 0..B-1).
    Per-sample times are the batch's shared equally. The people share faces and parts: one model serves all."""
    t0 = time.perf_counter()
    starts, bodies = [], []
    indices = range(len(poses)) if indices is None else indices
    for pose, i in zip(poses, indices, strict=True):  # one at a time: the same skinning, bit for bit, as drape_pose
        body = scene.body_for(i)
        body_v = pose_body(body, torch.from_numpy(pose)[None].float())
        starts.append(start_points(body_v, body.faces, scene.embedding, float(scene.sim.thickness))[0].numpy())
        bodies.append(body_v[0].numpy())
    t1 = time.perf_counter()
    if scene.batched is None:

        from pbc.sim.batched import batched_drape_for_garment  # noqa: PLC0415 - the simulator only to drape

        scene.batched = batched_drape_for_garment(scene.garment, scene.body, scene.embedding, scene.sim,
                                                  batch_worlds(scene.sim), starts[0], bodies[0])
    results = scene.batched.run(np.stack(starts), np.stack(bodies))
    t2 = time.perf_counter()
    return [_drape_record(scene, res, (t1 - t0) / len(poses), (t2 - t1) / len(poses)) for res in results]


_SCENE: Scene | None = None
_INIT_ERROR: BaseException | None = None  # a worker's failed start, raised by its first job (see _init_worker)
_SAMPLE_FIX = "free space there or set paths.data_dir to a disk with room, then run the same command again"


def _init_worker(cfg_yaml: str, threads: int, rested: np.ndarray | None = None) -> None:
    """A drape worker's start: its scene, once (with the parent's garment as draped onto the rest, `rested`,
    when it was made on another: the same bytes, without that drape again). An error is kept and raised by the
    worker's first job, so the parent gets the exception itself (a failing initializer would only print it and
    break the pool)."""
    global _SCENE, _INIT_ERROR
    try:
        torch.set_num_threads(threads)
        cfg = OmegaConf.create(cfg_yaml)
        _SCENE, _ = build_scene(cfg, rested)
    except Exception as err:  # re-raised in _scene() by the first job, then the parent stops every worker
        _INIT_ERROR = err


def _scene() -> Scene:
    if _INIT_ERROR is not None:
        raise _INIT_ERROR
    return _SCENE


def _write_sample(path: str, rec: dict) -> None:
    with naming_full_disk(path, "sample file", _SAMPLE_FIX), atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, positions=rec.pop("positions"), meta=np.array(json.dumps(rec, sort_keys=True)))


def _work(args: tuple[int, np.ndarray, str]) -> tuple[int, bool, str]:
    i, pose, path = args
    rec = drape_pose(_scene(), pose, i)
    _write_sample(path, rec)
    return i, rec["ok"], rec["reason"]


def _work_batch(jobs: list[tuple[int, np.ndarray, str]]) -> list[tuple[int, bool, str]]:
    """Drape one batch and write its samples (each atomically): a kill loses at most this batch."""
    recs = drape_batch(_scene(), np.stack([pose for _, pose, _ in jobs]), [i for i, _, _ in jobs])
    out = []
    for (i, _, path), rec in zip(jobs, recs, strict=True):
        if not Path(path).is_file():  # left by a batch killed while writing: the same bytes, keep it
            _write_sample(path, rec)
        out.append((i, rec["ok"], rec["reason"]))
    return out


@contextlib.contextmanager
def _standard_start_method(method: str = "spawn"):
    """Make multiprocessing's global start method a standard one for the block.

    A spawned child re-applies its parent's *global* start method (multiprocessing.spawn's preparation
    data), whatever context started it. Inside a joblib (loky) worker -- a Hydra joblib launcher's job --
    that method is 'loky', which a fresh child cannot find: every drape worker died at start with
    "ValueError: cannot find context for 'loky'" and multiprocessing.Pool respawned it forever."""
    current = mp.get_start_method(allow_none=True)
    if current is None or current in mp.get_all_start_methods():
        yield
        return
    mp.set_start_method(method, force=True)
    try:
        yield
    finally:
        with contextlib.suppress(ValueError):
            mp.set_start_method(current, force=True)


def map_in_workers(fn, jobs: list, workers: int, initializer=None, initargs: tuple = ()):
    """Yield `fn(job)` for every job (in completion order) from `workers` fresh processes.

    Spawned explicitly (spawn, not fork: warp and torch threads do not survive a fork; and never the
    inherited default, which a launcher may have set to its own method, see _standard_start_method). Fails
    fast: the first job that raises (or a worker whose `initializer` raised) stops every worker and the
    exception is re-raised here; a worker killed from outside (out of memory) is a RuntimeError saying so.
    A stop (SIGINT, SIGTERM: pbc.core.stops) stops every worker before it leaves.
    """
    ctx = mp.get_context("spawn")
    # SIGINT and SIGTERM as exceptions here (the entry floor's, or set for this block): the `finally` stops
    # the workers (Python's default for SIGTERM ends the process past it, and the workers drape on as orphans)
    with _standard_start_method("spawn"), stops.handled():
        ex = ProcessPoolExecutor(workers, mp_context=ctx, initializer=initializer, initargs=initargs)
        try:
            pending = {ex.submit(fn, job) for job in jobs}
            while pending:
                # FIRST_COMPLETED, not FIRST_EXCEPTION: that one waits for every job when none fails, so
                # nothing (progress included) came back before the last drape; a failure still surfaces as
                # soon as its future completes
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    try:
                        yield fut.result()
                    except BrokenProcessPool as err:
                        raise RuntimeError(
                            "a drape worker process died without an error (killed from outside, e.g. by the "
                            "out-of-memory killer); run again with fewer data.workers (data.workers=1 drapes "
                            "in this process and shows any error here)"
                        ) from err
        finally:
            _stop(ex)


def _stop(ex: ProcessPoolExecutor) -> None:
    """Shut a pool down now: queued jobs cancelled, running workers terminated (a drape can take minutes)."""
    # taken before shutdown, which empties `_processes` (Python 3.11): read after it, no worker was terminated
    # and a worker in the middle of a drape ran on after its job had ended
    procs = list((getattr(ex, "_processes", None) or {}).values())
    ex.shutdown(wait=False, cancel_futures=True)
    terminate = getattr(ex, "terminate_workers", None)  # Python 3.14+
    if terminate is not None:
        terminate()
        return
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(5)
    # a worker still alive 5 s after SIGTERM is killed (seen once: the clean-clone CI on two xdist workers, the
    # machine loaded, had a spawned worker alive 15 s after it; the cause was not found)
    for p in procs:
        with contextlib.suppress(Exception):
            if p.is_alive():
                p.kill()
                p.join(5)


def _sample_path(work: Path, i: int) -> Path:
    return work / "samples" / f"{i:06d}.npz"


def _read_sample(path: Path) -> tuple[np.ndarray, dict]:
    fix = "delete it and re-run to redo that sample"
    z = load_npz(path, ("positions", "meta"), "sample file", fix)  # a truncated zip is named, not BadZipFile
    try:
        return z["positions"], json.loads(str(z["meta"]))
    except ValueError as err:
        raise ValueError(f"sample file {path} is corrupt ({err}); {fix}") from err


# config_mismatch's line of one setting: "sim.reuse_model: dataset True vs config False"
_DIFF_LINE = re.compile(r"(?P<key>[\w.]+): dataset (?P<there>.+) vs config (?P<here>.+)")
# a setting a dataset's fingerprint leaves out at this value (sim_fingerprint): absent = it
_ABSENT_MEANS = {"sim.reuse_model": False, "sim.fold_frames": 0}
# the fingerprint's keys that are no setting of their own: the setting a user changes for each
_SETTING_OF = {"seed": "data.seed", "num_samples": "data.num_samples", "garment_hash": "garment (its mesh)",
               "format_version": "pbc's dataset format"}


def _printed_value(text: str, key: str):
    """A value as config_mismatch printed it (its repr), '<absent>' read as the value its absence stands for."""
    if text == "'<absent>'":
        return _ABSENT_MEANS.get(key, "<absent>")
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def _override_text(key: str, value) -> str:
    return f"{key}={str(value).lower() if isinstance(value, bool) else value}"


def other_settings_message(cfg: DictConfig, out: Path, record: dict, tops: list[str]) -> str:
    """The refusal of a dataset folder `out` whose record (its manifest or fingerprint) was made with other
    settings under the fingerprint's top keys `tops` (`sim`, `seed`, ...): one line naming each setting that
    differs (`sim.reuse_model`), its value there and here, the overrides that go on with the dataset when every
    difference is a setting, and the other fixes."""
    diffs = [d for line in config_mismatch(cfg, record)
             if (d := _DIFF_LINE.fullmatch(line)) and d["key"].split(".", 1)[0] in tops]
    if not diffs:
        return (f"{out} holds a dataset made with a different {', '.join(tops)}; choose another data.dir or delete "
                f"{out} to regenerate")
    shown, goes_on = [], []
    for d in diffs:
        key = _SETTING_OF.get(d["key"], d["key"])
        there, here = _printed_value(d["there"], d["key"]), _printed_value(d["here"], d["key"])
        shown.append(f"{key} {_override_text('', there)[1:]} there, {_override_text('', here)[1:]} here")
        if key == d["key"] and there != "<absent>":
            goes_on.append(_override_text(key, there))
    keep = f"give {' '.join(goes_on)} to go on with it, " if len(goes_on) == len(diffs) else ""
    return (f"{out} holds a dataset made with other settings ({'; '.join(shown)}): {keep}make a new dataset "
            f"elsewhere (data.name=NAME or data.dir=DIR), or delete {out} to make it again")


def _check_or_write_fingerprint(out: Path, fp: dict, cfg: DictConfig) -> None:
    """Refuse `out` when its dataset (finished or in progress) was made with another fingerprint
    (`other_settings_message`), else record `fp` for a dataset begun here."""
    path = out / "work" / "fingerprint.json"
    for existing in (out / "manifest.json", path):
        if existing.is_file():
            record = read_json(existing, "dataset metadata")
            # a manifest's pose_source holds each row's clip and frame beside the fingerprint's keys
            old = {k: record.get(k) for k in fp}
            if isinstance(old.get("pose_source"), dict):
                old["pose_source"] = {k: old["pose_source"].get(k) for k in fp["pose_source"]}
            if old != fp:
                raise ValueError(other_settings_message(cfg, out, record, sorted(k for k in fp if old[k] != fp[k])))
            return
    write_json(path, fp)


def generate(cfg: DictConfig, wait_s: float = 0.0) -> Path:
    """Generate (or resume, or merge) the dataset configured by `cfg.data`. Returns its directory.

    A second generator on the same directory is refused (pbc.core.io.LockHeld names the holder): a whole run
    or merge holds `.generate.lock` exclusively; shard runs share it and each holds its own shard lock,
    so shards of one dataset run side by side but never beside a merge (which removes work/).
    `wait_s` > 0 waits that long for the holder instead, with a log line (training's `ensure_dataset`:
    the jobs of a multirun started from nothing wait for the one making the data, then find it finished).
    """
    check_config(cfg)  # typed values and ranges before any folder is made: data.shard=1.0, sim.fps=0
    check_motion_files()  # the poses' clips and clear_arms (conf/motion/sequence.yaml) are read here too
    out = dataset_dir(cfg)
    if (out / "manifest.json").is_file() and cfg.data.shard is None:
        return _generate(cfg)  # finished: only reads (the directory may be read-only)
    shard = cfg.data.shard
    with (stops.step(f"making the dataset {out}", STOP_NOTE),
          _lock_or_wait(out / ".generate.lock", f"dataset {out}", shard is not None, wait_s)):
        if shard is None:
            return _generate(cfg)
        with _lock_or_wait(out / f".generate-shard{shard}.lock", f"shard {shard} of dataset {out}", False, wait_s):
            return _generate(cfg)


# what a stop line adds to the command that continues a stopped generation
STOP_NOTE = "the same command resumes: the finished drapes in work/samples are kept"


def _lock_or_wait(path: Path, what: str, shared: bool, wait_s: float) -> contextlib.ExitStack:
    """`dir_lock`, held by the returned stack; when another process holds it and `wait_s` > 0, one log line
    naming the holder, then up to `wait_s` seconds of waiting (LockHeld after that, naming the setting)."""
    stack = contextlib.ExitStack()
    try:
        stack.enter_context(dir_lock(path, what, shared=shared))
        return stack
    except LockHeld as err:
        if not wait_s or wait_s <= 0:
            raise
        log.warning("%s: waiting for it to finish (at most %.0f s, data.lock_wait_s)",
                    str(err).split("; wait for it", 1)[0], wait_s)
    t0 = time.monotonic()
    try:
        stack.enter_context(dir_lock(path, what, shared=shared, timeout=wait_s))
    except LockHeld as err:
        raise LockHeld(
            f"{str(err).split('; wait for it', 1)[0]}, still after waiting {wait_s:.0f} s (data.lock_wait_s); "
            "wait for it to finish and run again, or raise data.lock_wait_s"
        ) from None
    log.info("%s is free after %.0f s of waiting: going on", what, time.monotonic() - t0)
    return stack


def _generate(cfg: DictConfig) -> Path:
    out = dataset_dir(cfg)
    data = cfg.data
    if (out / "manifest.json").is_file() and data.shard is None:
        # already finished; still refuse a directory made with another configuration
        scene, _ = build_scene(cfg)
        _check_or_write_fingerprint(out, fingerprint(cfg, scene), cfg)
        return out
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    log.info("building the scene: body, garment, cage and the rest-pose shrink-wrap")
    scene, wrap_stats = build_scene(cfg)
    timings["scene"] = time.perf_counter() - t0
    # the wrap's distortion, which decides whether drapes can pass the discard check: said, not only stored
    log.info("shrink-wrap: wrapped/pattern area per face mean %.2f, max %.2f; most stretched patch %s (%.2fx)",
             wrap_stats["area_after_mean"], wrap_stats["area_after_max"], wrap_stats.get("patch_stretch_worst"),
             wrap_stats.get("patch_stretch_max", float("nan")))
    log.info("scene built in %.1f s (%d body, %d garment vertices)", timings["scene"],
             scene.body.vertices.shape[0], scene.garment.vertices.shape[0])
    work = out / "work"
    fp = fingerprint(cfg, scene)
    # bad clips and an asymmetric garment are refused here, before anything is written
    t0 = time.perf_counter()
    poses, angles, pose_stats, sources = dataset_poses(cfg, scene)
    timings["sample_poses"] = time.perf_counter() - t0
    mirror = scene_mirror_map(cfg, scene, poses)
    (work / "samples").mkdir(parents=True, exist_ok=True)
    _check_or_write_fingerprint(out, fp, cfg)

    n_shards = int(data.num_shards)
    shards = range(n_shards) if data.shard is None else [int(data.shard)]
    if any(not 0 <= s < n_shards for s in shards):
        raise ValueError(f"data.shard={data.shard} is out of range for data.num_shards={n_shards}")
    # poses go in fixed batches of sim.batch_size (b*k ... b*k+k-1) whatever was done before, so a
    # pose always shares its batch with the same poses; shards take every n-th batch (every n-th pose
    # when k = 1); a batch with any sample missing is draped again whole
    k = batch_size(cfg.sim)
    batches = [list(range(b * k, min((b + 1) * k, len(poses)))) for b in range(math.ceil(len(poses) / k))]
    todo = [batches[b] for s in shards for b in range(s, len(batches), n_shards)
            if not all(_sample_path(work, i).is_file() for i in batches[b])]
    _report_progress(work, len(poses), k, n_shards, data.shard, todo)
    t0 = time.perf_counter()
    _run_drapes(cfg, scene, poses, todo, work)
    timings["drape_wall"] = time.perf_counter() - t0
    if data.shard is not None:
        return out
    merge(out, poses, angles, fp, wrap_stats, pose_stats, scene, timings, batch=k, num_shards=n_shards,
          sources=sources, mirror=mirror, workers=max(1, int(data.workers or 1)))
    return out


def dataset_poses(cfg: DictConfig, scene: Scene) -> tuple[np.ndarray, np.ndarray, dict, dict | None]:
    """The generation poses (N, J, 3, 3) float32, their Euler angles (N, J, 3) float32, the pose stats, and
    each pose's source (None: all from the D.3 sampler; else `pbc.data.mocap.motion_capture_poses`'s).
    Pose i depends only on the config and the seed."""
    data = cfg.data
    settings = sampling_settings_from_config(cfg.body.sampling)
    n, seed, skel = int(data.num_samples), int(data.seed), scene.body.skeleton
    if data.get("poses") is not None:
        return motion_capture_poses(data.poses, n, float(data.get("poses_sampled_fraction") or 0.0), seed, skel,
                                    scene.body, settings, str(data.get("poses_joint_map") or "auto"),
                                    bool(data.get("poses_allow_rest")), list(data.get("poses_holdout") or ()),
                                    str(data.get("poses_role") or "train"))
    poses, pose_stats = sample_poses(skel, n, seed, scene.body, settings)
    angles = np.asarray(pose_stats.pop("angles_deg"), dtype=np.float32)
    return poses.numpy().astype(np.float32), angles, pose_stats, None


MIRROR_PROBES = 4  # dataset poses the body's symmetry is checked under (and the rest pose)


def scene_mirror_map(cfg: DictConfig, scene: Scene, poses: np.ndarray) -> MirrorMap | None:
    """With data.mirror: the scene's checked mirror map (pbc.data.mirror; an asymmetric skeleton, body or
    garment is one ValueError), probed under the first dataset poses; None without."""
    if not cfg.data.get("mirror"):
        return None
    bodies = scene.people if scene.people is not None else [scene.body]
    return mirror_map(bodies, scene.garment.vertices.cpu().numpy(), scene.garment.faces.cpu().numpy(),
                      float(cfg.data.mirror_tolerance), poses[:MIRROR_PROBES],
                      where=f"the garment ({len(scene.garment.vertices)} vertices)")


def _report_progress(work: Path, num_poses: int, k: int, n_shards: int, shard, todo: list[list[int]]) -> None:
    """One log line per shard that a killed run left unfinished, by name: a resumed shard says so, and a
    merge that finds shards unfinished names them before draping what they left (here, in one job)."""
    if shard is not None:
        total = len(range(int(shard), math.ceil(num_poses / k), n_shards))  # its batches
        if 0 < len(todo) < total:
            log.info("shard %s of %d: resuming, %d of its %d batches already made", shard, n_shards,
                     total - len(todo), total)
        return
    if n_shards > 1 and todo:
        for s, ids in sorted(missing_shards(work, num_poses, k, n_shards).items()):
            log.warning("shard %d of %d is unfinished (%d samples missing, first %s): draping them in this merge "
                        "job; to spread them instead, run data.shard=%d again first", s, n_shards, len(ids), ids[:5], s)


def _run_drapes(cfg: DictConfig, scene: Scene, poses: np.ndarray, todo: list[list[int]], work: Path) -> None:
    """Drape the batches in `todo` (lists of pose indices; batches of one go through `drape_pose`)."""
    if not todo:
        return
    batched = batch_size(cfg.sim) > 1
    workers = max(1, min(int(cfg.data.workers), len(todo)))
    jobs = [[(i, poses[i], str(_sample_path(work, i))) for i in batch] for batch in todo]
    if not batched:
        jobs = [job for batch in jobs for job in batch]
    work_fn = _work_batch if batched else _work
    n_samples = sum(map(len, todo))
    bar = progress_bar(n_samples, f"drape ({workers} workers)", "sample")
    if cfg.sim.get("kernel_cache_dir") and not _warp_cache_filled(cfg.sim):
        log.info("the first drape of each worker compiles warp's kernels into %s (about a minute on a CPU; "
                 "later runs reuse them)", cfg.sim.get("kernel_cache_dir"))
    discarded, done = 0, 0
    stops.at(f"the drapes ({n_samples} to make)")
    if workers == 1:
        global _SCENE, _INIT_ERROR
        _SCENE, _INIT_ERROR = scene, None
        results = map(work_fn, jobs)
    else:
        # unresolved: run-dir keys (${hydra:...}) exist only in the parent; workers never read them
        rested = None if scene.made is None else scene.garment.vertices.numpy()
        results = map_in_workers(work_fn, jobs, workers, _init_worker, (OmegaConf.to_yaml(cfg), 1, rested))
    try:
        for result in results:
            for _, ok, _reason in result if batched else [result]:
                discarded += not ok
                done += 1
                bar.update(1)
            stops.at(f"the drapes ({done} of {n_samples} made)")
            bar.set_postfix(discarded=discarded, refresh=False)  # shown at the bar's next (timed) refresh
    finally:
        bar.close()
        if workers > 1:
            results.close()  # stops the workers when the loop ended early (an error, ctrl-C)


class _LogLines:
    """A file-like sink for tqdm that turns each refresh into one log line (no carriage returns)."""
    def write(self, text: str) -> None:
        text = text.strip("\r\n\x1b[A ")
        if text:
            log.info(text)

    def flush(self) -> None:
        pass


def progress_bar(total: int, desc: str, unit: str, stream=None, log_every_s: float = 30.0) -> tqdm:
    """A tqdm bar on a terminal; elsewhere (a log file, a pipe, a batch job) a plain log line at most every
    `log_every_s` seconds instead of a redraw per item, which a file stores as one endless line."""
    stream = sys.stderr if stream is None else stream
    if getattr(stream, "isatty", lambda: False)():
        return tqdm(total=total, desc=desc, unit=unit, dynamic_ncols=True, file=stream)
    return tqdm(total=total, desc=desc, unit=unit, file=_LogLines(), mininterval=log_every_s,
                maxinterval=max(log_every_s, 1.0), miniters=1,
                bar_format="{desc}: {n_fmt}/{total_fmt} ({percentage:.0f}%) "
                           "[{elapsed}<{remaining}, {rate_fmt}{postfix}]")


def _warp_cache_filled(sim: DictConfig) -> bool:
    """Whether warp's kernel cache (`sim.kernel_cache_dir`) already holds compiled kernels."""
    d = sim.get("kernel_cache_dir")
    return bool(d) and Path(d).is_dir() and any(Path(d).iterdir())


# what a merge writes, the manifest last (its presence marks a finished dataset)
MERGED_FILES = ("garment.obj", "cage.json", "body.npz", "embedding.npz", "poses.npy", "verts.npy", "angles.npy",
                "shapes.npz", "person.npy", "timings.json", "manifest.json")


def missing_shards(work: Path, num_poses: int, batch: int = 1, num_shards: int = 1) -> dict[int, list[int]]:
    """{shard: its pose indices without a sample file} for the shards not finished (batch b of `batch`
    consecutive poses belongs to shard b % num_shards, as `_generate` deals them)."""
    out: dict[int, list[int]] = {}
    for i in range(num_poses):
        if not _sample_path(work, i).is_file():
            out.setdefault((i // max(1, batch)) % max(1, num_shards), []).append(i)
    return out


def merge(out: Path, poses, angles, fp: dict, wrap_stats: dict, pose_stats: dict, scene: Scene, timings,
          batch: int = 1, num_shards: int = 1, sources: dict | None = None, mirror: MirrorMap | None = None,
          workers: int = 1) -> None:
    """Collect all sample files into the final arrays and write the manifest last.

    `sources` (data.poses): each generation pose's clip and frame, recorded per kept sample (`pose_source`).
    `mirror` (data.mirror): after the split, every training sample's mirror image is appended and joins the
    training split (the validation and test samples' mirrors are never made).

    An unfinished shard is named (a killed shard job: run it again, it resumes). The space the arrays
    need is checked before anything is written, and a disk that fills up anyway is one DiskFull naming
    the dataset, the bytes and the fix; the files this merge wrote are then removed (work/ is kept), so
    the directory never looks finished or half-merged.
    """
    work = out / "work"
    missing = missing_shards(work, len(poses), batch, num_shards)
    if missing:
        n = sum(map(len, missing.values()))
        which = "; ".join(f"shard {s} of {num_shards}: {len(ids)} missing (first {ids[:5]})"
                          for s, ids in sorted(missing.items())) if num_shards > 1 else f"first {missing[0][:5]}"
        shards = ",".join(str(s) for s in sorted(missing))
        raise RuntimeError(
            f"cannot merge {out}: {n} of {len(poses)} samples are missing ({which}); "
            + (f"run the unfinished shard(s) again (data.shard={shards} with the same overrides; they resume "
               "where they stopped), then merge" if num_shards > 1 else "run the same command again to finish them")
        )
    kept, reasons, residuals, stage, per_sample = [], {}, [], {"skin": 0.0, "drape": 0.0}, []
    positions, discarded = [], []
    first_discarded = None
    for i in range(len(poses)):
        pos, meta = _read_sample(_sample_path(work, i))
        stage["skin"] += meta["t_skin"]
        stage["drape"] += meta["t_drape"]
        per_sample.append(meta["t_skin"] + meta["t_drape"])
        if meta["ok"]:
            residuals.append(meta["residual"])
            kept.append(i)
            positions.append(pos)
        else:
            reasons[meta["reason"]] = reasons.get(meta["reason"], 0) + 1
            discarded.append(pos)
            if first_discarded is None:
                first_discarded = (i, pos, meta["reason"])
    faces = discarded_faces(scene, discarded, wrap_stats) if discarded else None
    del discarded
    if not kept:
        preview = write_discard_preview(out, scene, *first_discarded)
        raise ValueError(f"every sample of {out} was discarded: {discard_summary(reasons, scene.sim, faces)}; "
                         f"the first discarded drape (sample {first_discarded[0]}) is in {preview}")
    if reasons:
        log.warning("%d of %d drapes discarded: %s", sum(reasons.values()), len(poses),
                    discard_summary(reasons, scene.sim, faces))
    rng = np.random.default_rng(fp["seed"])
    order = rng.permutation(len(kept))
    n_train, n_val = split_sizes(len(kept))
    splits = {
        "train": sorted(order[:n_train].tolist()),
        "val": sorted(order[n_train : n_train + n_val].tolist()),
        "test": sorted(order[n_train + n_val :].tolist()),
    }
    verts = np.stack(positions).astype(np.float32)
    # wall times differ between runs: they go to timings.json so the manifest stays byte-identical
    timed = {f"{name}_{k}": v for name, st in (("shrinkwrap", wrap_stats), ("poses", pose_stats))
             for k, v in st.items() if "seconds" in k}
    wrap_stats = {k: v for k, v in wrap_stats.items() if "seconds" not in k}
    pose_stats = {k: v for k, v in pose_stats.items() if "seconds" not in k}
    manifest = dict(fp)
    manifest.update(
        num_vertices=int(scene.garment.vertices.shape[0]),
        joints=list(scene.body.skeleton.names),
        # the joints the kept poses move (the rest stay at the rest pose): a garment's own joint set
        posed_joints=moving_joints(poses[kept], scene.body.skeleton.names),
        counts={"requested": len(poses), "kept": len(kept), "discarded": reasons},
        source_index=kept,
        splits=splits,
        shrinkwrap=_plain(wrap_stats),
        poses=_plain(pose_stats),
        # of the kept samples: max vertex speed at the end of the drape, m/s
        drape_residual={"mean": float(np.mean(residuals)), "max": float(np.max(residuals))},
    )
    # a worker's mean drape, the slowest `workers` left out (each worker's first builds its model): pbc garment
    # fit's plan
    warm = np.sort(per_sample)[:max(1, len(per_sample) - workers)]
    timings = dict(timings, **timed, **{f"{k}_cpu_total": v for k, v in stage.items()},
                   sample_warm_mean=float(warm.mean()))
    arrays = {"poses.npy": poses[kept], "verts.npy": verts, "angles.npy": angles[kept].astype(np.float32)}
    if _shapes(scene) is not None:  # each kept sample's person (data.body_shape)
        arrays["person.npy"] = np.array([person_of(i, scene.shapes) for i in kept], np.int64)
    rows = kept  # each dataset row's generation sample
    if mirror is not None:  # after the split: no validation or test pose has its mirror in training
        rows = _add_mirrors(arrays, manifest, mirror, splits["train"], kept)
    if sources is not None:
        # beside the fingerprint's pose_source keys (the clips' hashes, the mix): each row's clip and frame
        manifest["pose_source"] = dict(manifest.get("pose_source") or {}, clips=sources["clips"],
                                       clip=[int(sources["clip"][i]) for i in rows],
                                       frame=[int(sources["frame"][i]) for i in rows])

    fix = (f"free space there (or move {out} to a disk with room and point paths.data_dir at it), then run the "
           "same command again: the drapes in work/ are kept and only the merge is redone")
    with naming_full_disk(out, "dataset", fix):
        needed = sum(a.nbytes + 128 for a in arrays.values()) + _scene_bytes(scene, work)  # + .npy headers
    needed += sum(len(json.dumps(_plain(d), indent=2, sort_keys=True, default=str)) + 1 for d in (manifest, timings))
    require_free_space(out, needed, "dataset", fix)
    try:
        with naming_full_disk(out, "dataset", fix, needed):
            _write_merged(out, scene, arrays, manifest, timings)
    except DiskFull:
        for name in MERGED_FILES:  # each was written whole (atomic_path), but together they are half a dataset
            with contextlib.suppress(OSError):
                (out / name).unlink()
        raise
    shutil.rmtree(work, ignore_errors=True)


def _add_mirrors(arrays: dict[str, np.ndarray], manifest: dict, mirror: MirrorMap, train: list[int],
                 kept: list[int]) -> list[int]:
    """Append the mirror image of every training row to `arrays` and to the training split; record them
    in `manifest` (counts.mirrored; mirrored: the rows, the rows they mirror, the measured asymmetry).
    Returns each dataset row's generation sample (a mirror's is its original's)."""
    n = len(arrays["poses.npy"])
    poses = mirror_poses(arrays["poses.npy"][train], mirror)
    arrays["poses.npy"] = np.concatenate([arrays["poses.npy"], poses])
    arrays["verts.npy"] = np.concatenate([arrays["verts.npy"], mirror_verts(arrays["verts.npy"][train], mirror)])
    arrays["angles.npy"] = np.concatenate([arrays["angles.npy"], xzy_angles(poses).astype(np.float32)])
    if "person.npy" in arrays:  # a person's mirror is the same person (checked symmetric)
        arrays["person.npy"] = np.concatenate([arrays["person.npy"], arrays["person.npy"][train]])
    new = list(range(n, n + len(train)))
    manifest["splits"]["train"] = list(train) + new
    manifest["counts"]["mirrored"] = len(train)
    manifest["source_index"] = list(kept) + [kept[i] for i in train]
    manifest["mirrored"] = {"rows": new, "of": list(train), **_plain(mirror.stats)}
    return manifest["source_index"]


# the faces past the drape's limits named one by one in the discard summary (`discarded_faces`)
DISCARD_FACES_LISTED = 3
# a discard reason (pbc.sim.drape.check_sample) -> what it measures and its likely cause, for the user
DISCARD_REASONS = {
    "area_stretched": ("a face's draped area over its flat-pattern area passed 1 + sim.discard.max_area_expansion "
                       "({limit_stretch:g}x)",
                       "the pattern is smaller than the garment (a wrong garment.uv_unit) or the shrink-wrap "
                       "stretched a part onto the body (sleeves modelled on another rest pose); `pbc garment "
                       "inspect` shows both before any drape"),
    "area_compressed": ("a face's draped area over its flat-pattern area fell below 1 - "
                        "sim.discard.max_area_compression ({limit_compress:g}x)",
                        "the pattern is larger than the garment (a wrong garment.uv_unit: `pbc garment inspect` "
                        "names the unit that fits) or cloth caught between body parts"),
    "not_converged": ("the drape still moved after sim's last frame",
                      "too few frames for this garment (sim settings), or cloth caught in a collision"),
    "nan": ("the drape's positions became NaN or infinite",
            "the simulation blew up: a garment far from the body, degenerate pattern triangles, or too large "
            "a time step (sim settings)"),
}


def discard_summary(reasons: dict[str, int], sim, faces: str | None = None) -> str:
    """One sentence on why drapes were discarded: the counts, the dominant reason, what it measures and its
    likely cause. For the area reasons the cause is ``faces`` when given (`discarded_faces`: the faces past the
    limits, their place and the cause measured), else `DISCARD_REASONS`' (measured nothing: what it usually is)."""
    top = max(reasons, key=reasons.get)
    limits = _area_limits(sim)
    measures, cause = DISCARD_REASONS.get(top, ("an unknown check", "see pbc.sim.drape.check_sample"))
    if faces is not None and top in ("area_stretched", "area_compressed"):
        cause = faces
    counts = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
    return (f"{counts}; mostly {top}: "
            f"{measures.format(limit_stretch=limits[1], limit_compress=limits[0])}; likely cause: {cause}")


def _area_limits(sim) -> tuple[float, float]:
    """The drape's (lowest, highest) face area ratio (pbc.sim.drape.area_limits, without importing the simulator)."""
    d = (sim.get("discard") or {}) if hasattr(sim, "get") else {}
    return 1.0 - float(d.get("max_area_compression", 0.75)), 1.0 + float(d.get("max_area_expansion", 1.0))


def discarded_faces(scene: Scene, drapes: list[np.ndarray], wrap_stats: dict | None = None,
                    listed: int = DISCARD_FACES_LISTED) -> str | None:
    """Which faces discarded the drapes and why, measured: the faces past the drape's area limits
    (sim.discard) in the most of the discarded drapes ``drapes`` (each (V, 3) positions), their chart and place on
    the body, in how many drapes, and the cause, first that applies: the whole garment's wrapped area is past the
    limits (the UV unit); the wrap (the drapes' start, `start_points` on the rest body) already had them past the
    limit; a sleeve off its arm (``wrap_stats``' sleeve angles past checks.SLEEVE_OFF_DEG) with those faces on
    it; else the drapes pulled them there. None when no face is past the limits (a drape discarded for not
    converging or NaN)."""
    lo, hi = _area_limits(scene.sim)
    g = scene.garment
    f = g.faces.cpu().numpy()
    pattern = g.pattern().double().cpu().numpy()  # (F, 3, 2)
    rest = face_areas(pattern.reshape(-1, 2), np.arange(3 * len(f)).reshape(-1, 3))
    past, over = [], np.zeros(len(f), np.int64)  # (drape, face) past either limit; per face, past the highest
    for pos in drapes:
        ratio = face_areas(np.nan_to_num(np.asarray(pos, np.float64), nan=1e6), f) / np.maximum(rest, 1e-30)
        past.append(~((ratio >= lo) & (ratio <= hi)))
        over += ratio > hi
    past = np.stack(past)
    counts = past.sum(0)
    if not counts.any():
        return None
    order = np.argsort(-counts, kind="stable")
    top = order[(counts[order] >= 0.8 * counts.max())][:listed]  # the faces past in (nearly) the most drapes
    stretched = bool(over[top].sum() * 2 >= counts[top].sum())
    n_any = int(past[:, top].any(1).sum())
    body = scene.body
    start = start_points(body.vertices[None].double(), body.faces, scene.embedding)[0].numpy()
    wrap = face_areas(start, f) / np.maximum(rest, 1e-30)
    chart = face_charts(g)
    names = chart_names_from_cage(scene.cage, chart, f)
    charts = sorted({names[int(chart[k])] for k in top})
    where = body_region(body, start[f[top[0]]].mean(0))
    ids = ", ".join(str(int(k)) for k in top)
    word = "stretched" if stretched else "compressed"
    what = (f"{'face' if len(top) == 1 else f'the same {len(top)} faces'} {ids} (chart"
            f"{'s' if len(charts) > 1 else ''} {', '.join(repr(c) for c in charts)}; the first's vertices "
            f"{', '.join(str(int(v) + 1) for v in f[top[0]])}, at {where}) {word} past the limit in {n_any} of "
            f"{len(drapes)} discarded drapes")
    overall = float(face_areas(start, f).sum() / max(float(rest.sum()), 1e-30))
    past_at_wrap = wrap[top] > hi if stretched else wrap[top] < lo
    sleeves = {}
    for side in ("left", "right"):
        angle = (wrap_stats or {}).get(f"sleeve_{side}_angle_deg")
        if angle is not None and float(angle) > SLEEVE_OFF_DEG:
            sleeves[side] = float(angle)
    part = scene.embedding.part.cpu().numpy()[f[top]]
    on_arm = {side for side, row in (("left", 1), ("right", 2)) if (part == row).any()}
    if not lo <= overall <= hi:
        why = (f"the whole garment's wrapped area is {overall:.3g}x its pattern area: the pattern's scale is off, "
               "check garment.uv_unit (`pbc garment inspect` names the one that fits)")
    elif past_at_wrap.any():
        w = float(wrap[top].max() if stretched else wrap[top].min())
        why = (f"they were {word} {w:.3g}x already by the shrink-wrap, where every drape starts (`pbc garment "
               f"inspect` names the faces past garment.shrinkwrap.max_face_stretch and why)")
    elif sleeves.keys() & on_arm:
        side = max(sleeves.keys() & on_arm, key=sleeves.get)
        why = (f"they lie on the {side} sleeve, {sleeves[side]:.0f} degrees off the body's rest arm: match the rest "
               "pose (rotate the sleeves onto the rest arms, or garment.made_on_rest)")
    else:
        why = (f"the wrap had them at {float(wrap[top].max()):.2f}x, within the limits, so the drapes {word} them "
               f"there: cloth caught between body parts at that place, or poses that pull it (open the "
               "discarded_<sample>.obj written beside the dataset)")
    return f"{what}: {why}"


def write_discard_preview(out: Path, scene: Scene, sample: int, positions: np.ndarray, reason: str) -> Path:
    """The first discarded drape as an OBJ beside the dataset (``discarded_<sample>.obj``, the garment's
    faces at the draped positions, the faces past the discard limits listed in a comment) to open in
    any viewer. Returns its path."""
    p = np.asarray(positions, np.float64)
    f = scene.garment.faces.cpu().numpy()
    pattern = scene.garment.pattern().double().cpu().numpy()
    e1, e2 = pattern[:, 1] - pattern[:, 0], pattern[:, 2] - pattern[:, 0]
    rest = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    t = p[f]
    ratio = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1) / np.maximum(rest, 1e-30)
    worst = np.argsort(-np.abs(np.log(np.maximum(np.nan_to_num(ratio, nan=1e9), 1e-9))))[:10]
    path = out / f"discarded_{sample:06d}.obj"
    lines = [f"# pbc: drape of sample {sample}, discarded ({reason}); area ratio of the worst faces: "
             + ", ".join(f"face {k}: {ratio[k]:.2f}" for k in worst)]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.nan_to_num(p)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    with atomic_path(path, suffix=".obj") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    return path


def _scene_bytes(scene: Scene, scratch: Path) -> int:
    """What the scene's files (garment, cage, body, embedding, shapes) take on disk: written once by the same
    writers into a folder under `scratch` (on the dataset's disk; removed after) and measured. A guess from
    the arrays (text formats x4) asked 3.4x the real size and refused disks with room."""
    probe = Path(scratch) / ".size_probe"
    try:
        _write_scene(probe, scene)
        return sum(p.stat().st_size for p in probe.iterdir())
    finally:
        shutil.rmtree(probe, ignore_errors=True)


def _write_scene(out: Path, scene: Scene) -> None:
    """The scene's files of a dataset, each atomically."""
    save_garment_obj(scene.garment, out / "garment.obj")
    save_cage(scene.cage, out / "cage.json")
    save_body(scene.body, out / "body.npz")
    save_embedding(scene.embedding, out / "embedding.npz")
    if _shapes(scene) is not None:
        save_shapes(scene.shapes, out / "shapes.npz")


def _write_merged(out: Path, scene: Scene, arrays: dict[str, np.ndarray], manifest: dict, timings: dict) -> None:
    """The dataset's files, each atomically, the manifest last (its presence marks a finished dataset)."""
    _write_scene(out, scene)
    for name, a in arrays.items():
        save_npy(out / name, a)
    write_json(out / "timings.json", _plain(timings))
    write_json(out / "manifest.json", manifest)


def _shapes(scene) -> BodyShapes | None:
    """The scene's people (data.body_shape), None for one body (and for a stand-in scene without the field)."""
    return getattr(scene, "shapes", None)


def split_sizes(n: int) -> tuple[int, int]:
    """Train and validation counts of an 80/10/10 split; with 3 or more samples no split is empty."""
    n_held = max(1, round(0.1 * n)) if n >= 3 else 0
    return n - 2 * n_held, n_held


def _plain(obj):
    """JSON-able copy of stats dicts that may hold numpy/torch scalars."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, torch.Tensor | np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
