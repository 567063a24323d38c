"""`python -m pbc.train +experiment=NAME [overrides]`: train, test on the best checkpoint, write metrics.json.

One job: build the DataModule (``conf/datamodule``), the :class:`~pbc.models.module.ClothModule`
(``conf/model``), callbacks, loggers and the Lightning Trainer from the config (``_target_`` nodes, as
lightning-hydra-template does), run fit + test, and leave everything in the Hydra run dir:

    <run dir>/.hydra/               the composed config (written by the entry point once the job passed
                                    every check at the door: pbc.cli.train)
    <run dir>/checkpoints/          epoch_NNN.ckpt (best by val/vertex_error_cm; a patch model's metrics
                                    say their scope: val/patch_vertex_error_cm) and last.ckpt
    <run dir>/tensorboard/          events: scalars, image panels, mesh, hparams tab with final metrics
    <run dir>/meshes/               predicted and ground-truth OBJ of one fixed validation pose
                                    (pred_val0.obj; a patch model's patch: pred_val0_patchNN.obj)
    <run dir>/metrics.json          {"status", "test", "val_best", "optimized_metric", "config", ...,
                                    "pose_range": the training split's joint-angle range (predict's flags)}

Return value: the best ``val/vertex_error_cm`` (the checkpoint monitor), so Hydra sweepers can minimise
it. Failures: the error is logged and ``metrics.json`` is written with ``"status": "failed"`` and the
traceback, then the exception is re-raised (Hydra's convention): the launcher marks that job FAILED,
the other jobs of the multirun still run (the basic and joblib launchers run the whole batch before the
sweeper re-raises the first failure; the Optuna sweeper records the trial as failed and continues), and
the process exits non-zero so CI notices.

Resume: ``ckpt_path=last`` continues the newest ``last.ckpt`` of the same training (this run dir first,
then sibling run dirs of the same job whose training identity -- model, loss, optimiser, batch, image sizes,
seed, dataset fingerprint; ``pbc.core.validate.training_identity`` -- equals this run's);
``ckpt_path=<run dir>`` or ``ckpt_path=<file.ckpt>`` are explicit. A checkpoint of another training
identity is refused, listing the differences (``pbc.core.validate.check_resume``).

Checks at the door (docs/reliability.md): config types first (``check_config``), a writable run dir, then,
once the data is open, the patch id against its cage and the dataset against the config's generation
settings (``check_matches_config``). ``metrics.json`` records the data by resolved dir and fingerprint
(``"data"``), so ``pbc.evaluate`` and the predictor reopen exactly that dataset from any shell.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from lightning.pytorch.plugins import TorchCheckpointIO
from omegaconf import DictConfig, OmegaConf

from pbc.core.config import register_resolvers
from pbc.core.io import (
    LockHeld,
    atomic_path,
    dir_lock,
    is_writable_dir,
    load_checkpoint,
    lock_holder,
    naming_full_disk,
    out_of_space,
    read_json,
    require_free_space,
    require_writable_dir,
)
from pbc.core.runs import RunRecord, monitor
from pbc.core.validate import (
    check_config,
    check_pose_joints,
    check_resume,
    identity_diff,
    training_identity,
)
from pbc.data.datamodule import ClothDataModule
from pbc.data.dataset import dataset_fingerprint, run_data_record
from pbc.inference.poses import training_pose_range
from pbc.models.module import TEST_SPLITS, ClothModule, flat_summary
from pbc.models.progress import metric_table, silence_training_noise
from pbc.motion.ranges import range_table_record
from pbc.motion.retarget import check_motion_files
from pbc.pixels.target import VertexTarget

log = logging.getLogger(__name__)


register_resolvers()  # ${pbc.monitor:...} in conf/callbacks


def output_dir(cfg: DictConfig) -> Path:
    """The run dir: Hydra's when inside an entry point, else ``cfg.paths.output_dir`` as given."""
    try:
        return Path(HydraConfig.get().runtime.output_dir)
    except ValueError:
        return Path(cfg.paths.output_dir)


def ensure_dataset(cfg: DictConfig) -> Path:
    """Make the configured dataset when it is missing (the entry point's job, not the DataModule's).

    When another process is making it already (the first job of a multirun started from nothing holds
    its generation lock), wait for that one, at most ``data.lock_wait_s`` seconds with a log line, and
    train on what it made, instead of failing with LockHeld."""
    data_dir = Path(cfg.data.dir)
    if not (data_dir / "manifest.json").is_file():
        from pbc.data.generate import generate  # noqa: PLC0415 - newton/warp load in seconds; only when data must be made

        log.info("no dataset at %s: making it first (python -m pbc.generate)", data_dir)
        generate(cfg, wait_s=float(OmegaConf.select(cfg, "data.lock_wait_s", default=0) or 0))
    return data_dir


