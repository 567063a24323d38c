"""Drape one garment on one static posed body to static equilibrium with newton's SolverStyle3D.

This module's one job is the physics of record for a sample (docs/architecture.md; appendix D.6): start
from the garment skinned onto the posed body, relax it under gravity with Style3D's anisotropic
stretch and bending energies whose rest shape is the flat sewing pattern, collide every cloth vertex
with its *primary* body part only (torso, left arm, right arm: D.6), and step frames until the cloth
stops moving. It also holds the D.6 discard rule (triangle area ratios against the pattern).

Per-part collision: newton has no per-particle collision groups (shape collision groups filter
shape-shape pairs only), but its `CollisionPipeline` launches soft contacts from an explicit list of
(particle, shape) candidate pairs. We add one static mesh shape per body part and replace that list
with exactly one pair per particle, (i, vertex_part[i]), so a vertex never sees the other parts. The
list is built at pipeline construction from worlds only, so replacing it is safe; the attributes are
checked (newton is pinned to 1.8.0 because this API moves between releases).

Shapes: V garment vertices, F garment faces, Vb/Fb body vertices/faces. Metres, y up, float32.
"""

from __future__ import annotations

import contextlib
import io
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

PART_NAMES = ("torso", "left_arm", "right_arm")

_WARP_STATE: dict[str, object] = {}


@dataclass
class DrapeResult:
    """Outcome of one drape.

    positions: (V, 3) float32 final positions.
    residual: speed over the last frame (m/s) of the vertex at quantile cfg.residual_quantile (0.95) of
        |x_k - x_{k-1}| / frame_dt. Not the max: a few vertices in contact chatter by ~1 mm a frame
        forever (contact/self-collision projection), while the cloth as a whole has settled.
    residual_max: the max vertex speed over the last frame (m/s), reported beside it.
    iterations: frames run (each frame = `substeps` solver steps of `iterations` PD iterations).
    seconds: wall time of the whole call (model build + stepping; kernels already compiled).
    cpu_seconds: CPU time of the call (equals `seconds` on an idle core; warp CPU kernels are serial).
    converged: residual < cfg.tolerance (and finite) before cfg.max_frames.
    """

    positions: np.ndarray
    residual: float
    iterations: int
    seconds: float
    converged: bool
    cpu_seconds: float = float("nan")  # process CPU time of the call: the per-core cost under contention
    residual_max: float = float("nan")


def config_value(cfg, key, default=None):
    """Read a key from a DictConfig / dict / namespace without caring which."""
    if cfg is None:
        return default
    if isinstance(cfg, dict):
        return cfg.get(key, default)
    try:
        return cfg.get(key, default)  # DictConfig
    except AttributeError:
        return getattr(cfg, key, default)


def init_warp(cache_dir: str | os.PathLike | None = None):
    """Initialise warp once per process, quietly, with a persistent kernel cache; return the module.

    The cache dir must be set before `wp.init()` so compiled CPU kernels (35-45 s the first time) are
    reused by later processes and CI. A second call with another dir keeps the first (warp cannot
    switch caches after init).
    """
    import warp as wp  # noqa: PLC0415 - warp loads in ~0.3 s; the discard rule and part capping here need no warp

    if not _WARP_STATE.get("ready"):
        # warp 1.19 replaced `config.quiet` by `log_level`; ERROR also hides the "no CUDA driver"
        # notice every CPU worker would print
        wp.config.quiet = True
        wp.config.log_level = wp.LOG_ERROR
        if cache_dir:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            wp.config.kernel_cache_dir = str(cache_dir)
        wp.init()
        _WARP_STATE["ready"] = True
        _WARP_STATE["cache_dir"] = str(cache_dir) if cache_dir else None
    return wp


def pattern_triangles(uv: np.ndarray, face_uv: np.ndarray, uv_scale: float) -> np.ndarray:
    """Flat sewing-pattern triangles: uv (T, 2), face_uv (F, 3), metres per uv unit -> (F, 3, 2) metres."""
    uv = np.asarray(uv, dtype=np.float64)
    return uv[np.asarray(face_uv)] * float(uv_scale)


