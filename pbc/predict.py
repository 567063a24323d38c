"""Fast inference: pose -> garment vertices, from the whole-shirt model or the 28 patch models + stitch.

One job: load the 29 checkpoints once (`ClothPredictor.from_runs`) and answer `predictor(pose)` with
`(V, 3)` (or `(B, V, 3)` for a batch) garment positions in metres.

The 28 patch decoders are identical networks, so they run as one stacked network
(`StackedPatchNet`): BatchNorm folded into the transpose convolutions, the 28 first linear layers as
one matmul, and per group either a batched matmul + `fold` (col2im; best for the weight-bound first
groups at small batch) or one grouped transpose convolution holding all 28 models in channels-last
layout (best for the large late groups). `bench/predict.py` measures the alternatives; the defaults
here are what measured fastest on the 2-core CPU. The layout is chosen per device at forward time
(`default_layer_modes`): the bmm+fold groups are a CPU tuning; on a GPU every group runs as one grouped
convolution unless `layer_modes` says otherwise. Every weight is a parameter or buffer, so
`.to(device)` / `ClothPredictor(..., device=)` move all of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import Tensor, nn

import pbc.data.dataset as datasets
from pbc.models.decoder import ConvDecoder
from pbc.pixels.frames import from_offsets
from pbc.pixels.reconstruct import Skinner
from pbc.pixels.target import image_operators, patch_crops
from pbc.runs import NUM_PATCHES, RunInfo, find_runs, read_run, select_patch_runs  # noqa: F401  (re-exported)
from pbc.stitch.seams import NEEDS_WHOLE, build_stitcher

# measured fastest per transpose-conv group at batch 1 on the 2-core CPU (see bench/predict.py)
DEFAULT_LAYER_MODES = ("bmm", "bmm", "grouped", "grouped", "grouped")
# on a GPU: one grouped transpose convolution per group (cuDNN); the H100 figures are owed (bench/predict.py
# --device cuda prints every layout side by side)
GPU_LAYER_MODES = ("grouped", "grouped", "grouped", "grouped", "grouped")
PRECISIONS = {"float32": torch.float32, "bfloat16": torch.bfloat16}


# ----------------------------------------------------------------------------- runs


def load_decoder(checkpoint: str | Path) -> tuple[ConvDecoder, dict]:
    """The network of a ClothModule checkpoint, in eval mode, and the checkpoint's hparams."""

    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    hp = ck["hyper_parameters"]
    net = instantiate(hp["net"])
    state = {k[4:]: v for k, v in ck["state_dict"].items() if k.startswith("net.")}
    net.load_state_dict(state)
    return net.eval(), hp


# ----------------------------------------------------------------------------- stacked patches


def default_layer_modes(device: torch.device | str) -> tuple[str, ...]:
    """The per-group layout used on `device` when a StackedPatchNet is given no `layer_modes`."""
    return DEFAULT_LAYER_MODES if torch.device(device).type == "cpu" else GPU_LAYER_MODES


def _fold_bn(conv: nn.ConvTranspose2d, bn: nn.BatchNorm2d) -> tuple[Tensor, Tensor]:
    """Eval-mode BatchNorm folded into the preceding transpose conv: weight (cin, cout, k, k), bias (cout,)."""
    s = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    w = conv.weight * s[None, :, None, None]
    b = (conv.bias - bn.running_mean) * s + bn.bias
    return w.detach(), b.detach()