def datamodule(cfg: DictConfig) -> ClothDataModule:
    """The DataModule of ``cfg.datamodule``, set up; what it serves follows ``model.kind`` / ``model.space``."""
    ensure_dataset(cfg)
    dm = instantiate(cfg.datamodule)
    dm.setup("fit")
    return dm


def net_config(cfg: DictConfig, target: VertexTarget) -> dict:
    """``model.net`` sized to what the target serves (image size and channels for decoders, vertex count for
    FC nets) and to the pose it reads: every joint of the dataset's skeleton, or the joints named by
    ``data.pose_joints`` (the necktie's 4 of 10: the net keeps those of the full pose it is given)."""
    net = OmegaConf.to_container(cfg.model.net, resolve=True)
    fit = ({"output_size": list(target.image_size), "out_channels": target.channels} if target.image_size
           else {"num_vertices": target.num_vertices})
    skeleton = target.skinner.skeleton
    wanted = OmegaConf.select(cfg, "data.pose_joints")
    if wanted is None:
        fit["in_features"] = 9 * skeleton.num_joints
    else:
        fit.update(in_features=9 * len(wanted), input_joints=skeleton.indices(wanted, "data.pose_joints"),
                   num_joints=skeleton.num_joints)
    if getattr(target, "num_patches", None):  # a stacked all-patches net: the cage's patch count
        fit["num_patches"] = int(target.num_patches)
    for k, v in fit.items():
        if net.get(k) != v:
            log.info("model.net.%s %s -> %s (what the target serves)", k, net.get(k), v)
    return dict(net, **fit)


def run_summary(cfg: DictConfig, dm: ClothDataModule) -> dict:
    """The flat hparams of a run (the TensorBoard hparams tab, metrics.json, pbc.report)."""
    return {
        "model": str(cfg.model.net._target_).rsplit(".", 1)[-1], "kind": cfg.model.kind,
        "patch_id": -1 if cfg.model.patch_id is None else int(cfg.model.patch_id), "space": cfg.model.space,
        "loss": f"{cfg.loss.norm}+n{cfg.loss.normal_weight}+e{cfg.loss.edge_weight}",
        "lr": float(cfg.model.lr),
        "data": str(cfg.data.name), "num_train": len(dm.splits["train"]), "seed": int(cfg.seed),
    }


def resolve_ckpt_path(spec: str | None, out_dir: Path, identity: dict, training: dict | None = None) -> str | None:
    """``null`` -> None; ``last`` -> newest matching last.ckpt (this run dir, then siblings); a run dir ->
    its checkpoints/last.ckpt; a file -> itself. Raises FileNotFoundError naming where it looked.

    identity: the target identity (garment, kind, resolution, patch, space); training: the full training
    identity (``pbc.core.validate.training_identity``). A sibling run is adopted only when both match; this run
    dir's own or an explicit checkpoint of another training identity is refused (ValueError listing the
    differences), never silently resumed with the checkpoint's settings.
    """
    if spec in (None, "", "null"):
        return None
    if spec != "last":
        p = Path(spec)
        if p.is_dir():
            p = p / "checkpoints" / "last.ckpt"
        if not p.is_file():
            raise FileNotFoundError(f"ckpt_path={spec}: no checkpoint at {p}")
        return _checked(p, training)
    own = out_dir / "checkpoints" / "last.ckpt"
    if own.is_file():
        return _checked(own, training)
    candidates = sorted(out_dir.parent.glob("*/checkpoints/last.ckpt"), key=lambda p: p.stat().st_mtime,
                        reverse=True)
    for c in candidates:
        hp = load_checkpoint(c).get("hyper_parameters", {})
        if hp.get("identity") != identity:
            continue
        if training is None or identity_diff(hp.get("training_identity") or {}, training) == []:
            return str(c)
        log.info("not resuming %s: trained with other settings (%s)", c,
                 "; ".join(identity_diff(hp.get("training_identity") or {}, training)))
    raise FileNotFoundError(f"ckpt_path=last: no last.ckpt of this setup in {out_dir} or {out_dir.parent}/*/ "
                            "(sibling runs must match the model, loss, optimiser, batch, image sizes, seed and data)")


