"""Inference: a whole run and its patch runs -> one predictor that maps poses ``(B, J, 3, 3)`` to garment
vertices ``(B, V, 3)``: the whole decoder, the 28 patch decoders as one stacked network (``StackedPatchNet``:
stacked weights, BatchNorm folded, one batched forward) and the stitcher. The jobs (``pbc predict``, the
viewer, ``pbc evaluate``, the shipped models) all predict through ``ClothPredictor``."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import Tensor, nn
from tqdm.auto import tqdm

import pbc.data.dataset as datasets
from pbc.core.config import CONF_DIR
from pbc.core.io import load_checkpoint, user_cache_dir
from pbc.core.runs import ModelKind, Run, find_runs, read_run, run_image_config, select_patch_runs
from pbc.core.validate import as_poses
from pbc.data.dataset import dataset_fingerprint, person_kw
from pbc.data.trimmed import recorded_known_poses
from pbc.geometry.mend import MendSettings, edge_operator, mend_settings, shorten_edges
from pbc.geometry.meshops import median_edge_lengths, mesh_edges
from pbc.models.decoder import ConvDecoder, pose_features
from pbc.motion.known import still_joints
from pbc.pixels.frames import from_offsets, to_offsets
from pbc.pixels.operators import image_sizes
from pbc.pixels.target import dataset_skinner, image_operators, make_target, patch_crops
from pbc.pretrained import pretrained_dir, repair_advice, resolve_run, shipped_model_of
from pbc.stitch.pca import check_pca_matches, dataset_hash, fit_pca
from pbc.stitch.seams import METHODS, NEEDS_WHOLE, build_stitcher

log = logging.getLogger(__name__)


# measured fastest per transpose-conv group at batch 1 on the 2-core CPU (see bench/predict.py)
DEFAULT_LAYER_MODES = ("bmm", "bmm", "grouped", "grouped", "grouped")


# on a GPU: one grouped transpose convolution per group (cuDNN); the H100 figures are owed (bench/predict.py
# --device cuda prints every layout side by side)
GPU_LAYER_MODES = ("grouped", "grouped", "grouped", "grouped", "grouped")


PRECISIONS = {"float32": torch.float32, "bfloat16": torch.bfloat16}


# what a predictor's whole-garment model can be: a whole-shirt image CNN, or a fully connected run (the
# baselines of appendix E.3, per-vertex values; on a 2-core CPU the one that trains to convergence)
WHOLE_KINDS = (ModelKind.WHOLE.value, ModelKind.FC.value)


# what `ClothPredictor(pose, model=...)` answers with: the P patch models stitched, or the whole-shirt model
MODELS = ("patches", "whole")


# the image sizes a patch model's crops follow (pbc.pixels.operators.image_sizes): the stitcher is built
# from one run's, so every patch run must share them
PATCH_SIZE_KEYS = ("patch_resolution", "crop_size", "margin", "patch_pad")


# x86 CPU flags (/proc/cpuinfo) of native bf16 arithmetic; without them torch emulates bf16 in software
# (measured: the stacked patch net ran 30x slower in bf16 than in float32 on such a CPU)
CPU_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


def cpu_flags() -> set[str]:
    """The CPU's feature flags from /proc/cpuinfo (Linux); elsewhere what torch's own probe reports."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    probes = {"avx512_bf16": "_is_avx512_bf16_supported", "amx_bf16": "_is_amx_tile_supported"}
    return {flag for flag, fn in probes.items() if getattr(torch.cpu, fn, lambda: False)()}