def rest_triangle_areas(rest_pattern_triangles: np.ndarray) -> np.ndarray:
    """(F, 3, 2) pattern triangles -> (F,) unsigned rest areas in m^2."""
    t = np.asarray(rest_pattern_triangles, dtype=np.float64)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def triangle_area_ratios(positions: np.ndarray, faces: np.ndarray, rest_areas: np.ndarray) -> np.ndarray:
    """Current / rest area per face: positions (V, 3), faces (F, 3), rest_areas (F,) -> (F,)."""
    p = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces)
    area = 0.5 * np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1)
    return area / np.maximum(np.asarray(rest_areas, dtype=np.float64), 1e-20)


def area_limits(cfg) -> tuple[float, float]:
    """The D.6 area ratios (lowest, highest) a face may have: 1 - cfg.discard.max_area_compression and
    1 + cfg.discard.max_area_expansion (cfg: the `sim` node, or its `discard` node)."""
    d = config_value(cfg, "discard", cfg)
    return (1.0 - float(config_value(d, "max_area_compression", 0.75)),
            1.0 + float(config_value(d, "max_area_expansion", 1.0)))


def check_sample(positions, faces, rest_areas, cfg, converged: bool = True) -> tuple[bool, str]:
    """D.6 discard rule. Returns (ok, reason); reason in {"", "nan", "not_converged",
    "area_compressed", "area_stretched"}, checked in that order.

    positions (V, 3), faces (F, 3), rest_areas (F,). Thresholds from cfg: a face is compressed when
    its area ratio < 1 - cfg.discard.max_area_compression (0.75 -> ratio < 0.25) and stretched when
    ratio > 1 + cfg.discard.max_area_expansion (1.0 -> ratio > 2).
    """
    p = np.asarray(positions)
    if not np.all(np.isfinite(p)):
        return False, "nan"
    if not converged:
        return False, "not_converged"
    lo, hi = area_limits(cfg)
    ratio = triangle_area_ratios(p, faces, rest_areas)
    if np.any(ratio < lo):
        return False, "area_compressed"
    if np.any(ratio > hi):
        return False, "area_stretched"
    return True, ""