def _checked(path: Path, training: dict | None) -> str:
    """An explicit or this run dir's checkpoint: refused when its training identity differs."""
    if training is not None:
        check_resume(load_checkpoint(path).get("hyper_parameters", {}).get("training_identity"), training, path)
    return str(path)


# ------------------------------------------------------------------------------------------- the run dir
RUN_LOCK = ".train.lock"  # held in the run dir for the whole training (pbc.core.io.dir_lock; gone when it ends)


class RunDirTaken(ValueError):
    """The run dir belongs to another training (running now, or finished there): nothing was written to it.
    A ValueError, so the CLI prints it as a user error; `record_failure` leaves the dir alone."""


class RunDirInUse(RunDirTaken, LockHeld):
    """Another process trains in this run dir now (also a `pbc.core.io.LockHeld`)."""


@contextlib.contextmanager
def run_dir_lock(out: Path):
    """Hold ``<out>/.train.lock`` for the block: a second job in the same hydra.run.dir is refused at once
    (two jobs would mix checkpoints, TensorBoard events and metrics.json). The kernel drops the lock of a
    SIGKILLed job, so a killed run's dir can be resumed at once."""
    lock = Path(out) / RUN_LOCK
    stack = contextlib.ExitStack()
    try:
        stack.enter_context(dir_lock(lock, f"run dir {out}"))
    except LockHeld:
        raise RunDirInUse(
            f"run dir {out} is in use by another training ({lock_holder(lock) or 'holder unknown'}; lock file "
            f"{lock}): two jobs in one run dir mix their checkpoints, logs and metrics.json. Give this job "
            "another run dir (hydra.run.dir=..., or paths.output_dir=... from Python), or wait for the other "
            "to finish"
        ) from None
    with stack:
        yield out


def check_run_dir_free(out: Path, ckpt_spec: str | None) -> None:
    """Refuse a run dir that holds another training's results (a finished metrics.json, or checkpoints of
    a killed or finished run) unless this job resumes that run dir's own last.ckpt.

    Refused rather than warned about: a second training there would write its epoch_NNN.ckpt beside the
    first's (pbc.predict and pbc.evaluate then could load either), add a second TensorBoard version, and
    overwrite metrics.json, so the first run's record is lost while its checkpoints stay."""
    out = Path(out)
    own_last = out / "checkpoints" / "last.ckpt"
    if ckpt_spec not in (None, "", "null"):
        if ckpt_spec == "last" and own_last.is_file():
            return  # continuing this dir's run (resolve_ckpt_path checks it is the same training)
        if ckpt_spec != "last" and Path(ckpt_spec).resolve() in (out.resolve(), own_last.resolve()):
            return
    found = training_results(out)
    if found:
        resume = "continue that training with ckpt_path=last, " if own_last.is_file() else ""
        raise RunDirTaken(
            f"run dir {out} already holds another training's results ({'; '.join(found)}): a new training "
            "there would mix its checkpoints and logs with them and overwrite metrics.json. Give this job "
            f"another run dir (hydra.run.dir=..., or paths.output_dir=... from Python), {resume}or delete {out}"
        )


def training_results(out: Path) -> list[str]:
    """What run dir `out` holds of a training: a finished metrics.json, checkpoints (empty: nothing)."""
    out, found = Path(out), []
    if (out / "metrics.json").is_file():
        with contextlib.suppress(ValueError, FileNotFoundError):  # unreadable: not a finished record
            if read_json(out / "metrics.json", "run metrics").get("status") == "ok":
                found.append("metrics.json of a finished training")
    ckpts = sorted(p.name for p in (out / "checkpoints").glob("*.ckpt"))
    if ckpts:
        found.append(f"checkpoints {', '.join(ckpts[:4])}{' ...' if len(ckpts) > 4 else ''}")
    return found


# run dirs whose job passed every check at the door in this process: only those may get a failed record
# over another training's results (a resumed run that failed while training)
_PAST_THE_DOOR: set[Path] = set()


