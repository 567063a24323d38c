"""Left/right mirroring (`data.mirror`): a training pose's mirror image and its drape's mirror image as one
more training sample, with no new drape, where body and garment are symmetric about the body's mid-plane.

The mirror is S = diag(-1, 1, 1) in the root frame (x is the body's left, conf/body). Joint j turns about
its rest head by W_j = F_j R_j F_j^T in root axes (pbc.geometry.body.skeleton.forward_kinematics); its
mirror joint m(j) (the one whose rest head is S h_j) takes W'_m = S W_j S, so the mirrored pose is
R'_m = F_m^T S F_j R_j F_j^T S F_m, a rotation (a conjugation by an orthogonal matrix).

The mirrored drape: garment vertex k takes S x, where x is the drape at the point of the garment's surface
that is vertex k's mirror image at rest (a triangle and barycentric weights). A mesh whose vertices are
symmetric maps vertex to vertex (the coarse shirt); one meshed a little unevenly still maps onto its surface
(pbc's full shirt: 18 of its 3,153 vertices lie 2-12 mm from a mirrored vertex, but every mirror image lies
within 8.2 mm of its surface, 0.08 mm on average).

What is checked before any drape, each against `data.mirror_tolerance` (m): the joints (every rest head has
a mirror head, parents map onto parents), the garment (every rest vertex's mirror image lies on its
surface) and the body (the mirror of the body posed by a pose lies on the body posed by the mirrored pose,
for the rest pose and a few of the dataset's poses: the mesh, the skinning and the skeleton at once).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from pbc.geometry.body.base import Body, pose_body
from pbc.geometry.body.skeleton import Skeleton

MIRROR = np.diag([-1.0, 1.0, 1.0])
CANDIDATES = 8  # nearest-centroid triangles searched for a closest surface point


@dataclass(frozen=True)
class MirrorMap:
    """What mirroring a sample needs."""

    joints: np.ndarray  # (J,) int64: joint j's mirror joint
    pose_conj: np.ndarray  # (J, 3, 3) Q_j = F_m^T S F_j, m = joints[j]: R'_m = Q_j R_j Q_j^T
    tri: np.ndarray  # (V, 3) int64: the garment vertices of the triangle holding vertex k's mirror image
    bary: np.ndarray  # (V, 3) its barycentric weights
    stats: dict  # the measured asymmetries, metres (recorded in the manifest)


def mirror_joints(skel: Skeleton, tol: float) -> np.ndarray:
    """(J,) int64: the joint whose rest head is joint j's mirrored (within `tol` m), parents onto parents.
    Raises ValueError naming the first joint without one."""
    heads = skel.rest_heads.double().numpy()
    dist, m = cKDTree(heads).query(heads @ MIRROR)
    for j, name in enumerate(skel.names):
        par, mpar = skel.parents[j], skel.parents[m[j]]
        if dist[j] > tol or m[m[j]] != j or (mpar != (m[par] if par >= 0 else -1)):
            raise ValueError(
                f"data.mirror=true: the body's skeleton is not left/right symmetric: joint {name!r} at "
                f"{np.round(heads[j], 4).tolist()} has no mirror joint (nearest {skel.names[m[j]]!r}, "
                f"{dist[j] * 1000:.1f} mm off the mirror point; data.mirror_tolerance={tol}); set data.mirror=false")
    return m.astype(np.int64)


def joints_mirror_map(skel: Skeleton, tol: float) -> MirrorMap:
    """The joints' part of a mirror map (`mirror_joints`, the pose conjugations), enough for `mirror_poses`; its
    garment part is empty (no drape to mirror)."""
    m = mirror_joints(skel, tol)
    frames = skel.frames().double().numpy()
    conj = np.swapaxes(frames[m], -1, -2) @ MIRROR @ frames  # Q_j = F_m^T S F_j
    return MirrorMap(m, conj, np.zeros((0, 3), np.int64), np.zeros((0, 3)), {})


def mirror_poses(poses: np.ndarray, mm: MirrorMap) -> np.ndarray:
    """poses (N, J, 3, 3) -> their mirror images (N, J, 3, 3), same dtype."""
    p = np.asarray(poses, np.float64)
    out = np.empty_like(p)
    q = mm.pose_conj
    out[:, mm.joints] = q @ p @ np.swapaxes(q, -1, -2)
    return out.astype(np.asarray(poses).dtype)


def mirror_verts(verts: np.ndarray, mm: MirrorMap) -> np.ndarray:
    """Draped garments (N, V, 3) -> the drapes of the mirrored poses (N, V, 3), same dtype."""
    v = np.asarray(verts, np.float64)
    at = np.einsum("nkcd,kc->nkd", v[:, mm.tri], mm.bary)  # the drape at each vertex's mirror point
    return (at @ MIRROR).astype(np.asarray(verts).dtype)


def symmetrised(points: np.ndarray, rest_vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """points (V, 3) of a garment whose rest vertices (V, 3) are left/right symmetric, made symmetric: the
    mean of each vertex and its mirror vertex's mirror image (the rest shape's own mirror map). A drape of a
    symmetric pose is symmetric but for its folds' rounding; a rest shape kept so lets `mirror_map` hold."""
    rest = np.asarray(rest_vertices, np.float64)
    f = np.asarray(faces, np.int64)
    _, tri, bary = surface_points(rest @ MIRROR, rest, f)
    x = np.asarray(points, np.float64)
    mirrored = np.einsum("kcd,kc->kd", x[f[tri]], bary) @ MIRROR
    return 0.5 * (x + mirrored)


