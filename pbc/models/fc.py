"""Fully connected baselines of appendix E.3 (Table 2): pose -> per-vertex values, directly or via PCA.

``FCNet`` is an MLP with two hidden layers of 256 and ReLU. In ``"direct"`` mode it outputs V*3 values;
in ``"pca"`` mode it outputs K (128) coefficients that a fixed linear PCA basis maps to V*3 values.
The basis is fitted on the training split (:func:`fit_pca`) and held as buffers, so it is saved in and
restored from the checkpoint with the weights. What the per-vertex values mean (local offsets, root
offsets, root positions) is the module's business, not this network's.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from pbc.models.decoder import pose_features, register_pose_input

MODES = ("direct", "pca")


def principal_components(values: Tensor, k: int, exact_below: float = float("inf")) -> tuple[Tensor, Tensor, Tensor]:
    """The one PCA of pbc: the top principal components of samples, in float64.

    values (N, D); k clamped to min(N, D). Exact SVD when min(N, D) <= exact_below, otherwise randomized
    `torch.svd_lowrank` (oversampled, with power iterations) so a 20k-sample, 3V-wide matrix stays cheap.
    Returns mean (D,), components (k, D) orthonormal rows, singular values (k,).
    """
    x = values.reshape(values.shape[0], -1).double()
    n, d = x.shape
    k = min(int(k), n, d)
    mean = x.mean(dim=0)
    x = x - mean
    if min(n, d) <= exact_below:
        _, s, vh = torch.linalg.svd(x, full_matrices=False)
        return mean, vh[:k], s[:k]
    _, s, v = torch.svd_lowrank(x, q=min(k + 16, n, d), niter=4)
    return mean, v[:, :k].T, s[:k]


def fit_pca(values: Tensor, num_components: int) -> tuple[Tensor, Tensor, Tensor]:
    """The FC baselines' basis of training samples (exact SVD).

    Args:
        values: (N, D) float samples (D = V*3).
        num_components: K.
    Returns:
        mean (D,), components (K, D) orthonormal rows, scale (K,) the coefficient standard deviations.
        When N or D is below K, the missing components are zero rows with scale 1 (shapes stay fixed,
        so a checkpoint loads whatever split size it was fitted on).
    """
    mean, vh, s = principal_components(values, num_components)
    k = vh.shape[0]
    comps = torch.zeros(num_components, values.shape[1], dtype=torch.float64)
    comps[:k] = vh
    scale = torch.ones(num_components, dtype=torch.float64)
    # std of the coefficients; floor keeps degenerate directions from exploding the decoded output
    scale[:k] = (s / max(values.shape[0] - 1, 1) ** 0.5).clamp_min(1e-8)
    return mean.float(), comps.float(), scale.float()


class FCNet(nn.Module):
    """Pose (B, in_features) -> per-vertex values (B, V, 3).

    Args:
        in_features: pose size (90).
        num_vertices: V.
        hidden: hidden layer widths (paper: 256, 256).
        mode: ``"direct"`` or ``"pca"``.
        num_components: K for ``"pca"`` (paper: 128).
        input_joints, num_joints: the joints of the pose read (``pbc.models.decoder.register_pose_input``).
    """

    def __init__(
        self,
        in_features: int,
        num_vertices: int,
        hidden: Sequence[int] = (256, 256),
        mode: str = "direct",
        num_components: int = 128,
        input_joints: Sequence[int] | None = None,
        num_joints: int | None = None,
    ) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self.num_vertices = int(num_vertices)
        dim = self.num_vertices * 3
        out = dim if mode == "direct" else int(num_components)
        layers: list[nn.Module] = []
        width = int(in_features)
        for h in hidden:
            layers += [nn.Linear(width, int(h)), nn.ReLU(inplace=True)]
            width = int(h)
        layers.append(nn.Linear(width, out))
        self.mlp = nn.Sequential(*layers)
        register_pose_input(self, in_features, input_joints, num_joints)
        if mode == "pca":
            # Buffers, not parameters: fitted once on the train split, then frozen and checkpointed.
            self.register_buffer("pca_mean", torch.zeros(dim))
            self.register_buffer("pca_components", torch.zeros(int(num_components), dim))
            self.register_buffer("pca_scale", torch.ones(int(num_components)))
            self.register_buffer("pca_fitted", torch.zeros((), dtype=torch.bool))

    def set_pca(self, mean: Tensor, components: Tensor, scale: Tensor) -> None:
        """Install a basis from :func:`fit_pca`."""
        self.pca_mean.copy_(mean)
        self.pca_components.copy_(components)
        self.pca_scale.copy_(scale)
        self.pca_fitted.fill_(True)

    def forward(self, pose: Tensor) -> Tensor:
        """pose (B, num_joints * 9) or (B, num_joints, 3, 3) -> (B, V, 3)."""
        y = self.mlp((pose_features(pose, self.input_joints) - self.input_mean) / self.input_scale)
        if self.mode == "pca":
            # the network predicts whitened coefficients so its outputs are O(1) like the direct mode
            y = (y * self.pca_scale) @ self.pca_components + self.pca_mean
        return y.view(-1, self.num_vertices, 3)