def record_failure(cfg: DictConfig, err: BaseException) -> Path | None:
    """Write the failed run's metrics.json (error line, traceback, config): the CLI's handler calls it.

    Nothing is written when the run dir belongs to another training (RunDirTaken), when this job was refused
    at the door (a bad config, another dataset, another training's checkpoint) in a dir holding another
    training's results, while another job holds the dir, or when it cannot be written (the one clear error,
    not a second one chained): a refusal never changes a file of an existing run."""
    out = output_dir(cfg)
    if isinstance(err, RunDirTaken) or not is_rank_zero() or not is_writable_dir(out):
        return None
    record = RunRecord.failure(err, OmegaConf.to_container(cfg, resolve=False),
                               "".join(traceback.format_exception(err)))
    try:
        if out.resolve() in _PAST_THE_DOOR:
            return write_metrics(out, record)
        with run_dir_lock(out):
            return None if training_results(out) else write_metrics(out, record)
    except RunDirInUse:
        return None
    except OSError as full:
        if not out_of_space(full):
            raise
        log.warning("no room for the failed run's metrics.json in %s (the disk is full)", out)
        return None  # the job's own error (its DiskFull) is the one to report


RUN_DIR_FULL_FIX = ("free space there and run the same command with ckpt_path=last (the last complete checkpoint "
                    "is kept), or give the run a disk with room (hydra.run.dir=...)")


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint writes, each to a temporary file beside the checkpoint and then renamed.

    Lightning's own save goes through an fsspec transaction that writes in the system's temp dir and then
    copies onto the checkpoint: a full disk truncated epoch_NNN.ckpt and left last.ckpt empty, the file
    ``ckpt_path=last`` resumes from. Here a full disk leaves the previous complete file (or none) and raises
    DiskFull naming the file, the bytes it needed and the fix."""

    def save_checkpoint(self, checkpoint: dict, path, storage_options=None) -> None:
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} takes no storage_options; got {storage_options!r}")
        buffer = io.BytesIO()
        torch.save(checkpoint, buffer)
        with naming_full_disk(path, "checkpoint", RUN_DIR_FULL_FIX, needed=buffer.tell()), atomic_path(path) as tmp:
            require_free_space(Path(path).parent, buffer.tell(), "checkpoint", RUN_DIR_FULL_FIX)
            tmp.write_bytes(buffer.getbuffer())


class KeepBestOfResumedRun(L.Callback):
    """A run resumed from another run dir's checkpoint keeps that run's best checkpoint in the running.

    Lightning's ModelCheckpoint restores only ``best_model_path`` (not its score or top-k) when the
    checkpoint's dirpath differs from its own, so the resumed run's first validation became "best" and
    the killed run's better epoch was never tested. At train start (after Lightning restored the state)
    this puts the checkpoint's top-k, those files still on disk, back into the trainer's monitored
    callback: a later epoch replaces them only when it is better, and Lightning never deletes a file
    outside its own dirpath. Chained resumes carry it on, as every checkpoint records the top-k."""
    def __init__(self, ckpt_path: str | Path):
        self.ckpt_path = str(ckpt_path)

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        carry_best(trainer.checkpoint_callback, load_checkpoint(self.ckpt_path))


def carry_best(mc, ckpt: dict) -> str | None:
    """Put the top-k of checkpoint dict `ckpt` (ModelCheckpoint `mc`'s state in it) into `mc` when it was
    written in another dirpath; returns the best path carried, or None (same dir, no state, files gone)."""
    state = (ckpt.get("callbacks") or {}).get(getattr(mc, "state_key", None)) if mc is not None else None
    if not state or not mc.monitor or state.get("dirpath") == mc.dirpath:
        return None  # same dir: Lightning restored all of it
    kept = {p: torch.as_tensor(s) for p, s in (state.get("best_k_models") or {}).items() if Path(p).is_file()}
    if not kept:
        return None
    worst, best = (max, min) if mc.mode == "min" else (min, max)
    merged = {**kept, **mc.best_k_models}  # with any epoch this run saved already (none at train start)
    k = len(merged) if mc.save_top_k == -1 else mc.save_top_k
    keep = sorted(merged, key=lambda p: float(merged[p]), reverse=mc.mode != "min")[:k]
    mc.best_k_models = {p: merged[p] for p in keep}
    if len(mc.best_k_models) == k:
        mc.kth_best_model_path = worst(mc.best_k_models, key=mc.best_k_models.get)
        mc.kth_value = mc.best_k_models[mc.kth_best_model_path]
    mc.best_model_path = best(mc.best_k_models, key=mc.best_k_models.get)
    mc.best_model_score = mc.best_k_models[mc.best_model_path]
    log.info("best checkpoint so far: %s (%s %.4f), from the run resumed", mc.best_model_path, mc.monitor,
             float(mc.best_model_score))
    return mc.best_model_path


def trainer_callbacks(cfg: DictConfig, ckpt: str | None) -> list[L.Callback]:
    """The config's callbacks, plus KeepBestOfResumedRun(ckpt) when resuming: the best checkpoint of the
    run resumed competes with this run's, whichever dir it lies in."""
    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values()]
    return callbacks + ([KeepBestOfResumedRun(ckpt)] if ckpt else [])