def _oriented_panels(rest_pattern_triangles: np.ndarray, faces: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Per-corner panel coordinates (F*3, 2) with positive signed area for every face.

    Style3D drops triangles whose panel (uv) area is negative, and image-style uv (v down) or a mirrored
    back chart flips the orientation against the 3D winding. Mirroring a flipped face's panel (u -> -u)
    keeps its edge lengths and angles, so weft/warp strains and the (quadratic) shear energy are
    unchanged. Corners are not shared between faces so each face can be mirrored on its own;
    Style3D's bending reads each face's own panel corners.
    """
    t = np.asarray(rest_pattern_triangles, dtype=np.float64).copy()
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    signed = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    t[signed < 0, :, 0] *= -1.0
    return t.reshape(-1, 2)


def _cap_holes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Close every boundary loop of an outward-oriented open mesh with a fan around the loop centroid.

    A part mesh cut out of the body is open where the part ends (e.g. the torso at the armpit). Near
    that cut the inside/outside sign of a closest-point query is ill-defined, so the contact normal of a
    cloth vertex there flips from frame to frame and the drape never settles. Capping makes each part
    watertight: the sign is exact and the part simply ends in a flat lid inside the neighbouring part.
    vertices (n, 3), faces (m, 3) -> capped (n + loops, 3), (m + boundary edges, 3).
    """
    he = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = he[:, 0] * len(vertices) + he[:, 1]
    rev = he[:, 1] * len(vertices) + he[:, 0]
    bnd = he[~np.isin(rev, key)]  # half-edges a->b whose twin b->a is missing
    if len(bnd) == 0:
        return vertices, faces
    n = len(vertices)
    graph = coo_matrix((np.ones(len(bnd)), (bnd[:, 0], bnd[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loops, loop_of_edge = np.unique(label[bnd[:, 0]], return_inverse=True)
    centroids = np.stack([vertices[np.unique(bnd[loop_of_edge == k])].mean(0) for k in range(len(loops))])
    # the lid's triangles run each boundary half-edge backwards so its normal points out of the part
    lid = np.stack([bnd[:, 1], bnd[:, 0], n + loop_of_edge], axis=1)
    return np.concatenate([vertices, centroids]), np.concatenate([faces, lid])


def part_meshes(body_vertices, body_faces, part_masks):
    """One closed (vertices, faces) mesh per part: the body faces whose three vertices are all in the
    part, with the cut capped (`_cap_holes`)."""
    bf = np.asarray(body_faces, dtype=np.int64)
    out = []
    for mask in np.asarray(part_masks, dtype=bool):
        keep = mask[bf].all(axis=1)
        if not keep.any():
            raise ValueError("a body part mask selects no complete face; cannot build its collision mesh")
        sub = bf[keep]
        used, inv = np.unique(sub, return_inverse=True)
        v, f = _cap_holes(np.asarray(body_vertices, dtype=np.float64)[used], inv.reshape(-1, 3))
        out.append((v.astype(np.float32), f.astype(np.int32)))
    return out


def check_drape_inputs(rest_pattern_triangles, faces, start, body_vertices, body_faces, vertex_part, part_masks):
    faces = np.asarray(faces)
    start = np.asarray(start)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be (F, 3), got {faces.shape}")
    if np.asarray(rest_pattern_triangles).shape != (faces.shape[0], 3, 2):
        raise ValueError(
            f"rest_pattern_triangles must be (F, 3, 2) = {(faces.shape[0], 3, 2)}, "
            f"got {np.asarray(rest_pattern_triangles).shape}"
        )
    if start.ndim != 2 or start.shape[1] != 3 or not np.all(np.isfinite(start)):
        raise ValueError(f"start must be a finite (V, 3) array, got shape {start.shape}")
    if np.asarray(vertex_part).shape != (start.shape[0],):
        raise ValueError(f"vertex_part must be (V,) = ({start.shape[0]},), got {np.asarray(vertex_part).shape}")
    pm = np.asarray(part_masks)
    if pm.ndim != 2 or pm.shape[1] != np.asarray(body_vertices).shape[0]:
        raise ValueError(f"part_masks must be (P, Vb), got {pm.shape}")
    vp = np.asarray(vertex_part)
    if vp.min() < 0 or vp.max() >= pm.shape[0]:
        raise ValueError(f"vertex_part values must be in [0, {pm.shape[0]}), got [{vp.min()}, {vp.max()}]")
    if np.asarray(body_faces).ndim != 2 or np.asarray(body_faces).shape[1] != 3:
        raise ValueError(f"body_faces must be (Fb, 3), got {np.asarray(body_faces).shape}")


def scene_builder(rest_pattern_triangles, faces, start, part_meshes, cfg):
    """One drape's newton scene: the garment as Style3D cloth starting at `start` (V, 3) with its sewing
    pattern as rest shape, and one static collision mesh per body part [(verts, tris), ...].

    Returns (ModelBuilder, shape ids). The single drape finalizes it; the batched drape replicates it into
    K worlds, so both simulate exactly the same scene.
    """
    wp = init_warp(config_value(cfg, "kernel_cache_dir"))
    import newton  # noqa: PLC0415 - newton loads in ~2 s; only building a drape needs it
    from newton.solvers import SolverStyle3D, style3d  # noqa: PLC0415 - as above: only a drape needs newton

    n_faces = faces.shape[0]
    builder = newton.ModelBuilder(up_axis=newton.Axis.Y)
    builder.gravity = wp.vec3(0.0, -float(config_value(cfg, "gravity")), 0.0)
    SolverStyle3D.register_custom_attributes(builder)
    style3d.add_cloth_mesh(
        builder,
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        vel=wp.vec3(0.0, 0.0, 0.0),
        # newton drops triangles that are degenerate in the positions given here (it also derives a
        # rest pose from them, which the pattern then overwrites); a skinned start can collapse a
        # triangle, so build from a tiny deterministic jitter of it and set the exact start below
        vertices=(start + 1.0e-5 * np.random.default_rng(0).standard_normal(start.shape)).tolist(),
        indices=faces.reshape(-1).tolist(),
        panel_verts=_oriented_panels(rest_pattern_triangles, faces, start).tolist(),
        panel_indices=np.arange(3 * n_faces).tolist(),
        density=float(config_value(cfg, "density")),
        # the particle radius is the cloth-body contact distance: the thickness
        particle_radius=float(config_value(cfg, "thickness")),
        tri_aniso_ke=wp.vec3(*[float(x) for x in config_value(cfg, "stretch_ke")]),
        edge_aniso_ke=wp.vec3(*[float(x) for x in config_value(cfg, "bend_ke")]),
    )
    if builder.particle_count != start.shape[0] or len(builder.tri_indices) != n_faces:
        raise ValueError("Style3D dropped degenerate pattern triangles; the rest pattern has zero-area faces")
    shape_cfg = newton.ModelBuilder.ShapeConfig(
        mu=float(config_value(cfg, "friction")), margin=0.0, has_shape_collision=False, has_particle_collision=True
    )
    shape_ids = [builder.add_shape_mesh(body=-1, mesh=newton.Mesh(verts, tris.reshape(-1), compute_inertia=False,
                                                                   is_solid=True), cfg=shape_cfg)
                 for verts, tris in part_meshes]
    return builder, shape_ids


SELF_COLLISION_TERMS = {"vertex_face": "stiff_vf", "edge_edge": "stiff_ee", "untangle": "stiff_ef"}


def configure_self_collision(collision, cfg) -> None:
    """Set Style3D's cloth-cloth contact (a `Collision` of newton 1.8.0) from cfg: the radius and the
    stiffness of its three terms (cfg.self_collision_stiffness: vertex_face and edge_edge push layers
    that come closer than 2 radii apart; untangle pulls apart cloth that already crosses itself).
    Shared by the single and the batched drape so both simulate the same cloth. A key left out keeps
    newton's value; self_collision: false turns all three off.
    """
    if not config_value(cfg, "self_collision", True):
        collision.stiff_vf = collision.stiff_ee = collision.stiff_ef = 0.0
        return
    if config_value(cfg, "self_collision_radius") is not None:
        collision.radius = float(config_value(cfg, "self_collision_radius"))
    stiffness = config_value(cfg, "self_collision_stiffness") or {}
    unknown = sorted(set(stiffness) - set(SELF_COLLISION_TERMS))
    if unknown:
        raise ValueError(f"sim.self_collision_stiffness has unknown term(s) {unknown}; the terms are "
                         f"{sorted(SELF_COLLISION_TERMS)} (conf/sim/style3d.yaml)")
    values = {term: float(stiffness[term]) for term in SELF_COLLISION_TERMS if stiffness.get(term) is not None}
    for term, value in values.items():  # all checked before any is set
        if not value >= 0.0:
            raise ValueError(f"sim.self_collision_stiffness.{term} must be >= 0, got {stiffness[term]!r} "
                             f"(conf/sim/style3d.yaml)")
    for term, value in values.items():
        setattr(collision, SELF_COLLISION_TERMS[term], value)


def stepping(cfg) -> tuple[float, float, int, float, int, int, float, float]:
    """The frame loop's settings, read in one place for the single and the batched drape:
    (frame_dt, dt, substeps, tolerance, min_frames, max_frames, keep, residual_quantile), where `keep`
    is the velocity kept per frame: a quasi-static drape only needs the end state, so bleeding kinetic
    energy (cfg.velocity_damping) shortens the settle without changing the equilibrium."""
    substeps = int(config_value(cfg, "substeps"))
    frame_dt = 1.0 / float(config_value(cfg, "fps"))
    return (frame_dt, frame_dt / substeps, substeps, float(config_value(cfg, "tolerance")),
            int(config_value(cfg, "min_frames", 1)),
            int(config_value(cfg, "max_frames")), 1.0 - float(config_value(cfg, "velocity_damping", 0.0)),
            float(config_value(cfg, "residual_quantile", 1.0)))


def build_drape_sim(rest_pattern_triangles, faces, start, body_vertices, body_faces, vertex_part, part_masks, cfg):
    """Build (model, solver, collision pipeline, contacts, states) for one drape. Returns a dict.

    Split out of `drape` so tests and benchmarks can inspect the model (masses, contact pairs).
    """
    wp = init_warp(config_value(cfg, "kernel_cache_dir"))
    import newton  # noqa: PLC0415 - newton loads in ~2 s; only building a drape needs it
    from newton.solvers import SolverStyle3D  # noqa: PLC0415 - as above: only a drape needs newton

    check_drape_inputs(rest_pattern_triangles, faces, start, body_vertices, body_faces, vertex_part, part_masks)
    device = config_value(cfg, "device") or None
    faces = np.asarray(faces, dtype=np.int64)
    start = np.asarray(start, dtype=np.float64)
    friction = float(config_value(cfg, "friction"))
    builder, shape_ids = scene_builder(rest_pattern_triangles, faces, start,
                                       part_meshes(body_vertices, body_faces, part_masks), cfg)

    model = builder.finalize(device=device)
    model.soft_contact_ke = float(config_value(cfg, "contact_ke"))
    model.soft_contact_kd = float(config_value(cfg, "contact_kd"))
    # newton mixes sqrt(model mu * shape mu): equal values give exactly cfg.friction
    model.soft_contact_mu = friction

    solver = SolverStyle3D(
        model,
        config=SolverStyle3D.Config(
            iterations=int(config_value(cfg, "iterations")),
            linear_iterations=int(config_value(cfg, "linear_iterations"))
        ),
    )
    configure_self_collision(solver.collision, cfg)

    n = model.particle_count
    pipeline = newton.CollisionPipeline(
        model,
        soft_contact_gap=float(config_value(cfg, "contact_gap")),
        soft_contact_max=n,
        rigid_contact_max=0,
    )
    # per-part collision (D.6): one candidate pair (particle i, shape of its part) per particle
    if not hasattr(pipeline, "soft_rigid_contact_pairs") or not hasattr(pipeline, "_soft_contact_pair_count"):
        raise RuntimeError("newton's CollisionPipeline changed; per-part contact filtering needs newton==1.8.0")
    pairs = np.stack([np.arange(n), np.asarray(shape_ids)[np.asarray(vertex_part, dtype=np.int64)]], axis=1)
    pipeline.soft_rigid_contact_pairs = wp.array(pairs.astype(np.int32), dtype=wp.vec2i, device=model.device)
    pipeline._soft_contact_pair_count = n
    contacts = pipeline.contacts()

    states = [model.state(), model.state()]
    for st in states:
        st.particle_q.assign(start.astype(np.float32))
    solver.rebuild_bvh(states[0])

    return {
        "wp": wp,
        "model": model,
        "solver": solver,
        "pipeline": pipeline,
        "contacts": contacts,
        "states": states,
        "control": model.control(),
    }


def drape(
    rest_pattern_triangles: np.ndarray,
    faces: np.ndarray,
    start: np.ndarray,
    body_vertices: np.ndarray,
    body_faces: np.ndarray,
    vertex_part: np.ndarray,
    part_masks: np.ndarray,
    cfg,
) -> DrapeResult:
    """Relax the skinned garment to static equilibrium on the static posed body.

    rest_pattern_triangles: (F, 3, 2) metres, the flat pattern per face (`pattern_triangles(uv, face_uv,
        uv_scale)`), the stress-free shape for stretch and (flat) bending.
    faces: (F, 3) int garment triangles. start: (V, 3) skinned start positions.
    body_vertices: (Vb, 3) posed body, body_faces: (Fb, 3) int, outward normals.
    vertex_part: (V,) int primary collision part per garment vertex; part_masks: (P, Vb) bool (P=3).
    cfg: the `sim` config node (conf/sim/style3d.yaml).

    Steps frames of `substeps` Style3D steps until the max vertex speed over a frame is below
    cfg.tolerance (after cfg.min_frames) or cfg.max_frames is reached.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    quiet = io.StringIO()
    # newton's precompute prints a ScopedTimer line; keep worker logs clean
    with contextlib.redirect_stdout(quiet):
        sim = build_drape_sim(
            rest_pattern_triangles, faces, start, body_vertices, body_faces, vertex_part, part_masks, cfg
        )
    wp = sim["wp"]
    solver, pipeline, contacts, control = sim["solver"], sim["pipeline"], sim["contacts"], sim["control"]
    s0, s1 = sim["states"]

    frame_dt, dt, substeps, tol, min_frames, max_frames, keep, quantile = stepping(cfg)
    fold_frames = int(config_value(cfg, "fold_frames", 0))
    rest_areas = rest_triangle_areas(rest_pattern_triangles)
    x_prev = s0.particle_q.numpy().copy()
    residual = residual_max = float("inf")
    frames = 0
    settled_at = None  # the first frame the speed rule held
    converged = False
    for frames in range(1, max_frames + 1):  # noqa: B007
        pipeline.collide(s0, contacts)
        for _ in range(substeps):
            s0.clear_forces()
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
        if keep < 1.0:
            s0.particle_qd.assign(s0.particle_qd.numpy() * keep)
        x = s0.particle_q.numpy()
        if not np.all(np.isfinite(x)):
            residual = residual_max = float("nan")
            break
        speed = np.sqrt(((x - x_prev) ** 2).sum(axis=1)) / frame_dt
        residual, residual_max = float(np.quantile(speed, quantile)), float(speed.max())
        x_prev = x.copy()
        if frames >= min_frames and residual < tol:
            settled_at = frames if settled_at is None else settled_at
            # a face past the D.6 area limits may be a fold still snapping through: judge it settled again later
            if frames - settled_at >= fold_frames or check_sample(x, faces, rest_areas, cfg)[0]:
                converged = True
                break
    wp.synchronize()
    return DrapeResult(
        positions=np.asarray(x_prev if np.isfinite(residual) else s0.particle_q.numpy(), dtype=np.float32),
        residual=residual,
        residual_max=residual_max,
        iterations=frames,
        seconds=time.perf_counter() - t0,
        converged=converged,
        cpu_seconds=time.process_time() - c0,
    )



def signed_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, cache_dir=None) -> np.ndarray:
    """Signed distance of points (N, 3) to a watertight mesh (Vb, 3)/(Fb, 3): (N,) metres, negative inside."""
    return closest_points(points, vertices, faces, cache_dir)[0]


def closest_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, cache_dir=None):
    """Closest surface points of a watertight mesh: points (N, 3) -> (signed distance (N,), closest (N, 3)).

    Distances are negative inside (warp BVH closest-point query, parity sign). Used to measure the
    penetration of a drape and by tests to place a cloth on a body.
    """
    wp = init_warp(cache_dir)
    kernel = _WARP_STATE.get("closest_kernel")
    if kernel is None:

        @wp.kernel
        def _closest(
            mesh: wp.uint64,
            pts: wp.array(dtype=wp.vec3),
            dist: wp.array(dtype=float),
            cp: wp.array(dtype=wp.vec3),
        ):
            i = wp.tid()
            q = wp.mesh_query_point_sign_parity(mesh, pts[i], 1.0e6)
            if q.result:
                c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
                cp[i] = c
                dist[i] = wp.length(pts[i] - c) * q.sign
            else:
                cp[i] = pts[i]
                dist[i] = 1.0e6

        kernel = _WARP_STATE["closest_kernel"] = _closest
    dev = "cpu"
    mesh = wp.Mesh(
        points=wp.array(np.asarray(vertices, dtype=np.float32), dtype=wp.vec3, device=dev),
        indices=wp.array(np.asarray(faces, dtype=np.int32).reshape(-1), dtype=int, device=dev),
    )
    pts = wp.array(np.asarray(points, dtype=np.float32), dtype=wp.vec3, device=dev)
    dist = wp.zeros(len(pts), dtype=float, device=dev)
    cp = wp.zeros(len(pts), dtype=wp.vec3, device=dev)
    wp.launch(kernel, dim=len(pts), inputs=[mesh.id, pts], outputs=[dist, cp], device=dev)
    return dist.numpy().astype(np.float64), cp.numpy().astype(np.float64)


def as_numpy(x) -> np.ndarray:
    """Tensor or array -> numpy (no torch import needed here)."""
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def drape_garment(garment, start, body_vertices, body, embedding, cfg) -> DrapeResult:
    """`drape` for pbc objects: garment (Garment: faces, uv, face_uv, uv_scale), start (V, 3), posed
    body_vertices (Vb, 3), body (Body: faces, parts (3, Vb)), embedding (Embedding: part (V,))."""
    return drape(
        pattern_triangles(as_numpy(garment.uv), as_numpy(garment.face_uv), float(garment.uv_scale)),
        as_numpy(garment.faces),
        as_numpy(start),
        as_numpy(body_vertices),
        as_numpy(body.faces),
        as_numpy(embedding.part),
        as_numpy(body.parts),
        cfg,
    )


def check_garment_result(result: DrapeResult, garment, cfg) -> tuple[bool, str]:
    """`check_sample` for a `drape_garment` result against the garment's pattern areas."""
    pattern = pattern_triangles(as_numpy(garment.uv), as_numpy(garment.face_uv), float(garment.uv_scale))
    rest = rest_triangle_areas(pattern)
    return check_sample(result.positions, as_numpy(garment.faces), rest, cfg, result.converged)
