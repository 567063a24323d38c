"""`python -m pbc.train +experiment=NAME [overrides]`: train, test on the best checkpoint, write metrics.json.

One job: build the DataModule (``conf/datamodule``), the :class:`~pbc.models.module.ClothModule`
(``conf/model``), callbacks, loggers and the Lightning Trainer from the config (``_target_`` nodes, as
lightning-hydra-template does), run fit + test, and leave everything in the Hydra run dir:

    <run dir>/.hydra/               the composed config
    <run dir>/checkpoints/          epoch_NNN.ckpt (best by val/vertex_error_cm; a patch model's metrics
                                    say their scope: val/patch_vertex_error_cm) and last.ckpt
    <run dir>/tensorboard/          events: scalars, image panels, mesh, hparams tab with final metrics
    <run dir>/meshes/               predicted and ground-truth OBJ of one fixed validation pose
                                    (pred_val0.obj; a patch model's patch: pred_val0_patchNN.obj)
    <run dir>/metrics.json          {"status", "test", "val_best", "optimized_metric", "config", ...}

Return value: the best ``val/vertex_error_cm`` (the checkpoint monitor), so Hydra sweepers can minimise
it. Failures: the error is logged and ``metrics.json`` is written with ``"status": "failed"`` and the
traceback, then the exception is re-raised (Hydra's convention): the launcher marks that job FAILED,
the other jobs of the multirun still run (the basic and joblib launchers run the whole batch before the
sweeper re-raises the first failure; the Optuna sweeper records the trial as failed and continues), and
the process exits non-zero so CI notices.

Resume: ``ckpt_path=last`` continues the newest ``last.ckpt`` of the same training (this run dir first,
then sibling run dirs of the same job whose training identity -- model, loss, optimiser, batch, image sizes,
seed, dataset fingerprint; ``pbc.validate.training_identity`` -- equals this run's);
``ckpt_path=<run dir>`` or ``ckpt_path=<file.ckpt>`` are explicit. A checkpoint of another training
identity is refused, listing the differences (``pbc.validate.check_resume``).

Checks at the door (docs/reliability.md): config types first (``check_config``), a writable run dir, then,
once the data is open, the patch id against its cage and the dataset against the config's generation
settings (``check_matches_config``). ``metrics.json`` records the data by resolved dir and fingerprint
(``"data"``), so ``pbc.evaluate`` and the predictor reopen exactly that dataset from any shell.
"""

from __future__ import annotations

import json
import logging
import time
import traceback
from pathlib import Path

import hydra
import lightning as L
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from pbc.config import register_resolvers
from pbc.data.datamodule import ClothDataModule
from pbc.data.dataset import dataset_fingerprint, run_data_record
from pbc.io import is_writable_dir, load_checkpoint, require_writable_dir, write_json
from pbc.models.module import TEST_SPLITS, ClothModule, flat_summary
from pbc.models.progress import metric_table, silence_training_noise
from pbc.pixels.target import VertexTarget
from pbc.runs import RunRecord, monitor
from pbc.validate import check_config, check_pose_joints, check_resume, identity_diff, training_identity

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
        from pbc.data.generate import generate  # heavy (newton/warp): only when data must be made

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
    identity (``pbc.validate.training_identity``). A sibling run is adopted only when both match; this run
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


def train(cfg: DictConfig) -> dict:
    """Fit, test on the best checkpoint, write metrics.json; returns the metrics dict."""
    t0, out = time.time(), output_dir(cfg)
    check_config(cfg)  # before anything is made: model.patch_id=3.0 is not patch 3
    require_writable_dir(out, "run dir", "set hydra.run.dir (or PBC_ROOT) to a writable place")
    L.seed_everything(int(cfg.seed), workers=True)
    dm = datamodule(cfg)
    check_opened_data(cfg, dm)
    identity, summary = dm.target.identity(dm.data), run_summary(cfg, dm)
    training = training_identity(cfg, dataset_fingerprint(dm.data))
    module: ClothModule = instantiate(cfg.model, net=net_config(cfg, dm.target), identity=identity,
                                      summary=summary, training_identity=training).attach(dm.target)
    silence_training_noise()  # before the Trainer: its constructor logs a tip
    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values()]
    loggers = [instantiate(c) for c in (cfg.get("logger") or {}).values()]
    trainer = instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)

    ckpt = resolve_ckpt_path(cfg.get("ckpt_path"), out, identity, training)
    if ckpt:
        log.info("resuming from %s", ckpt)
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
        # best_checkpoint may lie in the resumed run's dir (KeepBestOfResumedRun)
        extra={"resumed_from": ckpt} if ckpt else {},
    )
    if hasattr(module, "export_runs") and best_path:  # all patches in one job -> P single-patch run dirs
        record.exported_runs = module.export_runs(best_path, out, record, dm.data)
    metrics = record.to_dict()
    log_final(trainer, summary, metrics)
    write_metrics(out, record)
    return metrics


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
    from pbc.data.generate import check_matches_config  # pulls in the sim: only once data is open

    check_matches_config(cfg, dm.data)


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


def write_metrics(out: Path, record: RunRecord | dict) -> Path:
    """metrics.json of a run (what pbc.evaluate, pbc.report and the main job read), atomically, through
    the run record (a dict is read as one, so it is checked the same way: ``RunRecord.failure(...)`` makes
    a failed run's)."""
    record = record if isinstance(record, RunRecord) else RunRecord.from_dict(record, str(out / "metrics.json"))
    return record.write(out)


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> float:
    try:
        metrics = train(cfg)
    except Exception as e:  # report, record, re-raise: see the module docstring
        log.error("training failed: %s", e)
        if is_writable_dir(output_dir(cfg)):  # a read-only run dir: the one clear error, not a second one chained
            write_metrics(output_dir(cfg), {"status": "failed", "error": f"{type(e).__name__}: {e}",
                                            "traceback": traceback.format_exc(),
                                            "config": OmegaConf.to_container(cfg, resolve=False)})
        raise
    log.info("test metrics: %s", json.dumps(metrics["test"]))
    return metrics["val_best"][metrics["optimized_metric"].split("/", 1)[1]]


if __name__ == "__main__":
    main()
