"""An outfit at inference: several garments on one body, each predicted by its own model, composed as ordered layers
(PBNS): inner to outer, each layer pushed out of the layers under it (and, as conf/outfit.yaml's `body` says, out
of the body) by `pbc.geometry.mend.push_out_of`, one screened solve that keeps the predicted shape.

- `infer_order`: which piece covers which, from their rest garments: where two overlap, the one farther from the
  body is outer.
- `compose_frame` / `compose`: the push-outs of one frame / of frames, arrays only, with the PBNS/HOOD metric of
  each layer before and after: the share of its vertices inside the layers under it and inside the body.
- `OutfitPredictor`: ClothPredictors on one body (refused otherwise), the order given or inferred, poses in,
  every piece's vertices and the per-layer figures out.

A vertex is inside a layer under it when its closest point there lies off that layer's rim, on its inner side and
at most `push_band` (conf/mend.yaml) deep: a layer is an open surface, and a point beyond its opening (a shirt
above the trousers' waistband) is outside it whatever the normal at the rim says. No file is read but the
settings (conf/outfit.yaml, conf/mend.yaml) and nothing is written.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
import scipy.sparse as sp
import torch
from omegaconf import OmegaConf
from torch import Tensor

from pbc.core.paths import CONF_DIR
from pbc.core.validate import check_settings_file
from pbc.geometry.mend import Collider, MendSettings, collider_distances, edge_operator, mend_settings, push_out_of
from pbc.geometry.meshops import closest_on_mesh, mesh_edges, surface_distance
from pbc.inference.poses import posed_bodies
from pbc.inference.predictor import ClothPredictor
from pbc.sim.drape import part_meshes

SETTINGS_FILE = CONF_DIR / "outfit.yaml"
BODY_COLLIDERS = ("none", "parts", "whole")  # conf/outfit.yaml body


@dataclass(frozen=True)
class OutfitSettings:
    """conf/outfit.yaml as typed values (the defaults mirror it; a test keeps them equal)."""

    body: str = "none"  # the body each layer is also pushed out of: none, parts (its simulator parts), whole
    overlap: float = 0.03  # m: vertices of two pieces within this of each other overlap (the order is read there)
    min_overlap: int = 20  # vertices of each piece: fewer and the two do not overlap
    rounds: int = 3  # push-out solves of a layer at most, judged anew between them
    rim_tolerance: float = 1e-6  # barycentric weight under which a closest point lies on the opposite edge
    colours: tuple[tuple[float, float, float], ...] = ((0.25, 0.35, 0.55), (0.90, 0.45, 0.25), (0.35, 0.65, 0.35),
                                                       (0.70, 0.40, 0.75))

    def colour(self, layer: int) -> tuple[float, float, float]:
        """The RGB of layer `layer` (0: the innermost), the colours again from the first past the last."""
        return self.colours[layer % len(self.colours)]


def outfit_settings(**overrides) -> OutfitSettings:
    """conf/outfit.yaml held to conf/bounds.yaml's `outfit` section (one ValueError naming every bad key), as
    OutfitSettings, with `overrides` (field=value) on top."""
    node = OmegaConf.load(SETTINGS_FILE)
    check_settings_file("outfit", node, SETTINGS_FILE)
    values = OmegaConf.to_container(node)
    values["colours"] = tuple(tuple(float(c) for c in rgb) for _, rgb in sorted(values.get("colours", {}).items()))
    values.update(overrides)
    unknown = sorted(set(values) - {f.name for f in fields(OutfitSettings)})
    if unknown:
        raise ValueError(f"{SETTINGS_FILE}: unknown outfit setting(s) {unknown}; the settings are "
                         f"{[f.name for f in fields(OutfitSettings)]}")
    if values.get("body", "none") not in BODY_COLLIDERS:
        raise ValueError(f"{SETTINGS_FILE}: body={values['body']!r}: one of {', '.join(BODY_COLLIDERS)}")
    return OutfitSettings(**values)


@dataclass(frozen=True)
class LayerMesh:
    """One piece's mesh as a layer: its name, faces (F, 3), edges (E, 2), the body part each vertex collides with
    in the simulator (V,) (None: unknown), and its rim (the edges of one face) as sorted edge keys and a vertex
    mask (V,)."""

    name: str
    faces: np.ndarray
    edges: np.ndarray
    part: np.ndarray | None
    rim_keys: np.ndarray = field(repr=False)
    rim_vertices: np.ndarray = field(repr=False)
    operator: sp.csr_matrix = field(repr=False)

    @classmethod
    def of(cls, name: str, faces, num_vertices: int, part=None) -> LayerMesh:
        f = np.asarray(faces, np.int64)
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, count = np.unique(e, axis=0, return_counts=True)
        rim = uniq[count == 1]
        rim_vertices = np.zeros(int(num_vertices), bool)
        rim_vertices[rim.ravel()] = True
        edges = mesh_edges(f)
        return cls(name, f, edges, None if part is None else np.asarray(part, np.int64),
                   np.sort(rim[:, 0] * num_vertices + rim[:, 1]), rim_vertices, edge_operator(edges, num_vertices))

    @property
    def num_vertices(self) -> int:
        return len(self.rim_vertices)


def off_rim(points: np.ndarray, vertices: np.ndarray, layer: LayerMesh, candidates: int, tol: float) -> np.ndarray:
    """(P,) bool: whether each point's closest point on the layer (vertices (V, 3)) lies off its rim: not on an
    edge of one face, nor at a vertex of one."""
    _, face, bary = closest_on_mesh(points, vertices, layer.faces, candidates)
    f = layer.faces[face]  # (P, 3)
    n = layer.num_vertices
    on = np.zeros(len(points), bool)
    for s in range(3):
        a, b = f[:, (s + 1) % 3], f[:, (s + 2) % 3]
        key = np.minimum(a, b) * n + np.maximum(a, b)
        on |= (bary[:, s] < tol) & np.isin(key, layer.rim_keys)
        on |= (bary[:, s] > 1.0 - tol) & layer.rim_vertices[f[:, s]]
    return ~on


def layer_colliders(points: np.ndarray, under: Sequence[tuple[np.ndarray, LayerMesh]], mend: MendSettings,
                    settings: OutfitSettings) -> list[Collider]:
    """The layers under a layer, as open colliders of its vertices points (P, 3): each holding out the points whose
    closest point on it is off its rim. under: (vertices (V, 3), its LayerMesh) each."""
    return [Collider(v, m.faces, off_rim(points, v, m, mend.candidates, settings.rim_tolerance), closed=False)
            for v, m in under]


def body_colliders(layer: LayerMesh, body_vertices: np.ndarray, body_faces: np.ndarray, part_masks: np.ndarray | None,
                   settings: OutfitSettings) -> list[Collider]:
    """The body as the collider of a layer, as conf/outfit.yaml's `body` says: none ([]), whole (the posed body
    (Vb, 3), faces (Fb, 3)), parts (each vertex against its own simulator part, part_masks (P, Vb) bool; a layer
    without parts: the whole body)."""
    if settings.body == "none":
        return []
    if settings.body == "whole" or layer.part is None or part_masks is None:
        return [Collider(body_vertices, body_faces)]
    meshes = part_meshes(body_vertices, body_faces, part_masks)
    return [Collider(v, f, layer.part == p) for p, (v, f) in enumerate(meshes) if (layer.part == p).any()]


def inside_layers(points: np.ndarray, under: Sequence[tuple[np.ndarray, LayerMesh]], mend: MendSettings,
                  settings: OutfitSettings) -> np.ndarray:
    """(P,) bool: the points (P, 3) inside a layer under them (off its rim, within mend.push_band deep)."""
    if not under:
        return np.zeros(len(points), bool)
    dist, _, _ = collider_distances(points, layer_colliders(points, under, mend, settings), mend)
    return dist < 0.0


def inside_body(points: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, candidates: int) -> np.ndarray:
    """(P,) bool: the points (P, 3) inside the posed body (vertices (Vb, 3), faces (Fb, 3), outward normals)."""
    dist, _, _ = surface_distance(points, body_vertices, body_faces, candidates)
    return dist < 0.0


def compose_frame(xs: Sequence[np.ndarray], layers: Sequence[LayerMesh], body_vertices: np.ndarray,
                  body_faces: np.ndarray, part_masks: np.ndarray | None, mend: MendSettings,
                  settings: OutfitSettings) -> tuple[list[np.ndarray], list[dict]]:
    """One frame of an outfit: xs[i] (V_i, 3) the prediction of layers[i], innermost first, on the posed body
    (Vb, 3). Inner to outer, each layer is pushed out of the composed layers under it (and the body, as
    settings.body says), at most settings.rounds solves. Returns (the composed vertices, each (V_i, 3) float64;
    per layer: vertices inside the layers under it and inside the body, before (the predictions as they are) and
    after, the most a vertex moved in mm and the solves taken)."""
    mend = replace(mend, push_out=True)
    raw = [np.asarray(x, np.float64) for x in xs]
    body_vertices = np.asarray(body_vertices, np.float64)
    out: list[np.ndarray] = []
    stats: list[dict] = []
    for i, layer in enumerate(layers):
        x = raw[i]
        st = {"vertices": len(x),
              "inside_under_before": int(inside_layers(x, list(zip(raw[:i], layers[:i], strict=True)), mend,
                                                       settings).sum()),
              "inside_body_before": int(inside_body(x, body_vertices, body_faces, mend.candidates).sum())}
        under = list(zip(out, layers[:i], strict=True))
        body = body_colliders(layer, body_vertices, body_faces, part_masks, settings)
        y, solves = x, 0
        if under or body:
            for _ in range(int(settings.rounds)):
                y, pushed = push_out_of(y, layer.edges, [*layer_colliders(y, under, mend, settings), *body], mend,
                                        layer.operator)
                solves += pushed["passes"]
                if not pushed["passes"] or not pushed["inside_after"]:
                    break
        out.append(y)
        moved = y is not x
        st.update(inside_under_after=int(inside_layers(y, under, mend, settings).sum()),
                  inside_body_after=int(inside_body(y, body_vertices, body_faces, mend.candidates).sum()) if moved
                  else st["inside_body_before"],
                  moved_mm=float(np.linalg.norm(y - x, axis=1).max() * 1e3) if moved else 0.0, solves=solves)
        stats.append(st)
    return out, stats


def layer_summary(frames: Sequence[Sequence[dict]], names: Sequence[str]) -> list[dict]:
    """Per layer over frames (compose_frame's stats of each): the % of its vertices inside the layers under it and
    inside the body before and after (over every frame's vertices), the frames with any inside, the most a vertex
    moved in mm."""
    out = []
    for i, name in enumerate(names):
        rows = [f[i] for f in frames]
        total = max(1, sum(r["vertices"] for r in rows))
        entry = {"layer": i + 1, "piece": name, "frames": len(rows)}
        for key in ("inside_under_before", "inside_under_after", "inside_body_before", "inside_body_after"):
            entry[f"{key}_pct"] = round(100.0 * sum(r[key] for r in rows) / total, 4)
            entry[f"{key}_frames"] = sum(1 for r in rows if r[key])
        entry["moved_mm_max"] = round(max((r["moved_mm"] for r in rows), default=0.0), 3)
        out.append(entry)
    return out


def rest_overlap(a: tuple[np.ndarray, LayerMesh], b: tuple[np.ndarray, LayerMesh], body_dist_a: np.ndarray,
                 mend: MendSettings, settings: OutfitSettings) -> tuple[int, float]:
    """How piece a lies against piece b: (its vertices within settings.overlap of b, off b's rim; their mean
    distance from the body in m, nan when none). a, b: (vertices (V, 3), LayerMesh); body_dist_a (V_a,)."""
    (va, _), (vb, mb) = a, b
    dist, _, _ = surface_distance(va, vb, mb.faces, mend.candidates)
    near = (np.abs(dist) < settings.overlap) & off_rim(va, vb, mb, mend.candidates, settings.rim_tolerance)
    return int(near.sum()), float(body_dist_a[near].mean()) if near.any() else float("nan")


def infer_order(pieces: Sequence[tuple[np.ndarray, LayerMesh]], body_vertices: np.ndarray, body_faces: np.ndarray,
                mend: MendSettings, settings: OutfitSettings) -> tuple[list[int], list[dict]]:
    """The layer order of pieces (vertices (V, 3) on the rest body (Vb, 3), its LayerMesh), innermost first: where
    two overlap (each has settings.min_overlap vertices within settings.overlap of the other), the one whose
    overlapping vertices lie farther from the body is outer. A piece is placed by how many it is outer of, then by
    its mean distance from the body. Returns (the pieces' indices, innermost first; one record per pair)."""
    dists = [surface_distance(v, body_vertices, body_faces, mend.candidates)[0] for v, _ in pieces]
    outer_of = np.zeros(len(pieces), np.int64)
    pairs = []
    for i in range(len(pieces)):
        for j in range(i + 1, len(pieces)):
            ni, di = rest_overlap(pieces[i], pieces[j], dists[i], mend, settings)
            nj, dj = rest_overlap(pieces[j], pieces[i], dists[j], mend, settings)
            rec = {"pieces": [pieces[i][1].name, pieces[j][1].name], "overlap_vertices": [ni, nj],
                   "body_distance_mm": [round(di * 1e3, 3) if ni else None, round(dj * 1e3, 3) if nj else None]}
            if min(ni, nj) >= settings.min_overlap:
                outer = i if di > dj else j
                outer_of[outer] += 1
                rec["outer"] = pieces[outer][1].name
            else:
                rec["outer"] = None
            pairs.append(rec)
    mean = [float(np.mean(d)) for d in dists]
    return sorted(range(len(pieces)), key=lambda k: (outer_of[k], mean[k])), pairs


def check_order(order: Sequence[str], names: Sequence[str]) -> list[str]:
    """The layer order `order` (piece names, innermost first) checked against the pieces `names`: each once, none
    unknown; one ValueError naming the problem and the fix."""
    order = [str(o).strip() for o in order]
    every = ", ".join(names)
    unknown = [o for o in order if o not in names]
    if unknown:
        raise ValueError(f"--order {','.join(order)}: no piece {unknown[0]!r} in the outfit; name its pieces "
                         f"({every}), innermost first")
    twice = sorted({o for o in order if order.count(o) > 1})
    if twice:
        raise ValueError(f"--order {','.join(order)}: {twice[0]} named twice; name each piece ({every}) once, "
                         "innermost first")
    missing = [n for n in names if n not in order]
    if missing:
        raise ValueError(f"--order {','.join(order)}: leaves out {', '.join(missing)}; name every piece ({every}) "
                         "once, innermost first")
    return order


def check_same_body(predictors: Mapping[str, ClothPredictor]) -> None:
    """Refuse pieces whose models are on different bodies (vertices or faces differ): one ValueError naming both."""
    items = list(predictors.items())
    first, a = items[0]
    for name, b in items[1:]:
        ba, bb = a.dataset.body, b.dataset.body
        va, vb = np.asarray(ba.vertices), np.asarray(bb.vertices)
        same = va.shape == vb.shape and np.array_equal(np.asarray(ba.faces), np.asarray(bb.faces))
        gap = float(np.abs(va - vb).max()) if same else float("inf")
        if not same or gap > 1e-6:
            what = (f"{len(va)} and {len(vb)} vertices" if va.shape != vb.shape
                    else "other faces" if gap == float("inf") else f"vertices up to {gap * 1e3:.1f} mm apart")
            raise ValueError(f"{first} and {name} are on different bodies ({what}): an outfit's pieces must be "
                             "learnt on one body; give models trained on the same body (conf/body)")


@dataclass
class OutfitResult:
    """What `OutfitPredictor` answers: per piece (innermost first) the composed and the predicted vertices (B, V, 3)
    float32, the per-frame stats of `compose_frame`, the per-layer summary (`layer_summary`), the posed bodies
    (B, Vb, 3) and the seconds of the prediction and of the composition."""

    order: list[str]
    vertices: dict[str, np.ndarray]
    predicted: dict[str, np.ndarray]
    frames: list[list[dict]]
    layers: list[dict]
    bodies: np.ndarray
    seconds: dict[str, float]


class OutfitPredictor:
    """Pieces (name -> ClothPredictor, all on one body) as ordered layers: `order` (names, innermost first) or None,
    inferred from the rest garments (`infer_order`). settings: conf/outfit.yaml's (None: read); mend: the push-out's
    margin, weight and band (None: conf/mend.yaml's)."""

    def __init__(self, predictors: Mapping[str, ClothPredictor], order: Sequence[str] | None = None,
                 settings: OutfitSettings | None = None, mend: MendSettings | None = None):
        names = list(predictors)
        if len(names) < 2:
            raise ValueError(f"an outfit needs two pieces or more, got {len(names)} ({', '.join(names) or 'none'}): "
                             "give a model per piece, e.g. --pretrained tshirt trousers")
        if order is not None:
            order = check_order(order, names)
        check_same_body(predictors)
        self.settings = settings or outfit_settings()
        self.mend = replace(mend or mend_settings(), push_out=True)
        self.predictors = dict(predictors)
        first = self.predictors[names[0]].dataset
        self.body_faces = np.asarray(first.body.faces, np.int64)
        self.part_masks = np.asarray(first.body.parts, bool)
        self.meshes = {n: LayerMesh.of(n, p.dataset.garment.faces, len(p.dataset.garment.vertices),
                                       p.dataset.embedding.part) for n, p in self.predictors.items()}
        rest = [(np.asarray(p.dataset.garment.vertices, np.float64), self.meshes[n])
                for n, p in self.predictors.items()]
        found, self.pairs = infer_order(rest, np.asarray(first.body.vertices, np.float64), self.body_faces,
                                        self.mend, self.settings)
        self.inferred = [names[k] for k in found]
        self.order = list(order) if order is not None else self.inferred
        self.order_source = "given" if order is not None else "inferred"

    @property
    def dataset(self):
        """The dataset of the innermost piece (its body is every piece's)."""
        return self.predictors[self.order[0]].dataset

    def __call__(self, poses: Tensor, piece_poses: Mapping[str, Tensor] | None = None, model: str = "whole",
                 batch_size: int = 16) -> OutfitResult:
        """poses (B, J, 3, 3): the body's; piece_poses: each piece's own copy (its model's guard applied; None:
        `poses` for every piece). Every piece predicted by its model, then composed frame by frame."""
        t0 = time.time()
        predicted = {}
        for name in self.order:
            p = self.predictors[name]
            src = poses if piece_poses is None else piece_poses[name]
            with torch.no_grad():
                predicted[name] = torch.cat([p(src[i:i + batch_size], model=model)
                                             for i in range(0, len(src), batch_size)]).numpy()
        t1 = time.time()
        bodies = posed_bodies(self.dataset, poses).numpy()
        layers = [self.meshes[n] for n in self.order]
        composed = {n: np.empty_like(predicted[n]) for n in self.order}
        frames = []
        for k in range(len(poses)):
            ys, st = compose_frame([predicted[n][k] for n in self.order], layers, bodies[k], self.body_faces,
                                   self.part_masks, self.mend, self.settings)
            for n, y in zip(self.order, ys, strict=True):
                composed[n][k] = y
            frames.append(st)
        t2 = time.time()
        n = max(1, len(poses))
        seconds = {"predict": round(t1 - t0, 3), "compose": round(t2 - t1, 3),
                   "predict_per_frame": round((t1 - t0) / n, 4), "compose_per_frame": round((t2 - t1) / n, 4)}
        return OutfitResult(list(self.order), composed, predicted, frames, layer_summary(frames, self.order), bodies,
                            seconds)
