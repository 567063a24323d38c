"""The one LightningModule for every target (whole-shirt images, patch crops, FC per-vertex baselines).

Job: turn a batch of (pose, draped vertices) into losses, metrics and logs. Ground-truth cloth images
are rendered from the stored vertices on the batch's device (docs/architecture.md); predictions go back
image -> vertices -> 3D through the run's cloth target (``pbc.pixels.target``) so the normal/edge losses
and the cm metrics see the real garment. The target (operators, skinning, faces, edges) is not an hparam:
it is attached with :meth:`ClothModule.attach` before fit/test (``pbc.train`` attaches the DataModule's).
Built from ``conf/model/*.yaml`` (``_target_`` this class; optimiser and LR scheduler as ``_partial_``).

Also here: :class:`ImagePanel`, the TensorBoard callback drawing pred | gt | error images for fixed
validation poses and writing one predicted mesh (``add_mesh`` + OBJ) at the end of fit.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch import Tensor

from pbc.io import write_text
from pbc.losses import edge_loss, image_loss, normal_loss, vertex_value_loss
from pbc.metrics import normal_cosine_distance, vertex_error_cm
from pbc.models.fc import fit_pca as fit_pca_values
from pbc.pixels.reconstruct import edge_lengths, vertex_normals
from pbc.pixels.target import KINDS, VertexTarget

log = logging.getLogger(__name__)
# the identity keys a checkpoint must share with the run that loads it
MONITOR = "val/vertex_error_cm"
# log prefixes of the test dataloaders, in order (see pbc.data.datamodule.ClothDataModule.scoring_dataloaders)
TEST_SPLITS = ("test", "train_final")
IDENTITY_KEYS = ("garment_hash", "num_vertices", "kind", "resolution", "patch_id", "space")


class ClothModule(L.LightningModule):
    """Pose -> cloth (image, crop or per-vertex values), trained with eq. 1-3 (+ edge loss).

    Args:
        net: Hydra node of the network (``_target_`` ConvDecoder or FCNet).
        kind: ``whole`` | ``patch`` | ``fc``.
        space: offset space of the predicted values (``local`` | ``root`` | ``position``).
        loss: ``{norm, normal_weight, edge_weight}``.
        lr: learning rate (``model.optimizer.lr`` interpolates it).
        identity: what a checkpoint must match to be loaded here (garment hash, resolution, patch...).
        patch_id: patch of a patch model, else None.
        summary: flat extra hparams for the TensorBoard hparams tab (data size, loss name...).
        mean_image: image models start from the train split's mean image (``model.mean_image``;
            false = the paper's plain decoder).
        optimizer: a ``_partial_`` optimiser node (``model.optimizer``); None = Adam at ``lr``.
        scheduler: an optional ``_partial_`` LR scheduler node (``model.scheduler``), stepped per epoch.
    """

    def __init__(self, net: dict, kind: str, space: str, loss: dict, lr: float, identity: dict | None = None,
                 patch_id: int | None = None, summary: dict | None = None, mean_image: bool = True,
                 optimizer: dict | None = None, scheduler: dict | None = None) -> None:
        super().__init__()
        if kind not in KINDS:
            raise ValueError(f"model.kind must be one of {KINDS}, got {kind!r}")
        # logger=False: the hparams tab is written once at the end, together with the final metrics
        self.save_hyperparameters(logger=False)
        self.net = instantiate(net)
        self.target: VertexTarget | None = None

    # ------------------------------------------------------------------------------ wiring
    def attach(self, target: VertexTarget) -> ClothModule:
        """Give the module its cloth target (``pbc.pixels.target.make_target``); needed before a step."""
        if target.kind != self.hparams.kind:
            raise ValueError(f"a {self.hparams.kind!r} model cannot train on a {target.kind!r} target")
        self.target = target
        return self

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Refuse a checkpoint of another garment / resolution / patch / model kind, naming the difference."""
        theirs = checkpoint.get("hyper_parameters", {}).get("identity", {})
        mine = self.hparams.identity or {}
        diff = {k: (theirs.get(k), mine.get(k)) for k in IDENTITY_KEYS if theirs.get(k) != mine.get(k)}
        if diff:
            lines = ", ".join(f"{k}: checkpoint {a!r} vs this run {b!r}" for k, (a, b) in diff.items())
            raise ValueError(f"refusing checkpoint made for a different setup ({lines})")

    def configure_optimizers(self):
        """``model.optimizer`` (a ``_partial_`` node; Adam at ``lr`` when absent) and, when
        ``model.scheduler`` is set (a ``_partial_`` LR scheduler), the scheduler stepped per epoch."""
        node = self.hparams.get("optimizer") or {"_target_": "torch.optim.Adam", "_partial_": True,
                                                 "lr": self.hparams.lr}
        opt = instantiate(node)(params=self.net.parameters())
        sched = self.hparams.get("scheduler")
        if not sched:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": instantiate(sched)(optimizer=opt),
                                                   "monitor": MONITOR, "interval": "epoch"}}

    def forward(self, pose: Tensor) -> Tensor:
        return self.net(pose.reshape(pose.shape[0], -1))

    # ------------------------------------------------------------------------------ targets
    def targets(self, batch: dict) -> dict:
        """Ground truth of a batch (anchors, frames, offsets and the target image): what the DataModule
        already rendered on the device, else looked up in (or rendered by) the same target. Under a Trainer
        whose DataModule caches targets, the cache is built first (the mean-image and PCA passes of
        on_fit_start then read it too)."""
        dm = getattr(self._trainer, "datamodule", None) if self._trainer is not None else None
        if getattr(dm, "cache_targets", False) and dm.target is self.target and not self.target.rendered(batch):
            dm.ensure_cache(batch["pose"].device)
        return self.target.ensure(batch)

    def positions(self, pred: Tensor, t: dict) -> Tensor:
        """Prediction -> 3D positions (B, V, 3); outside a patch model's patch, ground truth."""
        return self.target.positions(pred, t)

    def step(self, batch: dict, split: str, batch_idx: int) -> tuple[Tensor, dict]:
        t = self.targets(batch)
        pred = self(batch["pose"])
        # under trainer.precision=bf16-mixed only the network runs in bf16: losses, the image -> 3D path and
        # the metrics stay float32 (bf16 keeps 8 mantissa bits: millimetres on a garment a metre across)
        with torch.autocast(pred.device.type, enabled=False):
            return self.losses(batch, t, pred.float(), split, batch_idx)

    def losses(self, batch: dict, t: dict, pred: Tensor, split: str, batch_idx: int) -> tuple[Tensor, dict]:
        """Eq. 1-3 (+ edge loss) and the metrics of one batch's prediction `pred` against its targets `t`;
        logged under `split`. Returns (total loss, {pred, image, mask, positions})."""
        lc = self.hparams.loss
        logs: dict[str, Tensor] = {}
        truth, mask = self.target.truth(t)
        base = vertex_value_loss(pred, truth, lc["norm"]) if mask is None else image_loss(pred, truth, mask,
                                                                                          lc["norm"])
        logs["image_loss"] = base
        total = base
        # 3D is always built: the cm metric needs it; only the optional losses add graph work
        pos = self.positions(pred, t)
        ids = self.target.vertices
        edges = self.target.topology(pos.device)[1]
        n_pred = n_gt = None
        if lc["normal_weight"] > 0 or split != "train":
            # only the faces around the covered vertices (a patch's neighbourhood); ground-truth normals
            # from the target cache when the DataModule has one (they depend only on the sample)
            faces = self.target.normal_faces(pos.device)
            n_pred = vertex_normals(pos, faces)
            n_gt = t["normals"] if "normals" in t else vertex_normals(t["verts"], faces)
        if lc["normal_weight"] > 0:
            sel = slice(None) if ids is None else ids.to(pos.device)
            nl = normal_loss(n_pred[:, sel], n_gt[:, sel])
            logs["normal_loss"] = nl
            total = total + lc["normal_weight"] * nl
        if lc["edge_weight"] > 0:
            el = edge_loss(edge_lengths(pos, edges), edge_lengths(t["verts"], edges))
            logs["edge_loss"] = el
            total = total + lc["edge_weight"] * el
        logs["loss"] = total
        with torch.no_grad():
            idv = None if ids is None else ids.to(pos.device)
            logs["vertex_error_cm"] = vertex_error_cm(pos, t["verts"], idv)
            if n_pred is not None:
                logs["normal_distance"] = normal_cosine_distance(n_pred, n_gt, idv)
        if not torch.isfinite(total):
            which = batch.get("index")
            raise FloatingPointError(
                f"non-finite {split} loss {total.item()} at global step {self.global_step}, epoch "
                f"{self.current_epoch}, batch {batch_idx}"
                + (f" (sample ids {which.tolist()})" if which is not None else "")
                + "; stopping instead of training a NaN model")
        bs = batch["pose"].shape[0]
        self.log_dict({f"{split}/{k}": v.detach() if k != "loss" else v for k, v in logs.items()},
                      on_step=split == "train", on_epoch=True, batch_size=bs, prog_bar=False,
                      add_dataloader_idx=False)
        return total, {"pred": pred.detach(), **{k: v for k, v in t.items() if k in ("image", "mask")},
                       "positions": pos.detach()}

    def training_step(self, batch, batch_idx):
        return self.step(batch, "train", batch_idx)[0]

    def validation_step(self, batch, batch_idx):
        self.step(batch, "val", batch_idx)

    def test_step(self, batch, batch_idx, dataloader_idx: int = 0):
        # test loaders in TEST_SPLITS order: the test split, then (pbc.train) the training split scored by
        # the best model (Table 1's training error) under its own prefix, never mixed with the test curves
        self.step(batch, TEST_SPLITS[dataloader_idx], batch_idx)

    # ------------------------------------------------------------------------------ PCA (fc)
    def on_fit_start(self) -> None:
        net = self.net
        if getattr(net, "mode", None) == "pca" and not bool(net.pca_fitted):
            self.fit_pca(self.trainer.datamodule.train_dataloader())
        # every fresh net standardises its pose input with the training poses' statistics
        if hasattr(net, "input_mean") and not net.input_mean.any():
            self.fit_input_stats(self.trainer.datamodule.train_dataloader())
        # a fresh image model starts from the training split's mean image (a resumed one has it already)
        if self.hparams.get("mean_image", True) and hasattr(net, "output_mean") and not net.output_mean.any():
            self.fit_output_mean(self.trainer.datamodule.train_dataloader())

    @torch.no_grad()
    def fit_input_stats(self, loader) -> None:
        """Set the net's input_mean / input_scale to the train split's per-entry pose mean and spread."""
        pose = torch.cat([b["pose"].reshape(b["pose"].shape[0], -1).double() for b in loader])
        if pose.shape[0] < 2:
            return
        # entries that never vary (a joint's fixed axis) keep scale 1 instead of dividing by ~0
        std = pose.std(0)
        self.net.input_mean.copy_(pose.mean(0).float())
        self.net.input_scale.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)).float())

    @torch.no_grad()
    def fit_output_mean(self, loader) -> None:
        """Set the decoder's output_mean to the train split's mean target image, and (where the decoder
        has one) its output_scale to each channel's spread over poses: the RMS over the pixels that vary
        of each pixel's standard deviation."""
        total, sq, n = None, None, 0
        for batch in loader:
            batch = {k: v.to(self.device) if torch.is_tensor(v) else v for k, v in batch.items()}
            image = self.targets(batch)["image"].double()
            s1, s2 = image.sum(0, keepdim=True), (image * image).sum(0, keepdim=True)
            total, sq = (s1, s2) if total is None else (total + s1, sq + s2)
            n += image.shape[0]
        mean = total / n
        self.net.output_mean.copy_(mean.float())
        scale = getattr(self.net, "output_scale", None)
        if scale is not None and n > 1:
            var = (sq / n - mean * mean).clamp_min(0)[0]  # (C, H, W) per-pixel variance over poses
            varies = var > 0
            per_channel = [var[c][varies[c]].mean().sqrt() if varies[c].any() else var.new_ones(()) for c in
                           range(var.shape[0])]
            scale.copy_(torch.stack(per_channel).float().view_as(scale))
        log.info("decoder starts from the mean image of %d train samples (output scale %s)", n,
                 None if scale is None else [f"{v:.2e}" for v in scale.flatten().tolist()])

    @torch.no_grad()
    def fit_pca(self, loader) -> None:
        """Fit the FC net's PCA basis on the (whole) train split, in the model's space."""
        rows = []
        for batch in loader:
            batch = {k: v.to(self.device) if torch.is_tensor(v) else v for k, v in batch.items()}
            rows.append(self.targets(batch)["offsets"].reshape(batch["verts"].shape[0], -1).cpu())
        mean, comps, scale = fit_pca_values(torch.cat(rows), self.net.pca_components.shape[0])
        self.net.set_pca(mean.to(self.device), comps.to(self.device), scale.to(self.device))
        log.info("fitted PCA on %d train samples", sum(len(r) for r in rows))


