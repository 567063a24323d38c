"""Drape K poses of one garment at once: one newton model, one world per pose (`sim.batch_size`).

The single-world `pbc.sim.drape.drape` stays the physics of record; this module runs the same scene
(Style3D cloth, the D.6 per-part contact pairs, the same stop and discard rules) for K poses in one
model so that a GPU gets thousands of vertices per kernel launch instead of one cloth's worth.

What keeps the worlds independent, and why each piece is needed:
- Style3D's PCG solve takes its step sizes from inner products over *all* particles, so K worlds in
  one model would share one alpha/beta per CG iteration and follow other trajectories than K single
  drapes (a 10-11 mm disagreement with the single-world drape when measured that way). `_WorldPcg` computes
  the inner products, and
  alpha/beta, per world (fixed-order chunked sums, so the result does not depend on thread timing).
- Style3D's cloth self-collision BVH spans all cloths and has no world filter, so its broad phase sees
  each world moved to its own place on a horizontal grid (`_WorldCollision`, `world_offsets`), far enough
  apart that no candidate pair crosses worlds (horizontal, so that a cloth slipping off its body falls
  past, never into, another world). Everything else sees the true positions: every world sits where a
  single drape would, bit for bit. Moving the particles themselves would not do: skinned start vertices
  lie on the body surface to float32 precision, where the contact normal is rounding noise, and the
  ~1e-7 m rounding of an offset turned it into 20-50 mm differences after one frame.
- Body contact uses one (particle, shape) pair per particle, each pointing at its own world's part mesh.
- Style3D sizes its body-contact launch as shapes x particles (3K x KV: quadratic in K); with one pair
  per particle, at most KV contacts exist, so the launch is cut to KV.

The stop rule runs on the device: after every frame a kernel damps velocities, measures each vertex's
speed and counts, per world, the speeds below the tolerance; the 95% quantile is below the tolerance
exactly when that count (with the largest speed below and the smallest above, for the interpolated
case) says so, which needs no sort. A world that converges, blows up (NaN) or runs out of frames is
frozen (its particles deactivated, its result copied on the device) and the rest keep going; the host
reads one small status array every `sim.batch_check_every` frames, collects the stopped worlds' results
and gives each the batch's next pose (so a slow pose holds up one world, not K), until all are done.
Frozen worlds still pass through every kernel (they are not compacted away); refilling them is what
keeps the work per sample at the single drape's.

The model is built once and reused for every later batch (`BatchedDrape.run`): new start positions,
fresh body part meshes per world, reset velocities and flags. Everything the physics reads is a
function of the batch alone, so a batch draped by a fresh model or a reused one gives the same bytes
(on CPU, where warp's kernels run serially; on a GPU float atomics make every drape, single or
batched, reproducible only to rounding).

Shapes: K worlds, B <= K poses in a batch, V garment vertices, Vb body vertices. Metres, y up, float32.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import time

import newton
import numpy as np
import warp as wp
from newton._src.solvers.style3d.collision import Collision
from newton._src.solvers.style3d.linear_solver import PcgSolver
from newton.solvers import SolverStyle3D

from pbc.sim.drape import (
    DrapeResult,
    area_limits,
    as_numpy,
    check_drape_inputs,
    config_value,
    configure_self_collision,
    init_warp,
    part_meshes,
    pattern_triangles,
    rest_triangle_areas,
    scene_builder,
    stepping,
)

log = logging.getLogger(__name__)

# world status (device array `status`)
ACTIVE, CONVERGED, BLEW_UP, NOT_CONVERGED, IDLE = 0, 1, 2, 3, 4
_PARTICLE_ACTIVE = 1  # newton.ParticleFlags.ACTIVE (checked against newton in BatchedDrape.__init__)
_CHUNK = 64  # particles summed by one thread in the per-world inner products


@wp.kernel
def _chunk_dot(
    a: wp.array(dtype=wp.vec3),
    b: wp.array(dtype=wp.vec3),
    chunk_begin: wp.array(dtype=wp.int32),
    chunk_end: wp.array(dtype=wp.int32),
    partial: wp.array(dtype=wp.float32),
):
    c = wp.tid()
    s = wp.float32(0.0)
    for i in range(chunk_begin[c], chunk_end[c]):
        s += wp.dot(a[i], b[i])
    partial[c] = s


@wp.kernel
def _world_sum(
    partial: wp.array(dtype=wp.float32),
    world_chunk: wp.array(dtype=wp.int32),
    row: int,
    out: wp.array2d(dtype=wp.float32),
):
    w = wp.tid()
    s = wp.float32(0.0)
    for c in range(world_chunk[w], world_chunk[w + 1]):
        s += partial[c]
    out[row, w] = s


@wp.func
def _safe_ratio(num: wp.float32, denom: wp.float32):
    """A per-world CG coefficient num / denom, or 0 where the division is undefined (denom ~0, or either
    NaN): a degenerate world's update is then zero instead of inf/NaN."""
    r = wp.float32(0.0)
    if (wp.abs(denom) > 1.0e-30) and (not wp.isnan(denom)) and (not wp.isnan(num)):
        r = num / denom
    return r


