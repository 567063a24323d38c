"""All patch models in one job: P identical patch decoders trained as one stacked network.

One job: train the cage's P patch decoders (appendix D.7, E.1) as one network whose layers are grouped
(``groups=P``) convolutions, so one forward/backward serves every patch and the patch-resolution image is
rendered once per sample (``pbc.pixels.target.PatchesTarget``); then hand back P checkpoints that load
exactly as P single-patch runs do (``export_patch_runs``).

Exactness: patch p owns channel block p of every layer, and BatchNorm normalises per channel, so its
statistics are per patch; the loss is the sum of the per-patch losses, so patch p's gradient is that of
its own loss; Adam updates element-wise. One optimiser step of the stacked job therefore equals P
single-patch steps on the same batch and initial weights (``tests/test_stacked.py``). What would break
it: a global gradient-norm clip or weight decay coupled across patches (none are configured).

Layout: ``StackedDecoder`` pose (B, in) -> (B, P*C, H, W), channels [C p, C (p+1)) = patch p's crop.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor, nn

from pbc.core.io import atomic_path
from pbc.core.runs import PATCH_EXPORT_DIR, ModelKind, RunRecord, scoped_name
from pbc.geometry.meshops import vertex_normals
from pbc.models.decoder import ConvDecoder, add_buffer_defaults, group_strides, pose_features, set_pose_joints
from pbc.models.losses import edge_loss, image_loss, normal_loss
from pbc.models.metrics import normal_cosine_distance, vertex_error_cm
from pbc.models.module import ClothModule
from pbc.pixels.reconstruct import edge_lengths

log = logging.getLogger(__name__)
DECODER = "pbc.models.decoder.ConvDecoder"


class StackedDecoder(nn.Module):
    """P ``ConvDecoder``s (linear first layer, no hidden MLP) as one network.

    forward: pose (B, in_features) -> (B, P*out_channels, H, W), equal to concatenating the P decoders'
    outputs along channels, in train and eval mode alike (per-patch BatchNorm). Built from P freshly
    initialised decoders (the same draws as P single runs made in a row), or ``from_decoders``.
    """

    def __init__(self, num_patches: int, in_features: int, out_channels: int, output_size: Sequence[int],
                 start_size: Sequence[int], start_channels: int, first_layer: str = "linear",
                 hidden: Sequence[int] = (), final_kernel: int = 3, input_joints: Sequence[int] | None = None,
                 num_joints: int | None = None) -> None:
        super().__init__()
        if first_layer != "linear" or len(hidden):
            raise ValueError("StackedDecoder stacks patch decoders: first_layer must be 'linear' with no "
                             f"hidden MLP, got first_layer={first_layer!r}, hidden={list(hidden)}")
        P = int(num_patches)
        if P < 1:
            raise ValueError(f"num_patches must be >= 1, got {num_patches}")
        self.num_patches = P
        self.decoder_kwargs = {"in_features": int(in_features), "out_channels": int(out_channels),
                               "output_size": [int(v) for v in output_size],
                               "start_size": [int(v) for v in start_size], "start_channels": int(start_channels),
                               "first_layer": "linear", "final_kernel": int(final_kernel)}
        if input_joints is not None:  # a garment's own joints (register_pose_input); absent = every joint
            self.decoder_kwargs.update(input_joints=[int(j) for j in input_joints], num_joints=num_joints)
        self.in_features, self.out_channels = int(in_features), int(out_channels)
        self.start_size, self.start_channels = tuple(int(v) for v in start_size), int(start_channels)
        h0, w0 = self.start_size
        c = self.start_channels
        self.first_weight = nn.Parameter(torch.empty(P, c * h0 * w0, self.in_features))
        self.first_bias = nn.Parameter(torch.empty(P, c * h0 * w0))
        groups: list[nn.Module] = []
        for sh, sw in group_strides(self.start_size, output_size):
            kernel = (4 if sh == 2 else 3, 4 if sw == 2 else 3)
            groups += [nn.ConvTranspose2d(P * c, P * (c // 2), kernel, stride=(sh, sw), padding=1, groups=P),
                       nn.BatchNorm2d(P * (c // 2)), nn.ReLU(inplace=True)]
            c //= 2
        self.groups = nn.Sequential(*groups)
        self.head = nn.Conv2d(P * c, P * self.out_channels, final_kernel, padding=final_kernel // 2, groups=P)
        self.register_buffer("output_mean", torch.zeros(1, P * self.out_channels, *[int(v) for v in output_size]))
        self.register_buffer("output_scale", torch.ones(1, P * self.out_channels, 1, 1))
        self.register_buffer("input_mean", torch.zeros(P, self.in_features))
        self.register_buffer("input_scale", torch.ones(P, self.in_features))
        add_buffer_defaults(self, ("output_scale", "input_mean", "input_scale"))
        set_pose_joints(self, self.in_features, input_joints, num_joints)
        # initialised exactly as P single decoders built one after the other
        for p in range(P):
            self.load_patch(p, ConvDecoder(**self.decoder_kwargs))

    @classmethod
    def from_decoders(cls, decoders: Sequence[ConvDecoder]) -> StackedDecoder:
        d = decoders[0]
        net = cls(len(decoders), d.in_features, d.out_channels, d.output_size, d.start_size, d.start_channels,
                  d.first_layer, [m.out_features for m in d.mlp if isinstance(m, nn.Linear)], d.head.kernel_size[0],
                  d.input_joints, d.num_joints)
        for p, dec in enumerate(decoders):
            net.load_patch(p, dec)
        return net.to(d.output_mean.device)

    # ------------------------------------------------------------------ patch <-> stack
    def _slices(self):
        """(stacked tensor, single-decoder key, dim, block size) for every tensor of the network."""
        P = self.num_patches
        yield self.first_weight, "first.weight", 0, None
        yield self.first_bias, "first.bias", 0, None
        for i, m in enumerate(self.groups):
            if isinstance(m, nn.ConvTranspose2d):
                yield m.weight, f"groups.{i}.weight", 0, m.weight.shape[0] // P
                yield m.bias, f"groups.{i}.bias", 0, m.bias.shape[0] // P
            elif isinstance(m, nn.BatchNorm2d):
                for k in ("weight", "bias", "running_mean", "running_var"):
                    t = getattr(m, k)
                    yield t, f"groups.{i}.{k}", 0, t.shape[0] // P
        yield self.head.weight, "head.weight", 0, self.head.weight.shape[0] // P
        yield self.head.bias, "head.bias", 0, self.head.bias.shape[0] // P
        yield self.output_mean, "output_mean", 1, self.out_channels
        yield self.output_scale, "output_scale", 1, self.out_channels
        yield self.input_mean, "input_mean", 0, None
        yield self.input_scale, "input_scale", 0, None

    @staticmethod
    def _block(t: Tensor, p: int, dim: int, size: int | None) -> Tensor:
        return t[p] if size is None else t.narrow(dim, p * size, size)

    @torch.no_grad()
    def load_patch(self, p: int, decoder: ConvDecoder) -> None:
        """Copy decoder's weights, BatchNorm statistics and buffers into patch p's block."""
        state = decoder.state_dict()
        for t, key, dim, size in self._slices():
            self._block(t, p, dim, size).copy_(state[key])
        for i, m in enumerate(self.groups):
            if isinstance(m, nn.BatchNorm2d):
                m.num_batches_tracked.copy_(state[f"groups.{i}.num_batches_tracked"])

    @torch.no_grad()
    def patch_state(self, p: int) -> dict[str, Tensor]:
        """Patch p's block as a ``ConvDecoder`` state dict (CPU copies)."""
        out = {key: self._block(t, p, dim, size).detach().cpu().clone() for t, key, dim, size in self._slices()}
        for i, m in enumerate(self.groups):
            if isinstance(m, nn.BatchNorm2d):
                out[f"groups.{i}.num_batches_tracked"] = m.num_batches_tracked.detach().cpu().clone()
        return out

    def decoder(self, p: int) -> ConvDecoder:
        """Patch p as a standalone ``ConvDecoder`` (same mode as this network)."""
        net = ConvDecoder(**self.decoder_kwargs)
        net.load_state_dict(self.patch_state(p))
        return net.train(self.training)

    def decoder_config(self) -> dict:
        """The Hydra node of one patch's decoder (what a single-patch checkpoint's hparams hold)."""
        return {"_target_": DECODER, **copy.deepcopy(self.decoder_kwargs)}

    # ------------------------------------------------------------------ forward
    def forward(self, pose: Tensor) -> Tensor:
        B, P = pose.shape[0], self.num_patches
        x = (pose_features(pose, self.input_joints)[:, None] - self.input_mean) / self.input_scale  # (B, P, in)
        # the P first layers as one batched matmul: (P, B, in) @ (P, in, out)
        x = torch.baddbmm(self.first_bias[:, None], x.transpose(0, 1), self.first_weight.transpose(1, 2))
        h0, w0 = self.start_size
        x = torch.relu(x.transpose(0, 1).reshape(B, P * self.start_channels, h0, w0))
        return self.head(self.groups(x)) * self.output_scale + self.output_mean


