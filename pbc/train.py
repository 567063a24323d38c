"""`python -m pbc.train +experiment=NAME [overrides]`: train, test on the best checkpoint, write metrics.json.

One job: wire the Hydra config into a DataModule, a :class:`~pbc.models.module.ClothModule` and a
Lightning Trainer, run fit + test, and leave everything in the Hydra run dir:

    <run dir>/.hydra/               the composed config
    <run dir>/checkpoints/          epoch_NNN.ckpt (best by val/vertex_error_cm) and last.ckpt
    <run dir>/tensorboard/          events: scalars, image panels, mesh, hparams tab with final metrics
    <run dir>/meshes/               predicted (and ground-truth) OBJ of one fixed validation pose
    <run dir>/metrics.json          {"status", "test", "val_best", "optimized_metric", "config", ...}

Return value: the best ``val/vertex_error_cm`` (the checkpoint monitor), so Hydra sweepers can minimise
it. Failures: the error is logged and ``metrics.json`` is written with ``"status": "failed"`` and the
traceback, then the exception is re-raised (Hydra's convention): the launcher marks that job FAILED,
the other jobs of the multirun still run (the basic and joblib launchers run the whole batch before the
sweeper re-raises the first failure; the Optuna sweeper records the trial as failed and continues), and
the process exits non-zero so CI notices.

Resume: ``ckpt_path=last`` continues the newest ``last.ckpt`` of the same setup (this run dir first,
then sibling run dirs of the same job); ``ckpt_path=<run dir>`` or ``ckpt_path=<file.ckpt>`` are explicit.
"""

from __future__ import annotations

import json
import logging
import time
import traceback
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from pbc.io import write_json

log = logging.getLogger(__name__)
MONITOR = "val/vertex_error_cm"


