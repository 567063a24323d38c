"""The one LightningModule for every target (whole-shirt images, patch crops, FC per-vertex baselines).

Job: turn a batch of (pose, draped vertices) into losses, metrics and logs. Ground-truth cloth images
are rendered from the stored vertices on the batch's device (docs/architecture.md); predictions go back
image -> vertices -> 3D through the run's cloth target (``pbc.pixels.target``) so the normal/edge losses
and the cm metrics see the real garment. The target (operators, skinning, faces, edges) is not an hparam:
it is attached with :meth:`ClothModule.attach` before fit/test (``pbc.train`` attaches the DataModule's).
Built from ``conf/model/*.yaml`` (``_target_`` this class; optimiser and LR scheduler as ``_partial_``).

Also here: :class:`ImagePanel`, the TensorBoard callback drawing pred | truth | |error| images for fixed
validation poses and writing one predicted mesh (``add_mesh`` + OBJ via pbc.geometry.meshio; a patch
model's is its patch's submesh, ``pred_val0_patchNN.obj``) at the end of fit.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import lightning as L  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
from hydra.utils import instantiate  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402
from torch import Tensor  # noqa: E402

from pbc.core.runs import monitor, scoped_name  # noqa: E402
from pbc.core.validate import as_poses  # noqa: E402
from pbc.geometry.meshio import submesh, write_garment_mesh  # noqa: E402
from pbc.geometry.meshops import vertex_normals  # noqa: E402
from pbc.models.decoder import pose_features  # noqa: E402
from pbc.models.fc import fit_pca as fit_pca_values  # noqa: E402
from pbc.models.losses import edge_loss, image_loss, normal_loss, vertex_value_loss  # noqa: E402
from pbc.models.metrics import normal_cosine_distance, vertex_error_cm, vertex_error_cm_per_pose  # noqa: E402
from pbc.pixels.reconstruct import edge_lengths  # noqa: E402
from pbc.pixels.target import KINDS, VertexTarget  # noqa: E402

log = logging.getLogger(__name__)
# the identity keys a checkpoint must share with the run that loads it
MONITOR = monitor("whole")  # a patch model's is monitor("patch"): val/patch_vertex_error_cm
# log prefixes of the test dataloaders, in order (see pbc.data.datamodule.ClothDataModule.scoring_dataloaders)
TEST_SPLITS = ("test", "train_final")
IDENTITY_KEYS = ("garment_hash", "num_vertices", "kind", "resolution", "patch_id", "space", "window")


def on_progress_bar(split: str, name: str) -> bool:
    """The metrics the training progress bar shows: the training loss and the validation vertex error."""
    return (split == "train" and name == "loss") or (split == "val" and name.endswith("vertex_error_cm"))


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
        training_identity: what a resumed run must match (``pbc.core.validate.training_identity``: model, loss,
            optimiser, batch, image sizes, seed, data fingerprint); ``pbc.train`` stores it here so every
            checkpoint carries it, and refuses to resume a checkpoint of another one.
        check_rotation: test that input poses are rotations in :meth:`forward`; None (default) = outside
            training only (training batches come from the dataset, checked whole when it opened).
    """

    def __init__(self, net: dict, kind: str, space: str, loss: dict, lr: float, identity: dict | None = None,
                 patch_id: int | None = None, summary: dict | None = None, mean_image: bool = True,
                 optimizer: dict | None = None, scheduler: dict | None = None,
                 training_identity: dict | None = None, check_rotation: bool | None = None) -> None:
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
                                                   "monitor": monitor(self.hparams.kind),
                                                   "interval": "epoch"}}

    def forward(self, pose: Tensor) -> Tensor:
        """pose (B, J*9) or (B, J, 3, 3) (torch or numpy) -> the net's output for the batch.

        Checked first (pbc.core.validate.as_poses): shape, finiteness and (see ``check_rotation``) rotations; a
        single pose is refused rather than read as a batch of J*9 scalars.
        """
        # the joints of the pose the net reads (all of them, or a garment's own: the necktie keeps 4 of 10)
        j = getattr(self.net, "num_joints", None) or pose.shape[-1] // 9
        check = self.hparams.get("check_rotation")
        rot, batched = as_poses(pose, j, what="ClothModule pose",
                                check_rotation=(not self.training) if check is None else bool(check))
        if not batched:
            raise ValueError(f"ClothModule pose: got one pose of shape {tuple(pose.shape)}; the module takes a "
                             f"batch, (B, {j * 9}) or (B, {j}, 3, 3): pass pose[None] for one pose")
        return self.net(rot.to(self.device).reshape(rot.shape[0], -1))

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
        self.check_finite(total, split, batch, batch_idx)
        bs = batch["pose"].shape[0]
        # a patch model's vertex metrics cover its patch only: their names say so (patch_vertex_error_cm)
        logs = {scoped_name(k, self.hparams.kind): v for k, v in logs.items()}
        shown = {k for k in logs if on_progress_bar(split, k)}
        for keys, bar in ((shown, True), (set(logs) - shown, False)):
            self.log_dict({f"{split}/{k}": v.detach() if k != "loss" else v for k, v in logs.items() if k in keys},
                          on_step=split == "train", on_epoch=True, batch_size=bs, prog_bar=bar,
                          add_dataloader_idx=False)
        if split in TEST_SPLITS:
            self._record_spread(split, logs, pos, t["verts"], idv)
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

    # ------------------------------------------------------------------------------ per-pose spread
    @torch.no_grad()
    def check_finite(self, total: Tensor, split: str, batch: dict, batch_idx: int, detail: str = "") -> None:
        """Stop on a non-finite loss, naming where (step, epoch, batch, sample ids): never train a NaN model."""
        if torch.isfinite(total):
            return
        which = batch.get("index")
        raise FloatingPointError(
            f"non-finite {split} loss {total.item()}{detail} at global step {self.global_step}, epoch "
            f"{self.current_epoch}, batch {batch_idx}"
            + (f" (sample ids {which.tolist()})" if which is not None else "")
            + "; stopping instead of training a NaN model")

    def _record_spread(self, split: str, logs: dict, pos: Tensor, verts: Tensor, ids: Tensor | None) -> None:
        """Keep each test pose's vertex error (cm), so the epoch end can log their spread as
        ``<split>/<vertex error name>_std`` (the error bars of pbc.report's figures)."""
        name = next((k for k in logs if k.endswith("vertex_error_cm")), None)
        if name is None:
            return
        if getattr(self, "_per_pose", None) is None:
            self._per_pose: dict[str, list[Tensor]] = {}
        self._per_pose.setdefault(f"{split}/{name}_std", []).append(vertex_error_cm_per_pose(pos, verts, ids).cpu())

    def on_test_epoch_start(self) -> None:
        self._per_pose = {}

    def on_test_epoch_end(self) -> None:
        spread, self._per_pose = getattr(self, "_per_pose", None) or {}, {}
        for key, parts in spread.items():
            # every rank's poses (single device: the tensor itself)
            errors = self.all_gather(torch.cat(parts).to(self.device)).flatten().double()
            # the spread over poses (population std: one pose -> 0, not NaN)
            self.log(key, errors.std(unbiased=False).float() if errors.numel() else errors.new_zeros(()).float(),
                     add_dataloader_idx=False)

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
        keep = getattr(self.net, "input_joints", None)  # the joints the net reads (all, or a garment's own)
        pose = torch.cat([pose_features(b["pose"], keep).double() for b in loader])
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
        elif scale is not None:
            # one training pose has no spread: each channel's own size in it (RMS over its pixels) sets the
            # scale, not the 1 m default, with which a 3-drape smoke fit read 1e18 cm on validation
            img = mean[0]
            per_channel = [img[c][img[c] != 0].pow(2).mean().sqrt() if (img[c] != 0).any() else img.new_ones(())
                           for c in range(img.shape[0])]
            scale.copy_(torch.stack(per_channel).float().view_as(scale))
            log.warning("the train split holds 1 pose: the model can only learn that pose (make more data: "
                        "data.num_samples)")
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
PANEL_COLUMNS = ("pred", "truth", "|error|")