class StackedPatchNet(nn.Module):
    """P identical `ConvDecoder`s (linear first layer, k4/s2/p1 groups) evaluated as one network.

    forward: pose (B, in_features) -> crops (B, P, C, h, w) float32, equal to stacking the decoders'
    outputs in eval mode. layer_modes: per group "bmm" (batched matmul + fold) or "grouped" (grouped
    conv); None = `default_layer_modes` of the input's device, chosen at every forward.
    dtype: the weights' and activations' dtype; ``torch.bfloat16`` runs on the CPU's bf16/AMX
    units (on the reference CPU at batch 1: 85 vs 246 ms for the 28 nets, 1.5x on the full pose -> mesh,
    0.015 cm mean vertex difference; bench/predict.py).
    """

    def __init__(self, decoders: Sequence[ConvDecoder], layer_modes: Sequence[str] | None = None,
                 channels_last: bool = True, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.dtype = dtype
        d0 = decoders[0]
        if d0.first_layer != "linear" or len(d0.mlp) > 0:
            raise ValueError("StackedPatchNet needs decoders with a linear first layer and no hidden MLP")
        self.P = len(decoders)
        self.c0, self.s0 = d0.start_channels, d0.start_size
        self.channels_last = channels_last
        self.bmm_max_batch = 4
        # each decoder's pose standardisation folded into its first layer: W (x - m) / s + b
        ws = [d.first.weight.detach() / d.input_scale for d in decoders]
        self.first_w = nn.Parameter(torch.cat(ws), False)
        self.first_b = nn.Parameter(torch.cat([d.first.bias.detach() - w @ d.input_mean for w, d in
                                               zip(ws, decoders, strict=True)]), False)
        groups = [list(d.groups) for d in decoders]
        n = len(groups[0]) // 3
        self.num_groups = n
        self.modes = None if layer_modes is None else self._fit_modes(layer_modes)
        bad = set(self.modes or ()) - {"bmm", "grouped"}
        if bad:
            raise ValueError(f"layer_modes entries must be 'bmm' or 'grouped', got {sorted(bad)}")
        # the bmm layout is kept for the groups any layout this net may run uses it for
        bmm_groups = {i for modes in ([self.modes] if self.modes else [self._fit_modes(DEFAULT_LAYER_MODES),
                                                                      self._fit_modes(GPU_LAYER_MODES)])
                      for i, m in enumerate(modes) if m == "bmm"}
        self.weights, self.biases = nn.ParameterList(), nn.ParameterList()
        for i in range(n):
            convs = [g[3 * i] for g in groups]
            if any(c.stride != (2, 2) or c.kernel_size != (4, 4) or c.padding != (1, 1) for c in convs):
                raise ValueError("StackedPatchNet supports square k4/s2/p1 groups only")
            wb = [_fold_bn(g[3 * i], g[3 * i + 1]) for g in groups]
            w = torch.stack([x[0] for x in wb])  # (P, cin, cout, 4, 4)
            self.weights.append(nn.Parameter(w.flatten(0, 1).contiguous(), False))  # grouped layout
            self.biases.append(nn.Parameter(torch.stack([x[1] for x in wb]), False))  # (P, cout)
        # bmm layout: (P, cout*16, cin) for the groups that use it; buffers, so .to() moves them
        for i in sorted(bmm_groups):
            self.register_buffer(f"bmm_{i}", self.weights[i].view(self.P, -1, self.weights[i].shape[1] * 16)
                                 .transpose(1, 2).contiguous(), persistent=False)
        # each decoder's output_scale (C,) folded into its head
        scale = torch.cat([d.output_scale.detach().flatten() for d in decoders])  # (P*C,)
        self.head_w = nn.Parameter(torch.cat([d.head.weight.detach() for d in decoders]) * scale[:, None, None, None],
                                   False)
        self.head_b = nn.Parameter(torch.cat([d.head.bias.detach() for d in decoders]) * scale, False)
        self.head_pad = d0.head.padding
        self.out_channels = d0.out_channels
        self.output_mean = nn.Parameter(torch.cat([d.output_mean for d in decoders], 1), False)  # (1, P*C, h, w)
        if dtype != torch.float32:
            # the mean image stays float32: it is added after the network, where bf16 would round it
            for name, prm in self.named_parameters():
                if name != "output_mean":
                    prm.data = prm.data.to(dtype)
            for buf in self.buffers():
                buf.data = buf.data.to(dtype)

    def _fit_modes(self, modes: Sequence[str]) -> tuple[str, ...]:
        """Modes padded with the last one (or cut) to the number of groups."""
        modes = tuple(modes)
        return (modes + (modes[-1],) * (self.num_groups - len(modes)))[:self.num_groups]

    def layer_modes(self, device: torch.device | str) -> tuple[str, ...]:
        """The per-group layout a forward on `device` runs."""
        return self.modes if self.modes is not None else self._fit_modes(default_layer_modes(device))

    def forward(self, pose: Tensor) -> Tensor:
        B, P = pose.shape[0], self.P
        h0, w0 = self.s0
        x = F.linear(pose.reshape(B, -1).to(self.dtype), self.first_w, self.first_b).relu_()
        x = x.view(B, P * self.c0, h0, w0)
        for i, mode in enumerate(self.layer_modes(pose.device)):
            w, b = self.weights[i], self.biases[i]
            cin, cout = w.shape[0] // P, w.shape[1]
            s = x.shape[-1]
            # bmm+fold wins only while the group is weight-bound (small batch): at batch 32 the
            # all-grouped form measured 1.3x faster than the mix (bench/predict.py)
            if mode == "bmm" and B <= self.bmm_max_batch:
                x3 = x.reshape(B, P, cin, s * s).permute(1, 2, 0, 3).reshape(P, cin, B * s * s)
                cols = torch.bmm(getattr(self, f"bmm_{i}"), x3)  # (P, cout*16, B*s*s)
                cols = cols.view(P, cout * 16, B, s * s).permute(2, 0, 1, 3).reshape(B * P, cout * 16, s * s)
                x = F.fold(cols, (2 * s, 2 * s), 4, stride=2, padding=1).view(B, P * cout, 2 * s, 2 * s)
                x = x.add_(b.reshape(1, P * cout, 1, 1)).relu_()  # in place: these maps are the big ones
            else:
                if self.channels_last:
                    x = x.contiguous(memory_format=torch.channels_last)
                x = F.conv_transpose2d(x, w, b.reshape(-1), stride=2, padding=1, groups=P).relu_()
        y = F.conv2d(x, self.head_w, self.head_b, padding=self.head_pad, groups=P).float().add_(self.output_mean)
        return y.reshape(B, P, self.out_channels, y.shape[-2], y.shape[-1])


class LoopPatchNet(nn.Module):
    """The reference: the P decoders one after the other -> (B, P, C, h, w)."""

    def __init__(self, decoders: Sequence[ConvDecoder]):
        super().__init__()
        self.nets = nn.ModuleList(decoders)

    def forward(self, pose: Tensor) -> Tensor:
        return torch.stack([n(pose.reshape(pose.shape[0], -1)) for n in self.nets], 1)


# ----------------------------------------------------------------------------- predictor


class ClothPredictor:
    """pose (J, 3, 3) -> (V, 3), or (B, J, 3, 3) -> (B, V, 3), garment positions in metres.

    Built by `from_runs`. `model="patches"` (28 patch models + the seam method `method`) or "whole".
    precision: "float32" (exact) or "bfloat16" (the stacked patch net in bf16 on the CPU's AMX/AVX512-bf16
    units; the stitch, skinning and the whole model stay float32).
    device: where the networks, operators and stitch run ("cpu", "cuda", ...); poses are moved there and
    meshes come back on it. layer_modes: None = the device's default layout (`default_layer_modes`).
    """

    def __init__(self, dataset, image_cfg, whole_net: ConvDecoder | None, patch_nets: Sequence[ConvDecoder],
                 stitch_cfg, space: str = "local", pca=None, cache_dir=None, backend: str = "stacked",
                 layer_modes: Sequence[str] | None = None, threads: int | None = None,
                 precision: str = "float32", device: str | torch.device = "cpu"):
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        if precision != "float32" and backend != "stacked":
            raise ValueError(f"precision={precision!r} needs backend='stacked' (the loop runs the float32 decoders)")
        if threads:
            torch.set_num_threads(int(threads))
        self.dataset, self.space = dataset, space
        # the operators exactly as training built them (pbc.pixels.target: one cache, one method)
        self.skinner = Skinner(dataset.body, dataset.garment, dataset.embedding)
        self.faces = torch.as_tensor(dataset.garment.faces).long()
        self.ops_whole = image_operators(dataset, image_cfg, "whole", cache_dir)
        self.ops_patch = image_operators(dataset, image_cfg, "patch", cache_dir)
        self.crops = patch_crops(dataset, image_cfg, self.ops_patch)
        self.stitcher = build_stitcher(self.ops_patch, self.crops, dataset.garment, dataset.cage, stitch_cfg,
                                       pca=pca)
        self.method = str(stitch_cfg.method)
        self.whole_net = whole_net
        self.patch_nets = list(patch_nets)
        self.backend = backend
        self.precision = precision
        self.patch_net = (StackedPatchNet(self.patch_nets, layer_modes, dtype=PRECISIONS[precision])
                          if backend == "stacked" else LoopPatchNet(self.patch_nets)).eval()
        self.to(device)

    def to(self, device: str | torch.device) -> ClothPredictor:
        """Move the networks and the stitcher to `device` (operators and skinning follow the pose's device)."""
        self.device = torch.device(device)
        self.patch_net.to(self.device)
        if self.whole_net is not None:
            self.whole_net.to(self.device)
        self.stitcher.to(self.device)
        return self

    @classmethod
    def from_runs(cls, whole_run, patch_runs, stitch_cfg, pca=None, **kw) -> ClothPredictor:
        """whole_run: run dir (or None); patch_runs: run dirs and/or a sweep dir (all 28 patches)."""
        whole = read_run(whole_run) if whole_run else None
        if whole is not None and whole.kind != "whole":
            raise ValueError(f"{whole.dir}: a {whole.kind!r} run, not a whole-shirt run")
        first = whole or read_run(find_runs(patch_runs)[0])
        cfg = OmegaConf.create(first.config)
        dataset = datasets.load_dataset(OmegaConf.select(cfg, "data.dir"))
        ghash = str(dataset.manifest.get("garment_hash", ""))
        if whole is not None and whole.garment_hash != ghash:
            raise ValueError(f"{whole.dir}: trained on garment {whole.garment_hash!r}, the dataset is {ghash!r}")
        runs = select_patch_runs(patch_runs, ghash, len(dataset.cage.patches))
        whole_net = load_decoder(whole.checkpoint)[0] if whole is not None else None
        nets, spaces = [], set()
        for r in runs:
            net, hp = load_decoder(r.checkpoint)
            nets.append(net)
            spaces.add(hp.get("space", "local"))
        if len(spaces) > 1:
            raise ValueError(f"patch runs use different offset spaces {sorted(spaces)}")
        return cls(dataset, cfg.image, whole_net, nets, stitch_cfg, space=spaces.pop(), pca=pca, **kw)

    # -------------------------------------------------------------------- pieces
    def frames(self, pose: Tensor) -> tuple[Tensor, Tensor]:
        return self.skinner(pose)

    @torch.inference_mode()
    def patch_crops(self, pose: Tensor) -> Tensor:
        """pose (B, J, 3, 3) -> crops (B, P, 3, h, w), on the predictor's device."""
        return self.patch_net(pose.reshape(pose.shape[0], -1).to(self.device, torch.float32))

    @torch.inference_mode()
    def whole_offsets(self, pose: Tensor) -> Tensor:
        if self.whole_net is None:
            raise ValueError("no whole-shirt run was given")
        return self.ops_whole.sample(self.whole_net(pose.reshape(pose.shape[0], -1).to(self.device, torch.float32)))

    @torch.inference_mode()
    def __call__(self, pose: Tensor, model: str = "patches", method: str | None = None) -> Tensor:
        single = pose.ndim == 3
        pose = pose[None] if single else pose
        pose = pose.to(self.device, torch.float32)
        self.stitcher.to(self.device)  # a basis set after construction (pbc.evaluate's PCA) follows too
        if model == "whole":
            off = self.whole_offsets(pose)
        else:
            method = method or self.method
            whole = self.whole_offsets(pose) if method in NEEDS_WHOLE else None
            off = self.stitcher(self.patch_crops(pose), method, whole)
        anchors, frames = self.skinner(pose)
        x = from_offsets(off, anchors, frames, self.space)
        return x[0] if single else x