def train(cfg: DictConfig, past_the_door: Callable[[Path], None] | None = None) -> dict:
    """Fit, test on the best checkpoint, write metrics.json; returns the metrics dict.

    The run dir is locked for the whole training (a second job there is refused at once: RunDirInUse) and
    must not hold another training's results unless this job resumes it (RunDirTaken). `past_the_door(out)`
    is called once every check at the door has passed (config, run dir, dataset, resumed checkpoint), before
    the first file of the training is written: the entry point writes Hydra's `.hydra/` there, so a refused
    job leaves another run's config as it was."""
    t0, out = time.time(), output_dir(cfg)
    check_config(cfg)  # before anything is made: model.patch_id=3.0 is not patch 3, sim.fps=0 no drape
    check_motion_files()  # read when the data is made on the way (ensure_dataset)
    require_writable_dir(out, "run dir", "set hydra.run.dir (or PBC_ROOT) to a writable place")
    if not is_rank_zero():  # DDP starts ranks > 0 as copies of this command in rank 0's (held) run dir
        return fit_and_test(cfg, out, t0)
    with run_dir_lock(out):
        check_run_dir_free(out, cfg.get("ckpt_path"))
        return fit_and_test(cfg, out, t0, past_the_door)


def fit_and_test(cfg: DictConfig, out: Path, t0: float, past_the_door: Callable[[Path], None] | None = None) -> dict:
    """The training proper, in run dir `out` (held by `train`): fit, test the best checkpoint, metrics.json."""
    L.seed_everything(int(cfg.seed), workers=True)
    dm = datamodule(cfg)
    check_opened_data(cfg, dm)
    identity, summary = dm.target.identity(dm.data), run_summary(cfg, dm)
    training = training_identity(cfg, dataset_fingerprint(dm.data))
    module: ClothModule = instantiate(cfg.model, net=net_config(cfg, dm.target), identity=identity,
                                      summary=summary, training_identity=training).attach(dm.target)
    silence_training_noise()  # before the Trainer: its constructor logs a tip
    ckpt = resolve_ckpt_path(cfg.get("ckpt_path"), out, identity, training)
    if is_rank_zero():
        _PAST_THE_DOOR.add(out.resolve())
        if past_the_door is not None:
            with naming_full_disk(out, "run dir", RUN_DIR_FULL_FIX):
                past_the_door(out)
    if ckpt:
        log.info("resuming from %s", ckpt)
    loggers = [instantiate(c) for c in (cfg.get("logger") or {}).values()]
    trainer = instantiate(cfg.trainer, callbacks=trainer_callbacks(cfg, ckpt), logger=loggers or False,
                          plugins=[AtomicCheckpointIO()])
    with naming_full_disk(out, "run dir", RUN_DIR_FULL_FIX):  # TensorBoard, meshes: the checkpoints name their own
        trainer.fit(module, datamodule=dm, ckpt_path=ckpt)

    ck = trainer.checkpoint_callback
    best_path = ck.best_model_path if ck is not None else ""
    best_val = float(ck.best_model_score) if ck is not None and ck.best_model_score is not None else float("inf")
    # the test split, then the training split (Table 1's training error), each under its own prefix
    scores = score(trainer, module, dm, best_path) if cfg.get("test", True) else {}
    mon = monitor(cfg.model.kind)  # val/patch_vertex_error_cm for a patch model: its patch's vertices only
    record = RunRecord(
        kind=cfg.model.kind, optimized_metric=mon, val_best={mon.split("/", 1)[1]: best_val},
        test=scores.get("test", {}), train=scores.get("train_final", {}), best_checkpoint=best_path or None,
        epochs=trainer.current_epoch, seconds=round(time.time() - t0, 2), summary=summary, identity=identity,
        training_identity=training, data=run_data_record(dm.data), config=recorded_config(cfg, dm),
        pose_range=pose_range_record(dm.data),
        # best_checkpoint may lie in the resumed run's dir (KeepBestOfResumedRun)
        extra={"resumed_from": ckpt} if ckpt else {},
    )
    if not trainer.is_global_zero:  # one record, one export: rank 0's
        return record.to_dict()
    if hasattr(module, "export_runs") and best_path:  # all patches in one job -> P single-patch run dirs
        record.exported_runs = module.export_runs(best_path, out, record, dm.data)
    metrics = record.to_dict()
    with naming_full_disk(out, "run dir", RUN_DIR_FULL_FIX):
        log_final(trainer, summary, metrics)
        write_metrics(out, record)
    return metrics