def panel_error_cm(pred: Tensor, gt: Tensor, mask: Tensor) -> Tensor:
    """Per-pixel error of cloth images in cm: pred, gt (B, 3P, H, W) metres (P pieces of (du, dv, dn)),
    mask (B, 3P or 1, H, W) -> (B, P, H, W), the norm of each piece's offset difference, 0 off the charts."""
    b, c, h, w = pred.shape
    diff = (pred - gt).reshape(b, c // 3, 3, h, w).norm(dim=2)
    inside = mask.expand(b, c, h, w).reshape(b, c // 3, 3, h, w)[:, :, 0] > 0
    return diff * inside * 100.0


def _offset_rgb(x: Tensor, scale_cm: float) -> Tensor:
    """(3, H, W) signed offsets in metres -> (H, W, 3) [0, 1] RGB at a fixed scale, grey = no offset."""
    return (0.5 + x * 100.0 / (2 * scale_cm)).clamp(0, 1).permute(1, 2, 0)


def panel_tag(error_scale_cm: float) -> str:
    """The TensorBoard tag of the image panel; it names the fixed error colour scale."""
    return f"val/panel_err_0-{error_scale_cm:g}cm"


def panel_figure(pred: Tensor, gt: Tensor, mask: Tensor, error_scale_cm: float, offset_scale_cm: float,
                 names: list[str] | None = None):
    """A matplotlib figure: one row per (pose, piece), columns pred | truth | |error|, all at fixed scales.

    pred, gt (B, 3P, H, W) metres, mask (B or 1, 3P or 1, H, W). Offsets map to RGB at +-``offset_scale_cm``
    (grey = 0); the error column is the per-pixel offset error on 0..``error_scale_cm`` (colour bar), so
    brightness means the same across poses and epochs.
    """
    pred, gt, mask = pred.detach().float().cpu(), gt.detach().float().cpu(), mask.detach().float().cpu()
    mask = mask.expand(pred.shape[0], -1, -1, -1)  # a target's mask is one for the batch, (1, C, H, W)
    err = panel_error_cm(pred, gt, mask)
    b, p = err.shape[:2]
    pieces = names or (["front", "back"] if p == 2 else [f"piece {k}" for k in range(p)])
    fig, axes = plt.subplots(b * p, 3, figsize=(6.4, 1.9 * b * p + 0.8), squeeze=False, layout="constrained")
    for i in range(b):
        for k in range(p):
            row, s = i * p + k, slice(3 * k, 3 * k + 3)
            m = mask[i].expand_as(pred[i])[s]
            axes[row, 0].imshow(_offset_rgb(pred[i][s] * m, offset_scale_cm).numpy())
            axes[row, 1].imshow(_offset_rgb(gt[i][s], offset_scale_cm).numpy())
            h = axes[row, 2].imshow(err[i, k].numpy(), cmap="magma", vmin=0.0, vmax=error_scale_cm)
            axes[row, 0].set_ylabel(f"pose {i} {pieces[k]}", fontsize=8)
    for col, title in enumerate(PANEL_COLUMNS):
        axes[0, col].set_title(title if col < 2 else f"{title} (0-{error_scale_cm:g} cm)", fontsize=9)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(h, ax=axes.ravel().tolist(), location="bottom", shrink=0.5, aspect=30,
                 label=f"|error| (cm), clipped at {error_scale_cm:g}")
    fig.suptitle(f"offsets (du, dv, dn) as RGB at ±{offset_scale_cm:g} cm, grey = 0", fontsize=8)
    return fig


def _tensorboard(trainer):
    for lg in trainer.loggers:
        if isinstance(lg, L.pytorch.loggers.TensorBoardLogger):
            return lg.experiment
    return None


class ImagePanel(L.Callback):
    """Every ``every_n_epochs`` validation epochs and at the end of fit, log pred | truth | |error| for
    ``num_poses`` fixed val poses (:func:`panel_figure`, fixed scales; tag :func:`panel_tag`); at the end of
    fit also log one predicted mesh (``add_mesh``) and write it as OBJ under ``mesh_dir``."""

    def __init__(self, every_n_epochs: int = 5, num_poses: int = 4, mesh_dir: str | None = None,
                 error_scale_cm: float = 5.0, offset_scale_cm: float = 10.0) -> None:
        self.every = max(1, int(every_n_epochs))
        self.num = int(num_poses)
        self.error_scale_cm = float(error_scale_cm)
        self.offset_scale_cm = float(offset_scale_cm)
        self.mesh_dir = Path(mesh_dir) if mesh_dir else None
        self._batch: dict | None = None
        self._panel_step: int | None = None  # global step of the last panel written

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
        if out is not None:
            self._log_panel(tb, trainer, pl_module, out)

    def _log_panel(self, tb, trainer, pl_module, out) -> None:
        if tb is None or pl_module.target.image_size is None or self._panel_step == trainer.global_step:
            return
        _, t, pred, _ = out
        fig = panel_figure(pred, t["image"], t["mask"], self.error_scale_cm, self.offset_scale_cm)
        tb.add_figure(panel_tag(self.error_scale_cm), fig, global_step=trainer.global_step, close=True)
        self._panel_step = trainer.global_step

    def on_fit_end(self, trainer, pl_module) -> None:
        if not trainer.is_global_zero:
            return
        out = self._predict(trainer, pl_module)
        if out is None:
            return
        # a run shorter than every_n_epochs (trainer=smoke) still gets its panel: the final weights', unless
        # the last validation epoch just wrote it
        self._log_panel(_tensorboard(trainer), trainer, pl_module, out)
        pos, gt = out[3][0].float().cpu(), out[1]["verts"][0].float().cpu()
        target = pl_module.target
        faces, ids = target.faces.cpu(), target.vertices
        # a patch model predicts its patch only (the rest is ground truth): its meshes are the patch's
        # submesh, and their names say so
        tag = "" if target.patch_id is None else f"_patch{int(target.patch_id):02d}"
        garment = getattr(trainer.datamodule, "data", None)
        garment = getattr(garment, "garment", None)
        if self.mesh_dir is not None and garment is not None:
            for name, v in (("pred", pos), ("gt", gt)):
                write_garment_mesh(self.mesh_dir / f"{name}_val0{tag}.obj", garment, v, ids,
                                   header=[f"{name} of the first validation pose (pbc.train, end of fit)"])
        tb = _tensorboard(trainer)
        if tb is not None:
            if ids is not None:
                _, faces, ids = submesh(faces.numpy(), ids.cpu().numpy())
                pos, faces = pos[torch.as_tensor(ids)], torch.as_tensor(faces)
            tb.add_mesh(f"val/pred_mesh{tag}", vertices=pos[None], faces=faces[None].int(),
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

