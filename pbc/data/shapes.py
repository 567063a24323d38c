"""Shape as data (`data.body_shape`): a dataset draped on several people of one parametric body (Anny).

The people are drawn once from the data seed, uniformly in the configured phenotype ranges, K of them
(`data.body_shapes`); sample i is draped on person i mod K. Every person is the same mesh (connectivity,
skinning weights, skeleton joints, parents and frames) with other rest vertices and rest joint heads, so
the base body's rest-pose shrink-wrap embedding (barycentric in body triangles) holds on each of them, and
a person is fully described by its rest vertices (Vb, 3) and heads (J, 3).

Files of such a dataset, beside body.npz (the base person, the body config's own phenotype):
    shapes.npz   keys (P,) phenotype names, values (K, P), vertices (K, Vb, 3), heads (K, J, 3) float32
    person.npy   (N,) int64 the person of each kept sample
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch import Tensor

from pbc.core.io import atomic_path, hash_arrays, load_npz
from pbc.geometry.body import body_from_config
from pbc.geometry.body.base import Body

# mixed into the data seed, so the people's draw is a stream of its own (the poses keep theirs)
SHAPE_STREAM = 23


@dataclass
class BodyShapes:
    """K people of one body: phenotype values and their rest vertices and heads (see the module docstring)."""

    keys: tuple[str, ...]  # (P,) phenotype names
    values: np.ndarray  # (K, P) float64 phenotype values
    vertices: Tensor  # (K, Vb, 3) float32 rest vertices, the base body's frame
    heads: Tensor  # (K, J, 3) float32 rest joint heads

    def __len__(self) -> int:
        return len(self.values)

    def phenotype(self, k: int) -> dict[str, float]:
        """Person k's phenotype {key: value}."""
        return {key: float(v) for key, v in zip(self.keys, self.values[k], strict=True)}



def shape_ranges(cfg: DictConfig) -> dict[str, tuple[float, float]] | None:
    """`data.body_shape` checked against the body's phenotype bands: {key: (lo, hi)}, or None when unset.

    One ValueError naming every problem: a body without phenotypes (the mannequin), an unknown key, a range
    that is not [lo, hi] with lo <= hi, or one outside the key's band (conf/body/anny.yaml phenotype_ranges).
    """
    spec = (cfg.get("data") or {}).get("body_shape")  # a config without data (a test's bare one): none
    if spec is None:
        return None
    bands = cfg.body.get("phenotype_ranges")
    if not bands:
        raise ValueError(f"data.body_shape needs a body with phenotypes (body=anny or body=anny_tpose); "
                         f"body={cfg.body.get('kind', 'mannequin')} has one shape: drop data.body_shape")
    spec = OmegaConf.to_container(spec, resolve=True) if OmegaConf.is_config(spec) else spec
    if not isinstance(spec, dict) or not spec:
        raise ValueError(f"data.body_shape must map phenotype keys to [lo, hi] ranges, e.g. "
                         f"{{height: [0.3, 0.7]}}, got {spec!r}")
    problems, out = [], {}
    for key, rng in spec.items():
        if key not in bands:
            problems.append(f"unknown key {key!r}")
            continue
        lo_b, hi_b = (float(x) for x in bands[key])
        ok = isinstance(rng, list | tuple) and len(rng) == 2 and all(isinstance(x, int | float) for x in rng)
        if not ok or float(rng[0]) > float(rng[1]):
            problems.append(f"{key}: {rng!r} is not a range [lo, hi] with lo <= hi")
        elif float(rng[0]) < lo_b or float(rng[1]) > hi_b:
            problems.append(f"{key}: {list(rng)} leaves its band [{lo_b:g}, {hi_b:g}]")
        else:
            out[key] = (float(rng[0]), float(rng[1]))
    if problems:
        bands_txt = ", ".join(f"{k} [{float(v[0]):g}, {float(v[1]):g}]" for k, v in bands.items())
        raise ValueError(f"data.body_shape: {'; '.join(problems)}; the body's phenotype keys and bands are: "
                         f"{bands_txt}")
    k = cfg.data.get("body_shapes")
    if not isinstance(k, int) or isinstance(k, bool) or k < 1:
        raise ValueError(f"data.body_shapes must be a whole number of people >= 1, got {k!r}")
    return out


