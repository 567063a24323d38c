"""A PCA basis of whole-garment per-vertex offsets, for filtering stitched patch predictions.

One job: fit (on the training split), project onto, save and load a linear basis of flattened
`(V, 3)` offsets. The basis is stored with a hash and the fingerprint (pbc.data.dataset.dataset_fingerprint)
of the dataset it was fitted on, so a basis from another dataset or garment is refused
(`check_pca_matches`) instead of silently filtering with the wrong shapes.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from pbc.core.io import atomic_path
from pbc.data.dataset import dataset_fingerprint, fingerprint_diff
from pbc.models.fc import principal_components


@dataclass
class PCABasis:
    """mean: (D,), components: (K, D) orthonormal rows, singular_values: (K,), D = 3V."""

    mean: Tensor
    components: Tensor
    singular_values: Tensor
    dataset_hash: str
    fingerprint: dict | None = None  # dataset_fingerprint of the data it was fitted on (None: older basis)

    @property
    def num_components(self) -> int:
        return int(self.components.shape[0])

    def to(self, device) -> PCABasis:
        return PCABasis(self.mean.to(device), self.components.to(device),
                        self.singular_values.to(device), self.dataset_hash, self.fingerprint)


def fit_pca(samples: Tensor, n_components: int, dataset_hash: str = "", exact_below: int = 4096,
            fingerprint: dict | None = None) -> PCABasis:
    """Fit the top principal components of the samples.

    samples: (N, V, 3) or (N, D) float; n_components: K, clamped to min(N, D) (the most a basis can
    hold); exact SVD up to min(N, D) = exact_below, randomized above (pbc.models.fc.principal_components).
    """
    # float64 inside: the identity test needs it exact
    mean, comps, s = principal_components(samples, n_components, exact_below)
    return PCABasis(mean.float(), comps.float().contiguous(), s.float(), dataset_hash, fingerprint)


def project(basis: PCABasis, x: Tensor, k: int | None = None) -> Tensor:
    """Project onto the first k components (all when None): mean + C_k^T C_k (x - mean).

    x: (B, V, 3) or (B, D) -> same shape.
    """
    C = basis.components if k is None else basis.components[:k]
    flat = x.reshape(x.shape[0], -1) - basis.mean
    return ((flat @ C.T) @ C + basis.mean).reshape(x.shape)


def dataset_hash(dataset_dir: str | Path, split_key: str = "train") -> str:
    """Short hash of a dataset's manifest (garment, seed, counts, split): where a basis came from."""
    manifest = json.loads((Path(dataset_dir) / "manifest.json").read_text())
    keyed = {k: manifest.get(k) for k in ("format_version", "seed", "garment_hash", "body_hash",
                                           "num_vertices", "counts")}
    keyed["split"] = manifest.get("splits", {}).get(split_key)
    return hashlib.sha256(json.dumps(keyed, sort_keys=True, default=str).encode()).hexdigest()[:16]


def save_pca(basis: PCABasis, path: str | Path) -> None:
    """Atomic save (.pt): a killed job never leaves a half-written basis behind."""
    with atomic_path(path) as tmp:
        torch.save({"mean": basis.mean, "components": basis.components,
                    "singular_values": basis.singular_values, "dataset_hash": basis.dataset_hash,
                    "fingerprint": json.dumps(basis.fingerprint, sort_keys=True)}, tmp)


def load_pca(path: str | Path, expected_hash: str | None = None) -> PCABasis:
    """Load a basis; refuse it if it was fitted on another dataset than `expected_hash`."""
    d = torch.load(Path(path), map_location="cpu", weights_only=True)
    fp = json.loads(d["fingerprint"]) if isinstance(d.get("fingerprint"), str) else None
    basis = PCABasis(d["mean"], d["components"], d["singular_values"], d["dataset_hash"], fp)
    if expected_hash is not None and basis.dataset_hash != expected_hash:
        raise ValueError(f"PCA basis {path} was fitted on dataset {basis.dataset_hash!r}, "
                         f"not on this one ({expected_hash!r}); delete it to refit")
    return basis


def check_pca_matches(basis: PCABasis, data) -> None:
    """Refuse a basis fitted on another dataset than `data` (a pbc.data.dataset.ClothDataset): the
    fingerprints' differing keys, one line each; an older basis without a fingerprint by its hash."""
    if basis.fingerprint is not None:
        diff = fingerprint_diff(basis.fingerprint, dataset_fingerprint(data))
        if diff:
            raise ValueError("the PCA basis was fitted on another dataset than the predictor's:\n  - "
                             + "\n  - ".join(diff) + "\nrefit it on this dataset (pbc.evaluate with pca_path=null)")
    elif basis.dataset_hash and basis.dataset_hash != dataset_hash(data.dir):
        raise ValueError(f"the PCA basis was fitted on dataset {basis.dataset_hash!r}, not on this one "
                         f"({dataset_hash(data.dir)!r}); refit it on this dataset (pbc.evaluate with pca_path=null)")