# ---------------------------------------------------------------------------------- the module
class StackedPatchModule(ClothModule):
    """The ClothModule of ``model.kind=patches``: a ``StackedDecoder`` on a ``PatchesTarget``.

    Loss: the sum over patches of each patch's single-run loss (eq. 1 on its crop + the normal / edge
    terms on its vertices / edges); eq. 1 runs once over the channel-stacked crops (the same sum).
    Logged per split: ``patch_NN/vertex_error_cm`` and ``patch_NN/normal_distance`` per patch;
    ``vertex_error_cm`` and ``normal_distance`` as the mean over patches (the checkpoint monitor
    ``val/vertex_error_cm`` is that mean); ``loss`` and the loss terms as sums.
    """

    def step(self, batch: dict, split: str, batch_idx: int) -> tuple[Tensor, dict]:
        t = self.targets(batch)
        pred = self(batch["pose"])  # (B, P*3, S, S)
        lc = self.hparams.loss
        truth, mask = self.target.truth(t)
        subs = self.target.patches
        faces, _ = self.target.topology(pred.device)
        # eq. 1 over the channel-stacked crops in one call: with one mask piece per channel it is the sum of
        # the per-patch losses exactly (image_loss sums its pieces), without P slices in the backward
        image = image_loss(pred, truth, mask, lc["norm"])
        crops = pred.unflatten(1, (len(subs), -1)).unbind(1)  # P x (B, 3, S, S); one stack in the backward
        # each patch's 3D: ground truth outside its vertices (as its single run builds it)
        pos = torch.stack([s.positions(crops[p], t) for p, s in enumerate(subs)])  # (P, B, V, 3)
        need_normals = lc["normal_weight"] > 0 or split != "train"
        n_pred = n_gt = None
        if need_normals:
            P, B, V = pos.shape[:3]
            n_pred = vertex_normals(pos.reshape(P * B, V, 3), faces).view(P, B, V, 3)
            n_gt = vertex_normals(t["verts"], faces)
        logs: dict[str, Tensor] = {}
        terms: dict[str, list[Tensor]] = {"normal_loss": [], "edge_loss": []}
        errs, ndist = [], []
        total = image
        for p, sub in enumerate(subs):
            ids = sub.vertices.to(pred.device)
            if lc["normal_weight"] > 0:
                nl = normal_loss(n_pred[p][:, ids], n_gt[:, ids])
                terms["normal_loss"].append(nl)
                total = total + lc["normal_weight"] * nl
            if lc["edge_weight"] > 0:
                edges = sub.topology(pred.device)[1]
                el = edge_loss(edge_lengths(pos[p], edges), edge_lengths(t["verts"], edges))
                terms["edge_loss"].append(el)
                total = total + lc["edge_weight"] * el
            with torch.no_grad():
                errs.append(vertex_error_cm(pos[p], t["verts"], ids))
                logs[f"patch_{sub.patch_id:02d}/vertex_error_cm"] = errs[-1]
                if n_pred is not None:
                    ndist.append(normal_cosine_distance(n_pred[p], n_gt, ids))
                    logs[f"patch_{sub.patch_id:02d}/normal_distance"] = ndist[-1]
        logs["image_loss"] = image
        for k, v in terms.items():
            if v:
                logs[k] = torch.stack(v).sum()
        logs["loss"] = total
        logs["vertex_error_cm"] = torch.stack(errs).mean()
        if ndist:
            logs["normal_distance"] = torch.stack(ndist).mean()
        if not torch.isfinite(total):
            bad = [s.patch_id for p, s in enumerate(subs) if not torch.isfinite(crops[p]).all()]
            self.check_finite(total, split, batch, batch_idx, f" (non-finite output in patches {bad})")
        bs = batch["pose"].shape[0]
        per_step = {k: v for k, v in logs.items() if not k.startswith("patch_")}
        per_patch = {k: v for k, v in logs.items() if k.startswith("patch_")}
        self.log_dict({f"{split}/{k}": v.detach() if k != "loss" else v for k, v in per_step.items()},
                      on_step=split == "train", on_epoch=True, batch_size=bs, add_dataloader_idx=False)
        # per-patch curves per epoch only: 2 x P scalars a step would swamp the event files
        self.log_dict({f"{split}/{k}": v.detach() for k, v in per_patch.items()}, on_step=False, on_epoch=True,
                      batch_size=bs, add_dataloader_idx=False)
        return total, {"pred": pred.detach(), "image": t["image"], "mask": t["mask"],
                       "positions": self.target.positions(pred.detach(), t)}

    # ------------------------------------------------------------------ export
    def export_runs(self, checkpoint: str | Path, out_dir: str | Path, record: RunRecord, dataset) -> list[str]:
        """Write one single-patch run dir per patch under ``<out_dir>/patches/patch_NN/`` from the stacked
        ``checkpoint``: ``checkpoints/<same name>.ckpt`` (a ClothModule checkpoint of kind ``patch``:
        hparams with the patch's decoder node and identity, ``net.*`` state) and ``metrics.json`` (a patch
        run's record: the patch's test/train scores, identity, config, best checkpoint). Returns the run dirs."""
        return export_patch_runs(checkpoint, out_dir, record, self.target, dataset)