def sample_phenotypes(cfg: DictConfig) -> tuple[tuple[str, ...], np.ndarray] | None:
    """The people of `cfg`: (keys (P,), values (K, P)), every phenotype key of the body, those of
    `data.body_shape` drawn uniformly in their ranges from the data seed, the others at the body's own
    value. None without `data.body_shape`. Cheap (no body is built): the fingerprint reads it."""
    ranges = shape_ranges(cfg)
    if ranges is None:
        return None
    base = {str(k): float(v) for k, v in cfg.body.phenotype.items()}
    keys = tuple(sorted(set(base) | set(ranges)))
    rng = np.random.default_rng([int(cfg.data.seed), SHAPE_STREAM])
    values = np.empty((int(cfg.data.body_shapes), len(keys)))
    for p, key in enumerate(keys):  # one draw per key in key order: adding a key leaves the others' values
        lo, hi = ranges.get(key, (base.get(key, 0.5),) * 2)
        values[:, p] = rng.uniform(lo, hi, len(values)) if key in ranges else lo
    # rounded: a value printed in the manifest reads back the same, and rebuilds the same body
    return keys, np.round(values, 6)


def shape_bodies(cfg: DictConfig, base: Body) -> tuple[list[Body], BodyShapes] | tuple[None, None]:
    """The people of `cfg` as full Bodies (each built by the body's own builder; for the drapes, whose
    collisions need the person's inside test) and as BodyShapes; (None, None) without `data.body_shape`.
    Refuses a person whose mesh, weights or skeleton differ from `base` (the embedding would not hold)."""
    drawn = sample_phenotypes(cfg)
    if drawn is None:
        return None, None
    keys, values = drawn
    people = []
    for row in values:
        body = body_from_config(OmegaConf.merge(cfg.body, {"phenotype": dict(zip(keys, row.tolist(), strict=True))}))
        same = (body.vertices.shape == base.vertices.shape and torch.equal(body.faces, base.faces)
                and torch.equal(body.weights, base.weights) and body.skeleton.names == base.skeleton.names
                and body.skeleton.parents == base.skeleton.parents
                and torch.equal(body.skeleton.frames(), base.skeleton.frames()))
        if not same:
            raise ValueError(f"the body of phenotype {dict(zip(keys, row.tolist(), strict=True))} has another mesh, "
                             "skinning weights or skeleton than the base body: data.body_shape needs a body whose "
                             "phenotypes only move its rest vertices and joints (Anny)")
        people.append(body)
    shapes = BodyShapes(keys, values, torch.stack([b.vertices for b in people]).float(),
                        torch.stack([b.skeleton.rest_heads for b in people]).float())
    return people, shapes


def person_of(i: int, shapes: BodyShapes | None) -> int:
    """The person generation sample i is draped on: i mod K."""
    return 0 if shapes is None else i % len(shapes)


def person_body(base: Body, shapes: BodyShapes, k: int) -> Body:
    """Person k as a Body: the base body with person k's rest vertices and joint heads. Without an inside
    test (primitives None): those were fitted to the base person."""
    if not 0 <= k < len(shapes):
        raise ValueError(f"person {k} is outside 0..{len(shapes) - 1}, the dataset's people")
    skel = dataclasses.replace(base.skeleton, rest_heads=shapes.heads[k].clone())
    return dataclasses.replace(base, skeleton=skel, vertices=shapes.vertices[k].clone(), primitives=None,
                               config=None)


def shapes_hash(shapes: BodyShapes) -> str:
    return hash_arrays(shapes.values, shapes.vertices, shapes.heads)


def save_shapes(shapes: BodyShapes, path: str | Path) -> None:
    """Write shapes.npz atomically."""
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, keys=np.array(shapes.keys, dtype=np.str_), values=np.asarray(shapes.values, np.float64),
                 vertices=shapes.vertices.numpy().astype(np.float32), heads=shapes.heads.numpy().astype(np.float32))


def load_shapes(path: str | Path) -> BodyShapes:
    """Read shapes.npz (`save_shapes`), with a clear error when missing or corrupt."""
    z = load_npz(path, ("keys", "values", "vertices", "heads"), "body shapes", "regenerate the dataset")
    return BodyShapes(tuple(str(k) for k in z["keys"]), z["values"], torch.from_numpy(z["vertices"]).float(),
                      torch.from_numpy(z["heads"]).float())