@wp.kernel
def _cg_direction(
    it: int,
    world: wp.array(dtype=wp.int32),
    z: wp.array(dtype=wp.vec3),
    rTz: wp.array2d(dtype=wp.float32),
    p: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    new_p = z[i]
    if it > 0:
        w = world[i]
        new_p += _safe_ratio(rTz[it, w], rTz[it - 1, w]) * p[i]
    p[i] = new_p


@wp.kernel
def _cg_step(
    it: int,
    world: wp.array(dtype=wp.int32),
    rTz: wp.array2d(dtype=wp.float32),
    pTAp: wp.array2d(dtype=wp.float32),
    p: wp.array(dtype=wp.vec3),
    Ap: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    w = world[i]
    alpha = _safe_ratio(rTz[it, w], pTAp[it, w])
    r[i] = r[i] - alpha * Ap[i]
    x[i] = x[i] + alpha * p[i]


@wp.kernel
def _frame_speed(
    frame_dt: float,
    keep: float,
    damp: int,
    tol: float,
    world: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    pin: wp.array(dtype=wp.vec3),
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    q_prev: wp.array(dtype=wp.vec3),
    speed: wp.array(dtype=wp.float32),
    nan_flag: wp.array(dtype=wp.int32),
    n_below: wp.array(dtype=wp.int32),
    below_max: wp.array(dtype=wp.float32),
    above_min: wp.array(dtype=wp.float32),
):
    i = wp.tid()
    w = world[i]
    if status[w] != 0:
        # frozen worlds stay exactly where they were retired (belt and braces: they are inactive)
        q[i] = pin[i]
        qd[i] = wp.vec3(0.0)
        return
    if damp != 0:
        qd[i] = qd[i] * keep
    x = q[i]
    if not wp.isfinite(x):
        nan_flag[w] = 1
        speed[i] = wp.nan
        return
    s = wp.length(x - q_prev[i]) / frame_dt
    speed[i] = s
    if s < tol:
        wp.atomic_add(n_below, w, 1)
        wp.atomic_max(below_max, w, s)
    else:
        wp.atomic_min(above_min, w, s)


@wp.kernel
def _decide(
    frame: int,
    min_frames: int,
    max_frames: int,
    q_index: int,
    q_frac: float,
    tol: float,
    start_frame: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    done_frame: wp.array(dtype=wp.int32),
    nan_flag: wp.array(dtype=wp.int32),
    n_below: wp.array(dtype=wp.int32),
    below_max: wp.array(dtype=wp.float32),
    above_min: wp.array(dtype=wp.float32),
    fold_frames: int,
    settled_frame: wp.array(dtype=wp.int32),
    area_fail: wp.array(dtype=wp.int32),
):
    w = wp.tid()
    if status[w] == 0:
        if nan_flag[w] != 0:
            status[w] = 2
            done_frame[w] = frame
        else:
            # numpy's linear quantile of the sorted speeds s: s[f] + frac * (s[f+1] - s[f]), f = q_index.
            # c speeds lie below tol, so s[f] < tol iff c > f and s[f+1] < tol iff c > f + 1.
            c = n_below[w]
            ok = False
            if c >= q_index + 2:
                ok = True
            elif c == q_index + 1:
                a = below_max[w]
                value = a
                if q_frac > 0.0:
                    b = above_min[w]
                    if q_frac >= 0.5:
                        value = b - (b - a) * (1.0 - q_frac)
                    else:
                        value = a + (b - a) * q_frac
                ok = value < tol
            wf = frame - start_frame[w]  # this world's own frame count (worlds are refilled mid-run)
            settled = False
            if wf >= min_frames and ok:
                if settled_frame[w] < 0:
                    settled_frame[w] = frame
                # as `drape`: a face past the D.6 area limits is judged settled again, up to fold_frames later
                settled = area_fail[w] == 0 or frame - settled_frame[w] >= fold_frames
            if settled:
                status[w] = 1
                done_frame[w] = frame
            elif wf >= max_frames:
                status[w] = 3
                done_frame[w] = frame
    nan_flag[w] = 0
    n_below[w] = 0
    below_max[w] = -1.0
    above_min[w] = 3.4e38
    area_fail[w] = 0


@wp.kernel
def _area_fail(
    faces_per_world: int,
    particles_per_world: int,
    min_ratio: float,
    max_ratio: float,
    tri: wp.array(dtype=wp.vec3i),
    rest_area: wp.array(dtype=wp.float32),
    status: wp.array(dtype=wp.int32),
    q: wp.array(dtype=wp.vec3),
    area_fail: wp.array(dtype=wp.int32),
):
    # flags each active world with a face past the D.6 area limits (`check_sample`'s area rule)
    t = wp.tid()
    w = t / faces_per_world
    if status[w] != 0:
        return
    f = t - w * faces_per_world
    base = w * particles_per_world
    i = tri[f]
    a = q[base + i[0]]
    area = 0.5 * wp.length(wp.cross(q[base + i[1]] - a, q[base + i[2]] - a))
    ratio = area / wp.max(rest_area[f], 1.0e-20)
    if ratio < min_ratio or ratio > max_ratio:
        area_fail[w] = 1


@wp.kernel
def _retire(
    frame: int,
    world: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
    done_frame: wp.array(dtype=wp.int32),
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
    q_prev: wp.array(dtype=wp.vec3),
    speed: wp.array(dtype=wp.float32),
    out_q: wp.array(dtype=wp.vec3),
    out_speed: wp.array(dtype=wp.float32),
    pin: wp.array(dtype=wp.vec3),
    flags: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    w = world[i]
    st = status[w]
    if st == 0:
        q_prev[i] = q[i]
        return
    if done_frame[w] == frame:
        out_q[i] = q[i]
        out_speed[i] = speed[i]
        if st == 2:
            # a blown-up world goes back to its last finite frame so no NaN reaches the shared BVHs
            pin[i] = q_prev[i]
            q[i] = q_prev[i]
        else:
            pin[i] = q[i]
        qd[i] = wp.vec3(0.0)
        flags[i] = flags[i] & ~1


@wp.kernel
def _shift(q: wp.array(dtype=wp.vec3), world: wp.array(dtype=wp.int32), offsets: wp.array(dtype=wp.vec3),
           out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = q[i] + offsets[world[i]]


def _world_collision_class():
    """Style3D's cloth self-collision, with each world moved to its own place for the broad phase only."""
    class _WorldCollision(Collision):
        """The BVHs and candidate searches see every world shifted by its offset, so no candidate pair
        crosses worlds; the contact forces then use the true (unshifted) positions, which are bit for
        bit those of a single-world drape of the same pose."""

        def __init__(self, model, world, offsets):
            super().__init__(model)
            self.world = world
            self.offsets = offsets
            self.shifted = wp.zeros(model.particle_count, dtype=wp.vec3, device=model.device)

        def _shifted(self, pos):
            wp.launch(_shift, dim=len(pos), inputs=[pos, self.world, self.offsets], outputs=[self.shifted],
                      device=self.model.device)
            return self.shifted

        def rebuild_bvh(self, pos):
            super().rebuild_bvh(self._shifted(pos))

        def frame_begin(self, particle_q, particle_qd, dt):
            super().frame_begin(self._shifted(particle_q), particle_qd, dt)

    return _WorldCollision


def _world_pcg_class():
    """`PcgSolver` with per-world inner products and step sizes (built lazily: newton imports warp)."""
    class _WorldPcg(PcgSolver):
        """Style3D's PCG, but each world's CG runs on its own: rTz and pTAp are (iterations, K)."""

        def __init__(self, dim, device, particle_world: np.ndarray, n_worlds: int, max_iter: int):
            super().__init__(dim, device, maxIter=max_iter)
            pw = np.asarray(particle_world, dtype=np.int64)
            bounds = np.searchsorted(pw, np.arange(n_worlds + 1))
            begin, end, world_chunk = [], [], [0]
            for k in range(n_worlds):
                starts = np.arange(bounds[k], bounds[k + 1], _CHUNK)
                begin.extend(starts.tolist())
                end.extend(np.minimum(starts + _CHUNK, bounds[k + 1]).tolist())
                world_chunk.append(len(begin))
            self.world = wp.array(pw.astype(np.int32), dtype=wp.int32, device=device)
            self.chunk_begin = wp.array(np.asarray(begin, np.int32), dtype=wp.int32, device=device)
            self.chunk_end = wp.array(np.asarray(end, np.int32), dtype=wp.int32, device=device)
            self.world_chunk = wp.array(np.asarray(world_chunk, np.int32), dtype=wp.int32, device=device)
            self.partial = wp.zeros(len(begin), dtype=wp.float32, device=device)
            self.rTz = wp.zeros((max_iter, n_worlds), dtype=wp.float32, device=device)
            self.pTAp = wp.zeros((max_iter, n_worlds), dtype=wp.float32, device=device)
            self.n_worlds = n_worlds

        def _inner(self, a, b, out, row):
            wp.launch(_chunk_dot, dim=len(self.partial), inputs=[a, b, self.chunk_begin, self.chunk_end],
                      outputs=[self.partial], device=self.device)
            wp.launch(_world_sum, dim=self.n_worlds, inputs=[self.partial, self.world_chunk, row],
                      outputs=[out], device=self.device)

        def step3_update_rTz(self, iter: int):  # noqa: A002 (newton's name)
            self._inner(self.r, self.z, self.rTz, iter)

        def step4_update_p(self, iter: int):  # noqa: A002
            wp.launch(_cg_direction, dim=self.dim, inputs=[iter, self.world, self.z, self.rTz],
                      outputs=[self.p], device=self.device)

        def step6_update_pTAp(self, iter: int):  # noqa: A002
            self._inner(self.p, self.Ap, self.pTAp, iter)

        def step7_update_x_r(self, x, iter: int):  # noqa: A002
            wp.launch(_cg_step, dim=self.dim, inputs=[iter, self.world, self.rTz, self.pTAp, self.p, self.Ap],
                      outputs=[x, self.r], device=self.device)

    return _WorldPcg


class _PartTopology:
    """What `part_meshes` derives from the body's faces and part masks alone, kept so that a new pose
    costs a gather and a few means (`vertices`), not a connected-components search per part. The
    result is bit for bit `part_meshes`'s (same float64 means over the same sorted index sets)."""
    def __init__(self, body_vertices, body_faces, part_masks):
        bf = np.asarray(body_faces, dtype=np.int64)
        self.parts = []
        for (verts, faces), mask in zip(part_meshes(body_vertices, body_faces, part_masks),
                                        np.asarray(part_masks, dtype=bool), strict=True):
            used = np.unique(bf[mask[bf].all(axis=1)])
            n_loops = len(verts) - len(used)
            # the lid faces fan each loop around its centroid vertex n + k: the loop's vertices are the
            # other corners of the faces that use that centroid (what _cap_holes averaged)
            loops = [np.unique(faces[(faces == len(used) + k).any(axis=1)][:, :2]) for k in range(n_loops)]
            self.parts.append((used, loops, faces))

    def meshes(self, body_vertices) -> list[tuple[np.ndarray, np.ndarray]]:
        bv = np.asarray(body_vertices, dtype=np.float64)
        out = []
        for used, loops, faces in self.parts:
            v = bv[used]
            if loops:
                v = np.concatenate([v, np.stack([v[idx].mean(0) for idx in loops])])
            out.append((v.astype(np.float32), faces))
        return out


def world_offsets(n_worlds: int, spacing: float) -> np.ndarray:
    """(K, 3) offsets of K worlds on a square grid in the horizontal (x, z) plane, centred on the origin
    so the largest offset (and float32 rounding of positions) stays small."""
    side = math.ceil(math.sqrt(n_worlds))
    k = np.arange(n_worlds)
    ix, iz = k % side, k // side
    out = np.zeros((n_worlds, 3))
    out[:, 0] = (ix - (side - 1) / 2.0) * spacing
    out[:, 2] = (iz - (side - 1) / 2.0) * spacing
    return out


def _array_bytes(*objs) -> int:
    """Bytes held by the warp arrays that are attributes of objs (one level deep, each array once)."""
    seen, total = set(), 0
    for obj in objs:
        for v in vars(obj).values():
            if isinstance(v, wp.array) and id(v) not in seen:
                seen.add(id(v))
                total += int(v.capacity)
    return total


def _is_out_of_memory(err: BaseException) -> bool:
    msg = str(err).lower()
    return "out of memory" in msg or "failed to allocate" in msg or "cudaerrormemoryallocation" in msg


class BatchedDrape:
    """One newton model holding `n_worlds` copies of a garment; `run` drapes any number of poses in it.

    rest_pattern_triangles (F, 3, 2), faces (F, 3), body_faces (Fb, 3), vertex_part (V,), part_masks
    (P, Vb): as `pbc.sim.drape.drape`. template_start (V, 3) and template_body (Vb, 3): any valid pose
    (the model's arrays do not depend on it; positions and body meshes are replaced by every `run`).
    """
    def __init__(self, rest_pattern_triangles, faces, body_faces, vertex_part, part_masks, cfg, n_worlds: int,
                 template_start, template_body):
        if int(n_worlds) < 1:
            raise ValueError(f"sim.batch_size must be >= 1, got {n_worlds}")
        check_drape_inputs(rest_pattern_triangles, faces, template_start, template_body, body_faces, vertex_part,
                           part_masks)
        self.cfg = cfg
        self.n_worlds = int(n_worlds)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.body_faces = np.asarray(body_faces)
        self.part_masks = np.asarray(part_masks, dtype=bool)
        self.vertex_part = np.asarray(vertex_part, dtype=np.int64)
        start = np.asarray(template_start, dtype=np.float64)
        body = np.asarray(template_body, dtype=np.float64)
        # worlds sit one body-and-cloth extent plus a clear metre apart: far beyond any contact radius
        extent = np.ptp(np.concatenate([start, body]), axis=0).max()
        self.spacing = float(config_value(cfg, "batch_world_spacing") or (extent + 1.0))
        self.offsets = world_offsets(self.n_worlds, self.spacing)
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # newton's precompute prints a ScopedTimer line
            self._build(rest_pattern_triangles, start, body)
        self.build_seconds = time.perf_counter() - t0
        self.bytes_per_world = _array_bytes(self.model, self.solver, self.solver.linear_solver,
                                            self.solver.collision, self.contacts, self) / self.n_worlds

    # --- model ---------------------------------------------------------------------------------------
    def _build(self, rest_pattern_triangles, start, body):
        wp_ = init_warp(config_value(self.cfg, "kernel_cache_dir"))

        cfg = self.cfg
        if int(newton.ParticleFlags.ACTIVE) != _PARTICLE_ACTIVE:
            raise RuntimeError("newton's ParticleFlags changed; the batched drape needs newton==1.8.0")
        device = config_value(cfg, "device") or None
        faces, k = self.faces, self.n_worlds
        friction = float(config_value(cfg, "friction"))
        gravity = wp_.vec3(0.0, -float(config_value(cfg, "gravity")), 0.0)

        # one world's scene, exactly as the single drape builds it, then replicated into K worlds
        self.topology = _PartTopology(body, self.body_faces, self.part_masks)
        part_meshes = self.topology.meshes(body)
        world, _ = scene_builder(rest_pattern_triangles, faces, start, part_meshes, cfg)
        self.n_parts = len(part_meshes)
        self.part_faces = [tris for _, tris in part_meshes]

        builder = newton.ModelBuilder(up_axis=newton.Axis.Y)
        builder.gravity = gravity
        SolverStyle3D.register_custom_attributes(builder)
        builder.replicate(world, k, separate_worlds=True)
        model = builder.finalize(device=device)
        model.soft_contact_ke = float(config_value(cfg, "contact_ke"))
        model.soft_contact_kd = float(config_value(cfg, "contact_kd"))
        model.soft_contact_mu = friction

        n_per = start.shape[0]
        n = model.particle_count
        pw = model.particle_world.numpy()
        if n != k * n_per or not np.array_equal(pw, np.repeat(np.arange(k), n_per)):
            raise RuntimeError("newton laid out the replicated worlds unexpectedly; batching needs newton==1.8.0")
        sw = model.shape_world.numpy()
        if not np.array_equal(sw, np.repeat(np.arange(k), self.n_parts)):
            raise RuntimeError("newton laid out the replicated shapes unexpectedly; needs newton==1.8.0")

        iterations = int(config_value(cfg, "iterations"))
        linear_iterations = int(config_value(cfg, "linear_iterations"))
        solver = SolverStyle3D(model, config=SolverStyle3D.Config(iterations=iterations,
                                                                  linear_iterations=linear_iterations))
        solver.linear_solver = _world_pcg_class()(n, solver.device, pw, k, max(1, linear_iterations))
        world_arr = wp_.array(pw.astype(np.int32), dtype=wp_.int32, device=model.device)
        offsets_arr = wp_.array(self.offsets.astype(np.float32), dtype=wp_.vec3, device=model.device)
        solver.collision = _world_collision_class()(model, world_arr, offsets_arr)
        configure_self_collision(solver.collision, cfg)
        # at most one body contact per particle (one candidate pair each): launch n threads, not 3K * n
        solver.collision.body_contact_max = n

        pipeline = newton.CollisionPipeline(model, soft_contact_gap=float(config_value(cfg, "contact_gap")),
                                            soft_contact_max=n, rigid_contact_max=0)
        if not hasattr(pipeline, "soft_rigid_contact_pairs") or not hasattr(pipeline, "_soft_contact_pair_count"):
            raise RuntimeError("newton's CollisionPipeline changed; per-part contact filtering needs newton==1.8.0")
        shape_of = np.arange(k)[:, None] * self.n_parts + self.vertex_part[None, :]  # (K, V) shape per particle
        pairs = np.stack([np.arange(n), shape_of.reshape(-1)], axis=1).astype(np.int32)
        pipeline.soft_rigid_contact_pairs = wp_.array(pairs, dtype=wp_.vec2i, device=model.device)
        pipeline._soft_contact_pair_count = n

        self.newton, self.model, self.solver, self.pipeline = newton, model, solver, pipeline
        self.contacts = pipeline.contacts()
        self.states = [model.state(), model.state()]
        self.control = model.control()
        self.n_per_world = n_per
        self.flags0 = model.particle_flags.numpy().copy()
        dev = model.device
        self.world = wp_.array(pw.astype(np.int32), dtype=wp_.int32, device=dev)
        self.q_prev = wp_.zeros(n, dtype=wp_.vec3, device=dev)
        self.pin = wp_.zeros(n, dtype=wp_.vec3, device=dev)
        self.out_q = wp_.zeros(n, dtype=wp_.vec3, device=dev)
        self.speed = wp_.zeros(n, dtype=wp_.float32, device=dev)
        self.out_speed = wp_.zeros(n, dtype=wp_.float32, device=dev)
        self.status = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.done_frame = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.start_frame = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.nan_flag = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.n_below = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.below_max = wp_.zeros(k, dtype=wp_.float32, device=dev)
        self.above_min = wp_.zeros(k, dtype=wp_.float32, device=dev)
        self.settled_frame = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.area_fail = wp_.zeros(k, dtype=wp_.int32, device=dev)
        self.tri = wp_.array(faces.astype(np.int32), dtype=wp_.vec3i, device=dev)
        self.rest_area = wp_.array(rest_triangle_areas(rest_pattern_triangles).astype(np.float32), dtype=wp_.float32,
                                   device=dev)
        self._meshes: list = []

    def _set_body(self, k: int, body: np.ndarray) -> None:
        """Fresh part meshes for world k (body (Vb, 3)), built as `build_drape_sim` builds them; the
        model's arrays are written by `_push_bodies`."""
        for p, (verts, tris) in enumerate(self.topology.meshes(body)):
            m = self.newton.Mesh(verts, tris.reshape(-1), compute_inertia=False, is_solid=True)
            j = k * self.n_parts + p
            self._ptrs[j] = m.finalize(device=self.model.device)
            # newton's local AABB of a mesh shape (builder.finalize): the vertex bounds
            v = np.asarray(m.vertices)
            self._lo[j], self._hi[j] = v.min(axis=0), v.max(axis=0)
            self._meshes[j] = m  # keeps the warp mesh alive while its id is in the model

    def _push_bodies(self) -> None:
        self.model.shape_source_ptr.assign(self._ptrs)
        self.model.shape_collision_aabb_lower.assign(self._lo)
        self.model.shape_collision_aabb_upper.assign(self._hi)

    def _start_world(self, k: int, start: np.ndarray, state, frame: int) -> None:
        """Put a new pose into world k at global frame `frame`: positions, zero velocity, active."""
        a, b = k * self.n_per_world, (k + 1) * self.n_per_world
        q = start.astype(np.float32)
        for arr in (state.particle_q, self.q_prev, self.pin):
            arr[a:b].assign(q)
        state.particle_qd[a:b].zero_()
        self.model.particle_flags[a:b].assign(self.flags0[a:b])
        self.settled_frame[k:k + 1].fill_(-1)

    # --- stepping ------------------------------------------------------------------------------------
    def run(self, starts, bodies, on_frame=None) -> list[DrapeResult]:
        """Drape B poses in the K worlds: starts (B, V, 3), bodies (B, Vb, 3) -> B `DrapeResult`s, in order.

        Poses 0..K-1 start in worlds 0..K-1; when a world stops (seen at the host's next look, every
        `sim.batch_check_every` frames) it takes the next waiting pose, so a slow pose holds up one
        world, not the batch. Each result is what `drape` returns for that pose alone, up to rounding:
        positions at the frame its world stopped, its residual over that frame, `iterations` = frames
        it ran. `seconds` and `cpu_seconds` are the batch's shared equally among its B poses.
        `on_frame(frame, state)` (tests, debugging) runs after each frame's solver steps.
        """
        starts = np.asarray(starts, dtype=np.float64)
        bodies = np.asarray(bodies, dtype=np.float64)
        b, k, n_per = len(starts), self.n_worlds, self.n_per_world
        if b == 0:
            return []
        if starts.shape[1:] != (n_per, 3) or bodies.shape[0] != b or not np.all(np.isfinite(starts)):
            raise ValueError(f"starts must be finite (B, {n_per}, 3) and bodies (B, Vb, 3), got "
                             f"{starts.shape} and {bodies.shape}")
        t0, c0 = time.perf_counter(), time.process_time()
        cfg = self.cfg
        model, solver, pipeline, contacts, control = self.model, self.solver, self.pipeline, self.contacts, self.control
        # the first K poses fill the worlds; idle worlds (fewer poses than worlds) hold a frozen copy of
        # pose 0, so everything the physics reads is a function of the batch alone
        first = [j if j < b else 0 for j in range(k)]
        self._ptrs = np.zeros(k * self.n_parts, dtype=np.uint64)
        self._lo = np.zeros((k * self.n_parts, 3), dtype=np.float32)
        self._hi = np.zeros((k * self.n_parts, 3), dtype=np.float32)
        self._meshes = [None] * (k * self.n_parts)
        for w in range(k):
            self._set_body(w, bodies[first[w]])
        self._push_bodies()
        q0 = starts[first].reshape(-1, 3).astype(np.float32)
        flags = self.flags0.reshape(k, n_per).copy()
        flags[b:] &= ~_PARTICLE_ACTIVE
        model.particle_flags.assign(flags.reshape(-1))
        for st in self.states:
            st.particle_q.assign(q0)
            st.particle_qd.zero_()
            st.particle_f.zero_()
        for a in (self.q_prev, self.pin, self.out_q):
            a.assign(q0)
        self.speed.zero_()
        self.out_speed.fill_(float("nan"))
        self.status.assign(np.where(np.arange(k) < b, ACTIVE, IDLE).astype(np.int32))
        self.start_frame.zero_()
        self.settled_frame.fill_(-1)
        self.area_fail.zero_()
        self.done_frame.fill_(-1)
        self.nan_flag.zero_()
        self.n_below.zero_()
        self.below_max.fill_(-1.0)
        self.above_min.fill_(3.4e38)
        s0, s1 = self.states
        solver.rebuild_bvh(s0)

        frame_dt, dt, substeps, tol, min_frames, max_frames, keep, quantile = stepping(cfg)
        h = (n_per - 1) * quantile
        q_index = int(math.floor(h))
        q_frac = float(h - q_index)
        # one world has no other to keep busy: a look every frame stops it at its own frame, not up to 9 later
        # (the results are the same either way: a world's stop frame is decided on the device)
        every = 1 if k == 1 else max(1, int(config_value(cfg, "batch_check_every", 10)))
        fold_frames = int(config_value(cfg, "fold_frames", 0))
        limits = area_limits(cfg)
        n_faces = len(self.faces)
        dev = model.device
        n = model.particle_count
        pose_of = np.array([j if j < b else -1 for j in range(k)])  # the pose each world drapes now
        start_of = np.zeros(k, dtype=np.int64)  # the global frame each world's pose started at
        waiting = list(range(k, b))
        results: list[DrapeResult | None] = [None] * b
        remaining = b
        frame = 0
        while remaining:
            frame += 1
            pipeline.collide(s0, contacts)
            for _ in range(substeps):
                s0.clear_forces()
                solver.step(s0, s1, control, contacts, dt)
                s0, s1 = s1, s0
            if on_frame is not None:
                on_frame(frame, s0)
            wp.launch(_frame_speed, dim=n, device=dev,
                      inputs=[frame_dt, keep, int(keep < 1.0), tol, self.world, self.status, self.pin,
                              s0.particle_q, s0.particle_qd, self.q_prev, self.speed, self.nan_flag,
                              self.n_below, self.below_max, self.above_min])
            if fold_frames > 0:
                wp.launch(_area_fail, dim=k * n_faces, device=dev,
                          inputs=[n_faces, n_per, *limits, self.tri, self.rest_area, self.status, s0.particle_q,
                                  self.area_fail])
            wp.launch(_decide, dim=k, device=dev,
                      inputs=[frame, min_frames, max_frames, q_index, q_frac, tol, self.start_frame, self.status,
                              self.done_frame, self.nan_flag, self.n_below, self.below_max, self.above_min,
                              fold_frames, self.settled_frame, self.area_fail])
            wp.launch(_retire, dim=n, device=dev,
                      inputs=[frame, self.world, self.status, self.done_frame, s0.particle_q, s0.particle_qd,
                              self.q_prev, self.speed, self.out_q, self.out_speed, self.pin, model.particle_flags])
            if frame % every:
                continue
            status = self.status.numpy()
            finished = [w for w in range(k) if pose_of[w] >= 0 and status[w] not in (ACTIVE, IDLE)]
            if not finished:
                continue
            done = self.done_frame.numpy()
            out_q = self.out_q.numpy().reshape(k, n_per, 3)
            out_speed = self.out_speed.numpy().reshape(k, n_per)
            for w in finished:
                results[pose_of[w]] = self._result(status[w], int(done[w] - start_of[w]), out_q[w], out_speed[w],
                                                   quantile)
                remaining -= 1
                pose_of[w] = -1
            status_new = status.copy()
            for w in finished:
                if waiting:
                    j = waiting.pop(0)
                    self._set_body(w, bodies[j])
                    self._start_world(w, starts[j], s0, frame)
                    pose_of[w], start_of[w], status_new[w] = j, frame, ACTIVE
                else:
                    status_new[w] = IDLE
            self._push_bodies()
            self.start_frame.assign(start_of.astype(np.int32))
            self.status.assign(status_new)
        self.states = [s0, s1]
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        for r in results:
            r.seconds, r.cpu_seconds = wall / b, cpu / b
        return results

    @staticmethod
    def _result(status, frames, positions, speed, quantile) -> DrapeResult:
        if status == BLEW_UP or not np.all(np.isfinite(speed)):
            res = res_max = float("nan")
        else:
            res, res_max = float(np.quantile(speed, quantile)), float(speed.max())
        return DrapeResult(positions=np.array(positions, dtype=np.float32), residual=res, residual_max=res_max,
                           iterations=frames, seconds=float("nan"), converged=bool(status == CONVERGED))


def make_batched_drape(rest_pattern_triangles, faces, body_faces, vertex_part, part_masks, cfg, n_worlds,
                       template_start, template_body) -> BatchedDrape:
    """`BatchedDrape` with the asked number of worlds, or fewer when the device runs out of memory.

    Halves K until the model fits and logs what failed (K and the memory per world measured at the
    size that fitted); raises MemoryError naming both when not even one world fits.
    """
    k = int(n_worlds)
    failed = []
    while True:
        try:
            sim = BatchedDrape(rest_pattern_triangles, faces, body_faces, vertex_part, part_masks, cfg, k,
                               template_start, template_body)
        except (RuntimeError, MemoryError) as err:
            if not _is_out_of_memory(err):
                raise
            failed.append(k)
            if k == 1:
                raise MemoryError(
                    f"the device ran out of memory building a batched drape of sim.batch_size={n_worlds} "
                    f"(tried K = {failed}); not even one world fits. Free device memory or set sim.device=cpu"
                ) from err
            k //= 2
            continue
        if failed:
            log.warning("sim.batch_size=%d does not fit the device (out of memory at K=%s); draping %d worlds at "
                        "a time (%.1f MB per world)", n_worlds, failed, k, sim.bytes_per_world / 2**20)
        return sim


def batched_drape_for_garment(garment, body, embedding, cfg, n_worlds, template_start, template_body):
    """`make_batched_drape` for pbc objects (Garment, Body, Embedding: see `drape_garment`)."""
    return make_batched_drape(
        pattern_triangles(as_numpy(garment.uv), as_numpy(garment.face_uv), float(garment.uv_scale)),
        as_numpy(garment.faces), as_numpy(body.faces), as_numpy(embedding.part), as_numpy(body.parts), cfg, n_worlds,
        as_numpy(template_start), as_numpy(template_body),
    )
