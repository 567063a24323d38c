"""The one convolutional decoder family: pose vector -> cloth image (paper sec. 7, appendix E.1, F).

One class, :class:`ConvDecoder`, configured by input size, optional hidden linear layers, the kind of
first layer (a transpose convolution on the 1x1 pose "image", or a linear layer reshaped to a feature
map), the start size/channels, the output size/channels. Between start and output sit groups of
[ConvTranspose2d(k4, s2, p1), BatchNorm2d, ReLU] that double the resolution and halve the channels,
then a 3x3 convolution to the output channels. The paper presets live in ``conf/model/*.yaml``:

=========  =====================================================  ==============
preset     layout                                                 parameters
=========  =====================================================  ==============
whole      90 -> ConvT(k8) 8x8x384 -> 5 groups -> 256x256x6        3,785,322
patch      90 -> Linear 5x5x512 -> 5 groups -> 160x160x3           3,960,195
necktie    36 -> Linear 128 -> Linear 8x32x64 -> 3 groups -> 64x256x3 2,161,667
=========  =====================================================  ==============

The necktie's 64x256 output is not square: the groups double both axes while an axis is short of
its target and only the other one afterwards (a non-doubling axis uses kernel 3, stride 1, padding 1,
which keeps its size). The literal reading of appendix F (an 8x8x64 start, 5 groups) has 576,851
parameters, not the paper's 2.16M; an 8x32x64 start (8x8 per square of the 1:4 image) has 2.16M and is the
preset; see ``conf/model/necktie.yaml``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn


def _doublings(start: int, end: int) -> int:
    """How many x2 steps take ``start`` to ``end`` (both > 0); raises when it is not a power of two."""
    ratio = end / start
    n = round(math.log2(ratio)) if ratio >= 1 else -1
    if n < 0 or start * 2**n != end:
        raise ValueError(f"output size {end} is not start size {start} times a power of two")
    return n


def group_strides(start_size: Sequence[int], output_size: Sequence[int]) -> list[tuple[int, int]]:
    """Per-group (row, col) strides taking ``start_size`` (h, w) to ``output_size`` (H, W).

    Both axes double together while both need it; the longer axis then doubles alone.
    """
    nh = _doublings(start_size[0], output_size[0])
    nw = _doublings(start_size[1], output_size[1])
    return [(2 if i < nh else 1, 2 if i < nw else 1) for i in range(max(nh, nw))]


def register_pose_input(net: nn.Module, in_features: int, input_joints: Sequence[int] | None = None,
                        num_joints: int | None = None) -> None:
    """What pose a net reads: `net.num_joints` rotations, (B, num_joints * 9) or (B, num_joints, 3, 3), of
    which it keeps the joints `net.input_joints` (None = all, in order; :func:`pose_features`), then
    standardises them (:func:`register_pose_standardisation`). A garment that moves with a few joints
    (the necktie: 4 of the body's 10) reads the full pose and keeps its own, so every caller passes the
    same pose. Raises ValueError when in_features is not 9 per kept joint.
    """
    set_pose_joints(net, in_features, input_joints, num_joints)
    register_pose_standardisation(net, in_features)


def set_pose_joints(net: nn.Module, in_features: int, input_joints: Sequence[int] | None = None,
                    num_joints: int | None = None) -> None:
    """`net.input_joints` and `net.num_joints` of :func:`register_pose_input`, checked against in_features."""
    net.input_joints = None if input_joints is None else tuple(int(j) for j in input_joints)
    kept = None if net.input_joints is None else len(net.input_joints)
    net.num_joints = int(num_joints) if num_joints is not None else (kept or int(in_features) // 9)
    if kept is None:
        return
    if not all(0 <= j < net.num_joints for j in net.input_joints):
        raise ValueError(f"input_joints {list(net.input_joints)}: a {net.num_joints}-joint pose has joints "
                         f"0..{net.num_joints - 1}")
    if 9 * kept != int(in_features):
        raise ValueError(f"the net keeps {kept} joints {list(net.input_joints)}: that is {9 * kept} input "
                         f"numbers, but in_features={in_features}")


def pose_features(pose: Tensor, input_joints: Sequence[int] | None) -> Tensor:
    """pose (B, J * 9) or (B, J, 3, 3) -> (B, 9 * len(input_joints)) the kept joints' rotations, flattened
    (all J of them when input_joints is None)."""
    x = pose.reshape(pose.shape[0], -1)
    if input_joints is None:
        return x
    return x.view(x.shape[0], -1, 9)[:, list(input_joints)].reshape(x.shape[0], -1)


def register_pose_standardisation(net: nn.Module, in_features: int) -> None:
    """Buffers input_mean / input_scale (in_features,): the net reads (pose - mean) / scale.

    Zeros and ones (the raw pose) until the module fits them on the training split. Most of the 90
    rotation entries sit near a constant; left raw, that constant swamps the pose-dependent part of
    the first layer's features (the whole CNN stayed at the mean image for 20 CPU epochs without it).
    """
    net.register_buffer("input_mean", torch.zeros(int(in_features)))
    net.register_buffer("input_scale", torch.ones(int(in_features)))
    add_buffer_defaults(net, ("input_mean", "input_scale"))


def add_buffer_defaults(net: nn.Module, names: Sequence[str]) -> None:
    """Checkpoints from before these buffers existed were trained without them: load their init values."""

    def hook(module, state_dict, prefix, *args):
        for name in names:
            state_dict.setdefault(prefix + name, getattr(module, name).clone())

    net.register_load_state_dict_pre_hook(hook)


class ConvDecoder(nn.Module):
    """Pose (B, in_features) -> image (B, out_channels, H, W).

    Args:
        in_features: pose vector size (90 = 10 joints x 3x3 for the T-shirt, 36 for the necktie).
        out_channels: image channels (6 whole shirt: 3 front + 3 back; 3 patch / necktie).
        output_size: (H, W) of the image.
        start_size: (h, w) of the first feature map.
        start_channels: channels of the first feature map (halved by every group).
        first_layer: ``"conv_transpose"`` (ConvTranspose2d with kernel = start size on the 1x1 pose,
            as the whole-shirt network) or ``"linear"`` (Linear to h*w*c, reshaped).
        hidden: widths of linear+ReLU layers applied to the pose before the first layer.
        final_kernel: kernel of the last convolution (3 in the paper).
        input_joints: the joints of the pose the net reads (None = all; the necktie: its 4), and
        num_joints: how many the pose has (:func:`register_pose_input`; ``pbc.train`` sets both from
            ``data.pose_joints`` and the dataset's skeleton).
    """

    def __init__(
        self,
        in_features: int,
        out_channels: int,
        output_size: Sequence[int],
        start_size: Sequence[int],
        start_channels: int,
        first_layer: str = "conv_transpose",
        hidden: Sequence[int] = (),
        final_kernel: int = 3,
        input_joints: Sequence[int] | None = None,
        num_joints: int | None = None,
    ) -> None:
        super().__init__()
        self.in_features = int(in_features)
        self.out_channels = int(out_channels)
        self.output_size = (int(output_size[0]), int(output_size[1]))
        self.start_size = (int(start_size[0]), int(start_size[1]))
        self.start_channels = int(start_channels)
        self.first_layer = first_layer
        strides = group_strides(self.start_size, self.output_size)
        if self.start_channels >> len(strides) < 1:
            raise ValueError(f"{start_channels} start channels cannot be halved {len(strides)} times")

        mlp: list[nn.Module] = []
        width = self.in_features
        for h in hidden:
            mlp += [nn.Linear(width, int(h)), nn.ReLU(inplace=True)]
            width = int(h)
        self.mlp = nn.Sequential(*mlp)

        h0, w0 = self.start_size
        if first_layer == "conv_transpose":
            self.first = nn.ConvTranspose2d(width, self.start_channels, kernel_size=(h0, w0))
        elif first_layer == "linear":
            self.first = nn.Linear(width, self.start_channels * h0 * w0)
        else:
            raise ValueError(f"first_layer must be 'conv_transpose' or 'linear', got {first_layer!r}")

        groups: list[nn.Module] = []
        c = self.start_channels
        for sh, sw in strides:
            # k4/s2/p1 doubles an axis exactly; k3/s1/p1 keeps it (used only by non-square outputs).
            kernel = (4 if sh == 2 else 3, 4 if sw == 2 else 3)
            groups += [
                nn.ConvTranspose2d(c, c // 2, kernel_size=kernel, stride=(sh, sw), padding=1),
                nn.BatchNorm2d(c // 2),
                nn.ReLU(inplace=True),
            ]
            c //= 2
        self.groups = nn.Sequential(*groups)
        self.head = nn.Conv2d(c, self.out_channels, kernel_size=final_kernel, padding=final_kernel // 2)
        # Output = head * output_scale + output_mean: the training split's mean image and per-channel
        # spread over poses (zeros and ones: the paper's plain decoder). Cloth images are in metres, with
        # a pose-dependent part of ~1 cm, while a freshly initialised head outputs O(1): Adam's first steps
        # then shrink the output by killing the ReLUs, and the net stays at the constant mean image for
        # good (measured on tshirt_small: 20 CPU epochs ended at exactly the mean image's 3.26 cm, where
        # ridge regression on the pose reaches 1.44 cm). With the scale the head works in units of that
        # spread. Buffers, so checkpoints and the stacked predictor carry them.
        self.register_buffer("output_mean", torch.zeros(1, self.out_channels, *self.output_size))
        self.register_buffer("output_scale", torch.ones(1, self.out_channels, 1, 1))
        add_buffer_defaults(self, ("output_scale",))
        register_pose_input(self, self.in_features, input_joints, num_joints)

    def forward(self, pose: Tensor) -> Tensor:
        """pose (B, num_joints * 9) or (B, num_joints, 3, 3) -> (B, out_channels, H, W)."""
        x = self.mlp((pose_features(pose, self.input_joints) - self.input_mean) / self.input_scale)
        h0, w0 = self.start_size
        if self.first_layer == "conv_transpose":
            x = self.first(x[:, :, None, None])
        else:
            x = self.first(x).view(-1, self.start_channels, h0, w0)
        x = torch.relu(x)
        return self.head(self.groups(x)) * self.output_scale + self.output_mean



def count_parameters(module: nn.Module) -> int:
    """Trainable parameters (BatchNorm running statistics are buffers, not counted)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)