def export_patch_runs(checkpoint: str | Path, out_dir: str | Path, record: RunRecord, target,
                      dataset) -> list[str]:
    """See :meth:`StackedPatchModule.export_runs`; record: the stacked run's; target: its ``PatchesTarget``."""
    checkpoint, out_dir = Path(checkpoint), Path(out_dir)
    if not checkpoint.is_file():
        raise FileNotFoundError(f"cannot export the patch runs: no checkpoint at {checkpoint}")
    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    hp = dict(ck["hyper_parameters"])
    net = StackedDecoder(**{k: v for k, v in hp["net"].items() if k != "_target_"})
    net.load_state_dict({k[4:]: v for k, v in ck["state_dict"].items() if k.startswith("net.")})
    dirs = []
    for p, sub in enumerate(target.patches):
        pid = sub.patch_id
        run = out_dir / PATCH_EXPORT_DIR / f"patch_{pid:02d}"
        ident = target.patch_identity(dataset, p)
        single = dict(hp, net=net.decoder_config(), kind=ModelKind.PATCH.value, patch_id=pid, identity=ident,
                      summary=dict(hp.get("summary") or {}, kind=ModelKind.PATCH.value, patch_id=pid))
        state = {f"net.{k}": v for k, v in net.patch_state(p).items()}
        ckpt = run / "checkpoints" / checkpoint.name
        payload = {k: v for k, v in ck.items() if k in ("epoch", "global_step", "pytorch-lightning_version")}
        payload.update(hyper_parameters=single, state_dict=state, exported_from=str(checkpoint))
        with atomic_path(ckpt) as tmp:
            torch.save(payload, tmp)
        config = copy.deepcopy(record.config)
        config["model"] = dict(config.get("model") or {}, kind=ModelKind.PATCH.value, patch_id=pid,
                               _target_="pbc.models.module.ClothModule", net=net.decoder_config())

        def own(block: dict, key=f"patch_{pid:02d}/") -> dict:
            # the stacked run logs patch p's metrics as patch_NN/<name>; a patch run's are its scoped names
            return {scoped_name(k[len(key):], ModelKind.PATCH): v for k, v in block.items() if k.startswith(key)}

        # no optimized_metric: the checkpoint was chosen by the stacked run's mean over patches, not by this
        # patch's own validation error (exported_from names that run)
        RunRecord(kind=ModelKind.PATCH, test=own(record.test), train=own(record.train), best_checkpoint=str(ckpt),
                  epochs=record.epochs, identity=ident, summary=single["summary"], config=config,
                  data=record.data, exported_from=str(out_dir), pose_range=record.pose_range).write(run)
        dirs.append(str(run))
    log.info("exported %d single-patch runs under %s", len(dirs), out_dir / PATCH_EXPORT_DIR)
    return dirs