def surface_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of a triangle mesh to points (P, 3): distance (P,), triangle (P,) and barycentric
    weights (P, 3), among the CANDIDATES triangles with the nearest centroids."""
    pts = np.asarray(points, np.float64)
    tris = np.asarray(vertices, np.float64)[faces]  # (F, 3, 3)
    k = min(CANDIDATES, len(tris))
    _, cand = cKDTree(tris.mean(1)).query(pts, k=k)
    cand = np.asarray(cand).reshape(len(pts), k)
    cp = trimesh.triangles.closest_point(tris[cand.ravel()], np.repeat(pts, k, 0)).reshape(len(pts), k, 3)
    d = np.linalg.norm(cp - pts[:, None], axis=2)
    best = d.argmin(1)
    rows = np.arange(len(pts))
    tri = cand[rows, best]
    bary = trimesh.triangles.points_to_barycentric(tris[tri], cp[rows, best])
    return d[rows, best], tri, bary


def _body_gap(body: Body, poses: np.ndarray, mirrored: np.ndarray) -> float:
    """Largest distance (m) of the mirror of the body posed by poses[i] from the body posed by mirrored[i]."""
    faces = body.faces.cpu().numpy()
    with torch.no_grad():
        a = pose_body(body, torch.from_numpy(np.asarray(poses, np.float32))).double().numpy()
        b = pose_body(body, torch.from_numpy(np.asarray(mirrored, np.float32))).double().numpy()
    return max(float(surface_points(a[i] @ MIRROR, b[i], faces)[0].max()) for i in range(len(a)))


def mirror_map(bodies: list[Body], garment_vertices: np.ndarray, garment_faces: np.ndarray, tol: float,
               probe_poses: np.ndarray, where: str = "the garment") -> MirrorMap:
    """The mirror map of a scene, checked: joints, garment (V, 3) rest vertices and faces (F, 3), and each
    body posed by the rest pose and probe_poses (P, J, 3, 3) against their mirrors. One ValueError naming
    what is asymmetric, by how much, and the fix (data.mirror=false)."""
    if not tol > 0:
        raise ValueError(f"data.mirror_tolerance={tol}: give a distance in metres > 0, e.g. 0.005")
    skel = bodies[0].skeleton
    joints = joints_mirror_map(skel, tol)
    m, conj = joints.joints, joints.pose_conj
    gv = np.asarray(garment_vertices, np.float64)
    gf = np.asarray(garment_faces, np.int64)
    gap, tri, bary = surface_points(gv @ MIRROR, gv, gf)
    worst = int(gap.argmax())
    if gap[worst] > tol:
        raise ValueError(
            f"data.mirror=true: {where} is not left/right symmetric: the mirror image of its vertex {worst} at "
            f"{np.round(gv[worst], 4).tolist()} lies {gap[worst] * 1000:.1f} mm off its surface "
            f"({int((gap > tol).sum())} of {len(gv)} vertices beyond data.mirror_tolerance={tol} m); mirrored drapes "
            "would be wrong: set data.mirror=false (or raise data.mirror_tolerance for a garment meshed unevenly)")
    mm = MirrorMap(m, conj, gf[tri], bary, {})
    eye = np.tile(np.eye(3), (1, skel.num_joints, 1, 1))
    probes = np.concatenate([eye, np.asarray(probe_poses, np.float64)])
    mirrored = mirror_poses(probes, mm)
    body_gap = 0.0
    for k, body in enumerate(bodies):
        g = _body_gap(body, probes, mirrored)
        body_gap = max(body_gap, g)
        if g > tol:
            who = "the body" if len(bodies) == 1 else f"person {k} of data.body_shape"
            raise ValueError(
                f"data.mirror=true: {who} is not left/right symmetric: posed by a pose and by its mirror, the two "
                f"bodies differ by up to {g * 1000:.1f} mm (data.mirror_tolerance={tol} m; the mesh, its skinning or "
                "its skeleton); set data.mirror=false")
    stats = {"garment_gap_max_m": float(gap.max()), "garment_gap_mean_m": float(gap.mean()),
             "body_gap_max_m": body_gap, "probe_poses": int(len(probes))}
    return MirrorMap(m, conj, gf[tri], bary, stats)