def bf16_is_fast(device: str | torch.device) -> bool:
    """Whether ``device`` runs bfloat16 in hardware: a CUDA GPU with native bf16 (Ampere on; older ones
    emulate it), a CPU with AVX512-BF16 or AMX. Any other device counts as slow until measured."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported(including_emulation=False)
    if device.type == "cpu":
        return bool(cpu_flags() & set(CPU_BF16_FLAGS))
    return False


def predictor_precision(precision: str, device: str | torch.device) -> str:
    """The precision a predictor runs at: ``precision``, except bfloat16 on a device that emulates it,
    which runs float32 with a warning. Why fall back rather than only warn: bf16 is here purely for speed
    (it costs ~0.015 cm), so where it is slower there is nothing to gain from it, and a script written on
    a bf16 machine (the README's snippet) should not become 30x slower on another."""
    if precision == "bfloat16" and not bf16_is_fast(device):
        warnings.warn(f"precision='bfloat16' on {torch.device(device)}: no native bf16 units (CPU flags "
                      f"{'/'.join(CPU_BF16_FLAGS)} or a bf16 GPU), where it runs many times slower than "
                      "float32; using float32", UserWarning, stacklevel=3)
        return "float32"
    return precision


def load_decoder(checkpoint: str | Path) -> tuple[nn.Module, dict]:
    """The network of a ClothModule checkpoint (a ConvDecoder, or an FCNet of a `model.kind=fc` run), in eval
    mode, and the checkpoint's hparams."""

    shipped = shipped_model_of(checkpoint)  # a shipped model has no other checkpoint to fall back on
    ck = load_checkpoint(checkpoint, fix=repair_advice(shipped) if shipped else "")  # a corrupt file is named
    hp = ck["hyper_parameters"]
    net = instantiate(hp["net"])
    state = {k[4:]: v for k, v in ck["state_dict"].items() if k.startswith("net.")}
    net.load_state_dict(state)
    return net.eval(), hp


def pretrained_run(name: str) -> Path:
    """The run dir of the pretrained model `name`, for any reader of runs (`ClothPredictor.from_runs`,
    `pbc view --pretrained`): the user's (`pbc.pretrained.user_models()`), which shadows a shipped one of that
    name, else the one shipped with pbc (`pbc.pretrained.shipped_models()`); an unknown name is refused listing
    both. `whole_run="pretrained:NAME"` in from_runs / pbc evaluate is the same."""
    return pretrained_dir(name)


def open_run_dataset(run: Run, directory: str | Path | None = None) -> datasets.ClothDataset:
    """The dataset `run` was trained on: its recorded resolved dir and fingerprint (metrics.json "data"),
    or `directory` (a moved copy), refused with both fingerprints' differences when it is other data.
    Runs written before the record existed fall back to their config's data.dir (or `directory`)."""
    if run.data:
        record = run.data
        if directory is None and not Path(record["dir"]).is_absolute():
            # a shipped model carries its data inside its run dir (pbc.pretrained): relative to the run
            record = dict(record, dir=str(Path(run.path) / record["dir"]))
        return datasets.open_recorded_dataset(record, directory)
    d = directory if directory is not None else OmegaConf.select(OmegaConf.create(run.config), "data.dir")
    return datasets.load_dataset(d)


def _patch_sizes(image_cfg) -> dict:
    sizes = image_sizes(image_cfg)
    return {k: sizes[k] for k in PATCH_SIZE_KEYS}


def _sizes_text(sizes: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in sizes.items())


def check_patch_sizes(first: Run, patch_runs: Sequence[Run]) -> None:
    """Refuse patch runs whose crops differ from `first`'s image config (the run whose config the
    predictor's operators and stitcher are built from: the whole run, else the first patch run), naming
    both runs and their sizes; the stitcher otherwise fails deep inside with a shape error."""
    if not patch_runs or not (first.config or {}).get("image"):
        return
    want = _patch_sizes(run_image_config(first))
    for r in patch_runs:
        image = run_image_config(r)
        if image is None:
            continue  # a run recording no image config: the net sizes are compared in the constructor
        got = _patch_sizes(image)
        if got != want:
            raise ValueError(
                f"patch run {r.path} was trained at other image sizes than {first.path}: {_sizes_text(got)} vs "
                f"{_sizes_text(want)} (pixels at the patch resolution); the predictor stitches every patch "
                "model with one run's operators, so train them with the same image.patch_resolution / "
                "crop_size / margin / pad (or give runs made together)"
            )


def check_net_sizes(image_cfg, whole_net: ConvDecoder | None, patch_nets: Sequence[ConvDecoder]) -> None:
    """Every patch net must predict the crop size `image_cfg` gives (crop_size at patch_resolution)."""
    if not patch_nets:
        return
    sizes = _patch_sizes(image_cfg)
    side = min(sizes["crop_size"], sizes["patch_resolution"])  # ImageOperators.crop_window clamps it so
    crop = (side, side)
    bad = [i for i, n in enumerate(patch_nets) if tuple(getattr(n, "output_size", crop)) != crop]
    if bad:
        got = tuple(patch_nets[bad[0]].output_size)
        raise ValueError(f"patch models {bad[:8]}{' ...' if len(bad) > 8 else ''} predict {got} crops, the image "
                         f"config gives {crop} ({_sizes_text(sizes)}): the patch models and the image config "
                         "(or the whole-shirt run it came from) were made at different image sizes; train "
                         "them with the same image settings")


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
        if len({d.input_joints for d in decoders}) > 1:
            raise ValueError("StackedPatchNet: the decoders read different joints of the pose (model input_joints)")
        self.input_joints = d0.input_joints
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
        x = F.linear(pose_features(pose, self.input_joints).to(self.dtype), self.first_w, self.first_b).relu_()
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


class ClothPredictor:
    """pose (J, 3, 3) -> (V, 3), or (B, J, 3, 3) -> (B, V, 3), garment positions in metres.

    Built by `from_runs`. `model="patches"` (the P patch models + the seam method `method`) or "whole".
    precision: "float32" (exact) or "bfloat16" (the stacked patch net in bf16 on the CPU's AMX/AVX512-bf16
    units; the stitch, skinning and the whole model stay float32). bfloat16 on a device without native bf16
    runs float32 with a warning (`predictor_precision`); ``self.precision`` is the one used.
    device: where the networks, operators and stitch run ("cpu", "cuda", ...); poses are moved there and
    meshes come back on it. layer_modes: None = the device's default layout (`default_layer_modes`).
    """

    def __init__(self, dataset, image_cfg, whole_net: nn.Module | None, patch_nets: Sequence[ConvDecoder],
                 stitch_cfg, space: str = "local", pca=None, cache_dir=None, backend: str = "stacked",
                 layer_modes: Sequence[str] | None = None, threads: int | None = None,
                 precision: str = "float32", device: str | torch.device = "cpu", whole_kind: str = "whole"):
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        if precision != "float32" and backend != "stacked":
            raise ValueError(f"precision={precision!r} needs backend='stacked' (the loop runs the float32 decoders)")
        precision = predictor_precision(precision, device)
        if threads:
            torch.set_num_threads(int(threads))
        self.dataset, self.space = dataset, space
        # the training split's joint-angle range its run recorded (RunRecord.pose_range) and that run's dir;
        # from_runs fills them, None for a run written before runs recorded it (`run_pose_range`)
        self.pose_range_record: dict | None = None
        self.pose_range_run: Path | None = None
        # the operators exactly as training built them (pbc.pixels.target: one cache, one method)
        self.skinner = dataset_skinner(dataset)
        self.faces = torch.as_tensor(dataset.garment.faces).long()
        if whole_net is None and not patch_nets:
            raise ValueError("no model to predict with: give a whole-shirt run and/or one patch run per cage patch")
        # whole-only (no patch nets): no patch operators, stitcher or patch net; model="whole" throughout
        patches = bool(patch_nets)
        # what the whole model predicts and how it goes back to offsets: the run's own cloth target, the
        # garment's image ("whole") or its per-vertex values (a fully connected run, "fc")
        if whole_kind not in WHOLE_KINDS:
            raise ValueError(f"whole_kind must be one of {WHOLE_KINDS} (what the whole-garment model predicts), "
                             f"got {whole_kind!r}")
        self.whole_kind = whole_kind
        check_net_sizes(image_cfg, whole_net, patch_nets)  # before any operator is built
        self.whole_target = make_target(dataset, image_cfg, whole_kind, space=space, skinner=self.skinner,
                                        cache_dir=cache_dir)
        self._image_cfg, self._cache_dir, self._image_target = image_cfg, cache_dir, None
        nv = len(dataset.garment.vertices)
        if whole_kind == "fc" and whole_net is not None and int(whole_net.num_vertices) != nv:
            raise ValueError(f"the fully connected model predicts {int(whole_net.num_vertices)} vertices, the "
                             f"dataset's garment has {nv}: give the run's own dataset")
        if whole_kind == "whole" and whole_net is not None and \
                tuple(whole_net.output_size) != tuple(self.whole_target.image_size):
            raise ValueError(f"the whole-shirt model predicts {tuple(whole_net.output_size)} images, the image "
                             f"config gives {tuple(self.whole_target.image_size)} (image.whole_resolution / "
                             "whole_sides / whole_rows): build the predictor with the image config the model "
                             "was trained with (from_runs reads it from the run)")
        self.ops_patch = image_operators(dataset, image_cfg, "patch", cache_dir) if patches else None
        self.crops = patch_crops(dataset, image_cfg, self.ops_patch) if patches else []
        self.stitcher = build_stitcher(self.ops_patch, self.crops, dataset.garment, dataset.cage, stitch_cfg,
                                       pca=pca) if patches else None
        self.method = str(stitch_cfg.method) if patches else "whole"
        self.whole_net = whole_net
        self.patch_nets = list(patch_nets)
        self.backend = backend
        self.precision = precision
        self.patch_net = (StackedPatchNet(self.patch_nets, layer_modes, dtype=PRECISIONS[precision])
                          if backend == "stacked" else LoopPatchNet(self.patch_nets)).eval() if patches else None
        if pca is not None:
            self.use_pca(pca)
        self._held: list[int] | None = None  # held_joints, found on first use
        self.hold_unread = True  # False: skin the garment with every joint as posed (`held_joints`, for study)
        # edges stretched past mend.stretch_cap times their usual length shortened (`mend_frames`); None: the
        # models' output as is
        self.mend: MendSettings | None = mend_settings()
        self._edges = None  # (edges (E, 2), usual lengths (E,)), found on first use (`edge_lengths`)
        self._edge_operator = None  # their operator G (E, V) for the mend, built with them
        self.to(device)

    @property
    def image_target(self):
        """The whole garment's cloth-image target (`pbc.pixels.target` "whole"): the whole model's own, or, for a
        fully connected model, built on first use (pbc evaluate's representation floor and error images)."""
        if self.whole_kind == "whole":
            return self.whole_target
        if self._image_target is None:
            self._image_target = make_target(self.dataset, self._image_cfg, "whole", space=self.space,
                                             skinner=self.skinner, cache_dir=self._cache_dir)
        return self._image_target

    def use_pca(self, basis) -> None:
        """Filter with PCA basis `basis`; refused when it was fitted on another dataset than this one."""
        if self.stitcher is None:
            raise ValueError("a PCA basis filters the patches' seams: this predictor has no patch models")
        check_pca_matches(basis, self.dataset)
        self.stitcher.pca = basis

    def to(self, device: str | torch.device) -> ClothPredictor:
        """Move the networks and the stitcher to `device` (operators and skinning follow the pose's device)."""
        self.device = torch.device(device)
        for part in (self.patch_net, self.whole_net, self.stitcher):
            if part is not None:
                part.to(self.device)
        return self

    @classmethod
    def from_runs(cls, whole_run, patch_runs=None, stitch_cfg=None, pca=None, data_dir=None,
                  **kw) -> ClothPredictor:
        """whole_run: a whole-shirt CNN run dir or a fully connected (`model.kind=fc`) run dir (or None);
        patch_runs: run dirs and/or a sweep dir (or a stacked `+experiment=patches` run dir), one run per patch
        of the dataset's cage, or
        None / [] for the whole-shirt model alone; stitch_cfg: the seam method's node (conf/stitch; None =
        conf/stitch/average.yaml), used with patch runs only; data_dir: where the runs' dataset is when it
        moved (default: where the runs recorded it)."""
        has_patches = patch_runs is not None and not (isinstance(patch_runs, Sequence) and not isinstance(
            patch_runs, str) and len(patch_runs) == 0)
        if not whole_run and not has_patches:
            raise ValueError("from_runs needs a whole-shirt run dir, or the patch run dirs (one per cage patch) / "
                             "their sweep dir")
        whole_run = resolve_run(whole_run)  # "pretrained:NAME": a pretrained model (pbc.pretrained)
        whole = read_run(whole_run) if whole_run else None
        if whole is not None and whole.kind.value not in WHOLE_KINDS:
            raise ValueError(f"{whole.path}: a {whole.kind.value!r} run, not a whole-garment run (a whole-shirt "
                             "CNN or a fully connected run)")
        first = whole or read_run(find_runs(patch_runs)[0])
        cfg = OmegaConf.create(first.config)
        dataset = open_run_dataset(first, data_dir)
        if data_dir is None and first.data and not Path(first.data["dir"]).is_absolute():
            # a shipped model's folder may be read-only (a wheel) or tracked (a checkout): operators go to
            # the user cache, not beside its data
            kw.setdefault("cache_dir", user_cache_dir("operators"))
        ghash = str(dataset.manifest.get("garment_hash", ""))
        if whole is not None and whole.garment_hash != ghash:
            raise ValueError(f"{whole.path}: trained on garment {whole.garment_hash!r}, the dataset is {ghash!r}")
        runs = select_patch_runs(patch_runs, ghash, len(dataset.cage.patches)) if has_patches else []
        check_patch_sizes(first, runs)
        if has_patches and stitch_cfg is None:
            stitch_cfg = stitch_config("average")
        whole_net, whole_hp = load_decoder(whole.checkpoint) if whole is not None else (None, None)
        nets, spaces = [], set()
        for r in runs:
            net, hp = load_decoder(r.checkpoint)
            nets.append(net)
            spaces.add(hp.get("space", "local"))
        if whole_hp is not None:  # one space for every model: the predictor turns all offsets back alike
            spaces.add(whole_hp.get("space", "local"))
        if len(spaces) > 1:
            raise ValueError(f"the runs use different offset spaces {sorted(spaces)}")
        if whole is not None:
            kw.setdefault("whole_kind", whole.kind.value)
        predictor = cls(dataset, cfg.image, whole_net, nets, stitch_cfg, space=spaces.pop(), pca=pca, **kw)
        predictor.pose_range_record, predictor.pose_range_run = first.record.pose_range, Path(first.path)
        return predictor

    @classmethod
    def from_pretrained(cls, name: str, **kw) -> ClothPredictor:
        """The pretrained whole-shirt model `name`: the user's, else the one shipped with pbc (`pretrained_run`;
        its MODEL_CARD.md says what it is, `pbc pretrained list` where it is); kw as `from_runs` (device,
        threads, ...)."""
        return cls.from_runs(pretrained_run(name), **kw)

    def check_model(self, model: str | None) -> str:
        """The model a call answers with: `model` ("patches" or "whole"), or None = the patches when there
        are patch models, else the whole. Anything else is refused naming the choices ("Whole",
        "whole_shirt" and "patch" used to fall through to the stitched patches)."""
        if model is None:
            return "patches" if self.patch_net is not None else "whole"
        if not isinstance(model, str) or model not in MODELS:
            raise ValueError(f"model={model!r} is not a predictor model; choose one of {list(MODELS)} (or None: "
                             f"{'patches' if self.patch_net is not None else 'whole'}, what this predictor has)")
        return model

    def read_joints(self) -> list[int]:
        """The body joints (indices) the predictor's models read from a pose (`input_joints`: a shirt on a body
        with legs reads its upper body only); a joint outside them cannot change the garment."""
        nets = [n for n in (self.whole_net, *self.patch_nets) if n is not None]
        every = range(len(self.dataset.body.skeleton.names))
        read = {j for n in nets for j in (every if getattr(n, "input_joints", None) is None else n.input_joints)}
        return sorted(read)

    def held_joints(self) -> list[int]:
        """The body joints the garment is skinned with at rest, whatever the pose: those no model reads and no
        pose of its data moved (its dataset's and its recorded training poses). A shirt learnt with the legs at
        rest follows the trunk on a walk: skinned through the thighs, the hem embedded in body triangles the
        hips' weights move would stretch between them to several times its length."""
        if self._held is None:
            ds, read = self.dataset, set(self.read_joints())
            poses = [np.asarray(ds.poses)] + [k for k in (recorded_known_poses(ds),) if k is not None]
            still = still_joints(np.concatenate(poses))
            self._held = [j for j in range(len(still)) if still[j] and j not in read]
        return list(self._held)

    def skinned_pose(self, pose: Tensor) -> Tensor:
        """pose (B, J, 3, 3) as the garment is skinned with it: the `held_joints` at rest (with `hold_unread`)."""
        held = self.held_joints() if self.hold_unread else []
        if not held:
            return pose
        out = pose.clone()
        out[:, held] = torch.eye(3, dtype=pose.dtype, device=pose.device)
        return out

    def edge_lengths(self) -> tuple[np.ndarray, np.ndarray]:
        """The garment's edges (E, 2) and their usual lengths (E,): the median over its dataset's drapes (at
        most conf/mend.yaml's usual_drapes, spread evenly), the yardstick of `mend_frames` and of a shattered
        frame."""
        if self._edges is None:
            ds = self.dataset
            edges = mesh_edges(np.asarray(ds.garment.faces))
            n, most = len(ds.verts), int((self.mend or mend_settings()).usual_drapes)
            rows = np.unique(np.linspace(0, n - 1, min(n, most)).round().astype(np.int64))
            usual = median_edge_lengths(np.asarray(ds.verts)[rows], edges)
            self._edges = (edges, usual)
            self._edge_operator = edge_operator(edges, len(ds.garment.vertices))
        return self._edges

    def mend_frames(self, x: Tensor, stats: list | None = None) -> Tensor:
        """Garments x (B, V, 3) with every edge past `mend.stretch_cap` times its usual length shortened
        (pbc.geometry.mend.shorten_edges); frames without one are returned as they are. stats: a list each
        frame's stats dict is appended to (edges past the cap, the longest edge's ratio before and after, the
        most a vertex moved in mm)."""
        if self.mend is None or self.mend.stretch_cap <= 0:
            return x
        edges, usual = self.edge_lengths()
        g = self._edge_operator
        out = x.clone()
        for k, frame in enumerate(x.detach().cpu().double().numpy()):
            y, st = shorten_edges(frame, edges, usual, self.mend, g)
            if st["stretched"]:
                out[k] = torch.from_numpy(y).to(out)
            if stats is not None:
                stats.append(st)
        return out

    def check_person(self, person) -> None:
        """Refuse a `person` (None, one int, or one per pose) this predictor's dataset does not have, before
        anything is predicted or written (`Skinner.people`)."""
        if person is not None:
            self.skinner.people(person)

    # -------------------------------------------------------------------- pieces
    def frames(self, pose: Tensor) -> tuple[Tensor, Tensor]:
        return self.skinner(self.skinned_pose(pose))

    def offsets_of(self, pose: Tensor, verts: Tensor, person: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Garment positions verts (B, V, 3) at poses (B, J, 3, 3) -> (offsets (B, V, 3) in the models'
        space, anchors (B, V, 3), frames (B, V, 3, 3)): what the models would have to predict. person (B,):
        each sample's person in a dataset of several people (`ClothDataset.person_kw`); None: the base one."""
        anchors, frames = self.skinner(self.skinned_pose(pose), person)
        return to_offsets(verts, anchors, frames, self.space), anchors, frames

    @torch.inference_mode()
    def patch_crops(self, pose: Tensor) -> Tensor:
        """pose (B, J, 3, 3) -> crops (B, P, 3, h, w), on the predictor's device."""
        return self.patch_net(pose.reshape(pose.shape[0], -1).to(self.device, torch.float32))

    @torch.inference_mode()
    def whole_offsets(self, pose: Tensor) -> Tensor:
        if self.whole_net is None:
            raise ValueError("no whole-shirt run was given")
        return self.whole_target.values(self.whole_net(pose.to(self.device, torch.float32)))

    @torch.inference_mode()
    def __call__(self, pose, model: str | None = None, method: str | None = None,
                 person=None, mend_stats: list | None = None) -> Tensor:
        """pose: torch or numpy, (J, 3, 3) / (J*9,) for one pose -> (V, 3), or (B, J, 3, 3) / (B, J*9) ->
        (B, V, 3); checked first (shape, finite, rotations: pbc.core.validate.as_poses).
        model: "patches" or "whole"; None = the patches when there are patch models, else the whole.
        person: in a dataset of several people (`data.body_shape`), the person k whose body the cloth is
        skinned on (the models read the pose only), one int for every pose or (B,) one per pose; None: the
        base person (body.npz). The garment is mended (`mend_frames`, each frame's stats appended to
        mend_stats) unless `self.mend` is None."""
        names = list(self.dataset.body.skeleton.names)
        pose, batched = as_poses(pose, len(names), joint_names=names)
        single = not batched
        model = self.check_model(model)
        if model == "patches" and self.patch_net is None:
            raise ValueError("this predictor has no patch models (built from a whole-shirt run alone): use "
                             f"model='whole', or give from_runs the {len(self.dataset.cage.patches)} patch runs "
                             "of its cage")
        pose = pose.to(self.device, torch.float32)
        if self.stitcher is not None:
            self.stitcher.to(self.device)  # a basis set after construction (pbc.evaluate's PCA) follows too
        if model == "whole":
            off = self.whole_offsets(pose)
        else:
            method = method or self.method
            whole = self.whole_offsets(pose) if method in NEEDS_WHOLE else None
            off = self.stitcher(self.patch_crops(pose), method, whole)
        anchors, frames = self.skinner(self.skinned_pose(pose), person)
        x = self.mend_frames(from_offsets(off, anchors, frames, self.space), mend_stats)
        return x[0] if single else x


def stitch_config(method: str):
    """The seam method's node: conf/stitch/<method>.yaml merged over the options its ``defaults`` list names,
    as Hydra composes the group (without composing a whole root config: a second instead of several)."""
    if method not in METHODS:
        raise ValueError(f"unknown seam method {method!r}; choose one of {METHODS}")
    node = OmegaConf.load(CONF_DIR / "stitch" / f"{method}.yaml")
    defaults = [str(d) for d in (node.pop("defaults", None) or [])] or ["_self_"]
    defaults += [] if "_self_" in defaults else ["_self_"]
    return OmegaConf.merge(*[node if d == "_self_" else stitch_config(d) for d in defaults])


def fit_training_pca(predictor: ClothPredictor, n_components: int, max_samples: int, batch: int = 64):
    """PCA of the training split's per-vertex offsets (in the models' space), tagged with the dataset hash."""
    ds = predictor.dataset
    idx = ds.split("train")[:max_samples]
    offs = []
    with torch.inference_mode():
        for i in range(0, len(idx), batch):
            j = idx[i:i + batch]
            offs.append(predictor.offsets_of(torch.from_numpy(ds.poses[j]).float(),
                                             torch.from_numpy(ds.verts[j]).float(), **person_kw(ds, j))[0])
    return fit_pca(torch.cat(offs), n_components, dataset_hash(ds.dir), fingerprint=dataset_fingerprint(ds))


def predict_poses(predictor: ClothPredictor, poses: Tensor, batch_size: int = 16, model: str | None = None,
                  progress: bool = True, person=None, mend_stats: list | None = None) -> Tensor:
    """poses (N, J, 3, 3) -> garment vertices (N, V, 3), in batches, with a progress bar for long runs;
    person: None (the base person), one int, or (N,) one per pose; mend_stats: a list each frame's mend stats are
    appended to (`ClothPredictor.__call__`)."""
    out = []
    per_pose = person is not None and np.ndim(person) > 0
    starts = range(0, poses.shape[0], max(1, int(batch_size)))
    for i in tqdm(starts, desc="predict", unit="batch", disable=not progress or len(starts) < 2, mininterval=2):
        who = np.asarray(person)[i:i + batch_size] if per_pose else person
        out.append(predictor(poses[i:i + batch_size], model=model, person=who, mend_stats=mend_stats))
    return torch.cat(out)