def is_rank_zero() -> bool:
    """This process is the job's first (or only) one. Lightning's DDP launcher sets LOCAL_RANK / NODE_RANK
    in the processes it starts; a SLURM job step sets SLURM_PROCID."""
    return all(os.environ.get(k, "0") == "0" for k in ("LOCAL_RANK", "NODE_RANK", "SLURM_PROCID"))


def check_opened_data(cfg: DictConfig, dm: ClothDataModule) -> None:
    """Once the dataset is open: the patch id against its cage, and its generation settings against the
    config's (garment, sim, seed, num_samples), so a run never records settings it did not train on."""
    check_config(cfg, num_patches=len(dm.data.cage.patches))
    check_pose_joints(dm.data.poses, dm.data.body.skeleton.names, OmegaConf.select(cfg, "data.pose_joints"),
                      f"dataset {dm.data.dir}")
    if OmegaConf.select(cfg, "garment") is None or OmegaConf.select(cfg, "sim") is None:
        return  # a config without generation settings (a bare data.dir) has nothing to compare
    if not {"seed", "num_samples", "sim"} <= set(dm.data.manifest):
        # made by hand or imported, not by pbc.generate: no generation record to compare with
        log.info("dataset %s records no generation settings: not compared with the config", dm.data.dir)
        return
    from pbc.data.generate import check_matches_config  # noqa: PLC0415 - it pulls in newton/warp; only once data is open

    check_matches_config(cfg, dm.data)


def pose_range_record(data) -> dict | None:
    """The training split's joint-angle range as metrics.json records it (``pose_range``; the range itself is
    `pbc.inference.poses.training_pose_range`): predict flags the frames of a clip outside it from the run
    alone, so a run whose dataset is gone, or a shipped model, still knows what it saw. None for an empty
    training split (nothing was seen)."""
    seen = len(data.split("train"))
    return None if seen == 0 else range_table_record(training_pose_range(data), data.body.skeleton.names, seen)


def recorded_config(cfg: DictConfig, dm: ClothDataModule) -> dict:
    """The run's config as metrics.json keeps it: unresolved, except data.dir, resolved to the directory
    actually read (``${oc.env:PBC_ROOT,.}`` would re-resolve to another place in another shell)."""
    out = OmegaConf.to_container(cfg, resolve=False)
    if isinstance(out.get("data"), dict):
        out["data"]["dir"] = str(Path(dm.data.dir).resolve())
    return out


def score(trainer: L.Trainer, module: ClothModule, dm: ClothDataModule, ckpt: str) -> dict[str, dict]:
    """{prefix: {metric: value}} of the best checkpoint on each of ``dm.scoring_dataloaders()``."""
    # verbose=False: Lightning's Rich table cuts metric names and wraps at 80 columns in a log file
    res = trainer.test(module, dataloaders=dm.scoring_dataloaders(), ckpt_path=ckpt or None, verbose=False)
    merged = {k: float(v) for r in res for k, v in r.items()}
    scores = {p: {k.split("/", 1)[1]: v for k, v in merged.items() if k.startswith(p + "/")} for p in TEST_SPLITS}
    if trainer.is_global_zero:
        log.info("scores of %s:\n%s", ckpt or "the final weights", metric_table(scores))
    return scores


def log_final(trainer: L.Trainer, summary: dict, metrics: dict) -> None:
    """The TensorBoard hparams tab: the run's summary with its final val/test metrics."""
    for lg in trainer.loggers:
        if isinstance(lg, L.pytorch.loggers.TensorBoardLogger):
            final = {f"final/val_best_{k}": v for k, v in metrics["val_best"].items()}
            final.update({f"final/test_{k}": v for k, v in metrics["test"].items()})
            lg.log_hyperparams(flat_summary(summary), metrics=final)
            lg.finalize("success")


def write_metrics(out: Path, record: RunRecord) -> Path:
    """metrics.json of a run (what pbc.evaluate, pbc.report and the main job read): the run record,
    checked and written atomically (``RunRecord.failure(...)`` makes a failed run's)."""
    return record.write(out)