# ---------------------------------------------------------------------------------- visuals
def _to_rgb(x: Tensor, scale: float) -> Tensor:
    """(3, H, W) signed offsets -> [0, 1] RGB, 0.5 = no offset."""
    return (0.5 + x / (2 * scale)).clamp(0, 1)


def image_panel(pred: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """One pose: pred (C, H, W), gt, mask (C, H, W) -> (3, C/3*H, 3*W) rows = pieces, cols = pred|gt|error."""
    scale = float(gt.abs().max().clamp_min(1e-6))
    rows = []
    for k in range(pred.shape[0] // 3):
        s = slice(3 * k, 3 * k + 3)
        err = ((pred[s] - gt[s]).abs().sum(0) * mask[s][0]) / scale
        rows.append(torch.cat([_to_rgb(pred[s] * mask[s], scale), _to_rgb(gt[s], scale),
                               err.clamp(0, 1).expand(3, -1, -1)], dim=2))
    return torch.cat(rows, dim=1)


def write_obj(path: Path, vertices: Tensor, faces: Tensor) -> Path:
    """Plain OBJ (v / f, 1-based), written atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces.tolist()]
    write_text(path, "\n".join(lines) + "\n")
    return path


def _tensorboard(trainer):
    for lg in trainer.loggers:
        if isinstance(lg, L.pytorch.loggers.TensorBoardLogger):
            return lg.experiment
    return None


class ImagePanel(L.Callback):
    """Every ``every_n_epochs`` validation epochs, log pred | gt | error for ``num_poses`` fixed val poses;
    at the end of fit, log one predicted mesh (``add_mesh``) and write it as OBJ under ``mesh_dir``."""

    def __init__(self, every_n_epochs: int = 5, num_poses: int = 4, mesh_dir: str | None = None) -> None:
        self.every = max(1, int(every_n_epochs))
        self.num = int(num_poses)
        self.mesh_dir = Path(mesh_dir) if mesh_dir else None
        self._batch: dict | None = None

    def _fixed_batch(self, trainer, pl_module) -> dict | None:
        if self._batch is None:
            dm = trainer.datamodule
            if dm is None:
                return None
            # the first val samples, always the same ones, so panels are comparable across epochs
            for b in dm.val_dataloader():
                self._batch = {k: v[: self.num] if torch.is_tensor(v) else v for k, v in b.items()}
                break
        if self._batch is None:
            return None
        return {k: v.to(pl_module.device) if torch.is_tensor(v) else v for k, v in self._batch.items()}

    @torch.no_grad()
    def _predict(self, trainer, pl_module):
        batch = self._fixed_batch(trainer, pl_module)
        if batch is None:
            return None
        was = pl_module.training
        pl_module.eval()
        t = pl_module.targets(batch)
        pred = pl_module(batch["pose"])
        pos = pl_module.positions(pred, t)
        pl_module.train(was)
        return batch, t, pred, pos

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        tb = _tensorboard(trainer)
        epoch = trainer.current_epoch
        if tb is None or trainer.sanity_checking or pl_module.target.image_size is None:
            return
        if (epoch + 1) % self.every:
            return
        out = self._predict(trainer, pl_module)
        if out is None:
            return
        _, t, pred, _ = out
        mask = t["mask"].expand_as(pred)
        panels = [image_panel(pred[i].float().cpu(), t["image"][i].float().cpu(), mask[i].float().cpu())
                  for i in range(pred.shape[0])]
        tb.add_image("val/panel_pred_gt_error", torch.cat(panels, dim=1), global_step=trainer.global_step)

    def on_fit_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        out = self._predict(trainer, pl_module)
        if out is None:
            return
        pos = out[3][0].float().cpu()
        faces = pl_module.target.faces.cpu()
        if self.mesh_dir is not None:
            write_obj(self.mesh_dir / "pred_val0.obj", pos, faces)
            write_obj(self.mesh_dir / "gt_val0.obj", out[1]["verts"][0].float().cpu(), faces)
        tb = _tensorboard(trainer)
        if tb is not None:
            tb.add_mesh("val/pred_mesh", vertices=pos[None], faces=faces[None].int(),
                        global_step=trainer.global_step)


def flat_summary(cfg: DictConfig | dict) -> dict:
    """Scalars of a nested config as 'a/b' keys (the TensorBoard hparams tab accepts only scalars)."""
    d = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg
    out = {}

    def walk(prefix, v):
        if isinstance(v, dict):
            for k, x in v.items():
                walk(f"{prefix}/{k}" if prefix else str(k), x)
        elif isinstance(v, bool | int | float | str) or v is None:
            out[prefix] = "none" if v is None else v
        else:
            out[prefix] = str(v)

    walk("", d)
    return {k: v for k, v in out.items() if not (isinstance(v, float) and math.isnan(v))}