def output_dir(cfg: DictConfig) -> Path:
    """The run dir: Hydra's when inside an entry point, else ``cfg.paths.output_dir`` as given."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return Path(HydraConfig.get().runtime.output_dir)
    except ValueError:
        return Path(cfg.paths.output_dir)


def datamodule(cfg: DictConfig):
    """The DataModule, set up (dataset generated on first use). The model is the source of truth for
    what it serves: target and offset space follow ``model.kind`` / ``model.space``."""
    from pbc.data.datamodule import from_config

    kind = cfg.model.kind
    if kind not in ("whole", "patch", "fc"):
        raise ValueError(f"model.kind must be whole | patch | fc, got {kind!r}")
    with open_dict(cfg):
        cfg.datamodule.target = "patch" if kind == "patch" else "whole"
        cfg.datamodule.patch_id = cfg.model.patch_id if kind == "patch" else None
        cfg.datamodule.space = cfg.model.space
        cfg.datamodule.render = kind != "fc"  # the FC baselines need no images
    dm = from_config(cfg)
    dm.prepare_data()
    dm.setup("fit")
    return dm


def run_identity(cfg: DictConfig, dm) -> dict:
    """What a checkpoint must match to be loaded by this run (see ClothModule.on_load_checkpoint)."""
    kind = cfg.model.kind
    res = getattr(dm.ops, "res", None)
    if kind == "patch":
        res = int(cfg.image.patch_resolution)
    return {
        "garment_hash": str(dm.data.manifest.get("garment_hash", "")),
        "num_vertices": int(dm.data.verts.shape[1]),
        "kind": str(kind),
        "resolution": None if kind == "fc" else int(res),
        "patch_id": None if kind != "patch" else int(cfg.model.patch_id),
        "space": str(cfg.model.space),
        "crop_size": None if kind != "patch" else int(dm.ops.window[2]),
    }


def resolve_ckpt_path(spec: str | None, out_dir: Path, identity: dict) -> str | None:
    """``null`` -> None; ``last`` -> newest matching last.ckpt (this run dir, then siblings); a run dir ->
    its checkpoints/last.ckpt; a file -> itself. Raises FileNotFoundError naming where it looked."""
    if spec in (None, "", "null"):
        return None
    if spec != "last":
        p = Path(spec)
        if p.is_dir():
            p = p / "checkpoints" / "last.ckpt"
        if not p.is_file():
            raise FileNotFoundError(f"ckpt_path={spec}: no checkpoint at {p}")
        return str(p)
    own = out_dir / "checkpoints" / "last.ckpt"
    if own.is_file():
        return str(own)
    candidates = sorted(out_dir.parent.glob("*/checkpoints/last.ckpt"), key=lambda p: p.stat().st_mtime,
                        reverse=True)
    for c in candidates:
        hp = torch.load(c, map_location="cpu", weights_only=False).get("hyper_parameters", {})
        if hp.get("identity") == identity:
            return str(c)
    raise FileNotFoundError(f"ckpt_path=last: no last.ckpt of this setup in {out_dir} or {out_dir.parent}/*/")


def train(cfg: DictConfig) -> dict:
    """Fit, test on the best checkpoint, write metrics.json; returns the metrics dict."""
    import lightning as L

    from pbc.models.module import ClothModule, flat_summary, geometry_from_datamodule

    t0 = time.time()
    out = output_dir(cfg)
    out.mkdir(parents=True, exist_ok=True)
    L.seed_everything(int(cfg.seed), workers=True)
    dm = datamodule(cfg)
    dataset = dm.data
    identity = run_identity(cfg, dm)
    net_cfg = OmegaConf.to_container(cfg.model.net, resolve=True)
    if cfg.model.kind == "fc":
        net_cfg["num_vertices"] = identity["num_vertices"]
    else:
        # the image size the DataModule really serves (crop_size scales with patch_resolution)
        size = [identity["crop_size"]] * 2 if cfg.model.kind == "patch" else [dm.ops.res] * 2
        if list(net_cfg["output_size"]) != size:
            log.info("decoder output_size %s -> %s (the served image size)", net_cfg["output_size"], size)
            net_cfg["output_size"] = size
    summary = {
        "model": str(cfg.model.net._target_).rsplit(".", 1)[-1], "kind": cfg.model.kind,
        "patch_id": -1 if cfg.model.patch_id is None else int(cfg.model.patch_id), "space": cfg.model.space,
        "loss": f"{cfg.loss.norm}+n{cfg.loss.normal_weight}+e{cfg.loss.edge_weight}",
        "lr": float(cfg.model.lr),
        "data": str(cfg.data.name), "num_train": len(dataset.split("train")), "seed": int(cfg.seed),
    }
    module = ClothModule(net=net_cfg, kind=cfg.model.kind, space=cfg.model.space,
                         loss=OmegaConf.to_container(cfg.loss, resolve=True), lr=float(cfg.model.lr),
                         identity=identity, patch_id=identity["patch_id"], summary=summary,
                         mean_image=bool(cfg.model.get("mean_image", True)))
    module.attach(geometry_from_datamodule(dm, cfg.model.kind))
    callbacks = [hydra.utils.instantiate(c) for c in (cfg.get("callbacks") or {}).values()]
    loggers = [hydra.utils.instantiate(c) for c in (cfg.get("logger") or {}).values()]
    trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)

    ckpt = resolve_ckpt_path(cfg.get("ckpt_path"), out, identity)
    if ckpt:
        log.info("resuming from %s", ckpt)
    trainer.fit(module, datamodule=dm, ckpt_path=ckpt)

    ck = trainer.checkpoint_callback
    best_path = ck.best_model_path if ck is not None else ""
    score = ck.best_model_score if ck is not None else None
    best_val = float(score) if score is not None else float("inf")
    test, train_metrics = {}, {}
    if cfg.get("test", True):
        res = trainer.test(module, datamodule=dm, ckpt_path=best_path or None)
        test = {k.split("/", 1)[1]: float(v) for k, v in (res[0] if res else {}).items()
                if k.startswith("test/")}
        # the same metrics of the best model on the training split (the paper's "training error")
        module.test_prefix = "train_final"
        res = trainer.test(module, dataloaders=dm.loader("train", shuffle=False), ckpt_path=best_path or None)
        module.test_prefix = "test"
        train_metrics = {k.split("/", 1)[1]: float(v) for k, v in (res[0] if res else {}).items()
                         if k.startswith("train_final/")}
    metrics = {
        "status": "ok", "optimized_metric": MONITOR, "val_best": {"vertex_error_cm": best_val},
        "test": test, "train": train_metrics, "best_checkpoint": best_path, "epochs": trainer.current_epoch,
        "seconds": round(time.time() - t0, 2), "summary": summary, "identity": identity,
        "config": OmegaConf.to_container(cfg, resolve=False),
    }
    for lg in trainer.loggers:
        if isinstance(lg, L.pytorch.loggers.TensorBoardLogger):
            final = {f"final/val_best_{k}": v for k, v in metrics["val_best"].items()}
            final.update({f"final/test_{k}": v for k, v in test.items()})
            lg.log_hyperparams(flat_summary(summary), metrics=final)
            lg.finalize("success")
    write_metrics(out, metrics)
    return metrics


def write_metrics(out: Path, metrics: dict) -> Path:
    """metrics.json of a run (what pbc.evaluate, pbc.report and the main job read), atomically."""
    write_json(out / "metrics.json", metrics)
    return out / "metrics.json"


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> float:
    try:
        metrics = train(cfg)
    except Exception as e:  # report, record, re-raise: see the module docstring
        log.error("training failed: %s", e)
        write_metrics(output_dir(cfg), {"status": "failed", "error": f"{type(e).__name__}: {e}",
                                        "traceback": traceback.format_exc(),
                                        "config": OmegaConf.to_container(cfg, resolve=False)})
        raise
    log.info("test metrics: %s", json.dumps(metrics["test"]))
    return metrics["val_best"]["vertex_error_cm"]


if __name__ == "__main__":
    main()
