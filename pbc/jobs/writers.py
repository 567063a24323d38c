"""What the jobs write of predicted garments: a mesh per frame, a contact sheet of poses, the video of a motion
(a small torch rasteriser, so no GL context is needed) and the animated GLB. Every mesh file goes through
``pbc.geometry.meshio``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pygltflib
import torch
from PIL import Image
from torch import Tensor

from pbc.core.io import (
    atomic_path,
    save_figure,
    write_text,
)
from pbc.geometry.meshio import write_garment_mesh
from pbc.geometry.meshops import vertex_normals

SHEET_COLUMNS = 4


GARMENT_LIFT = 0.02  # m, contact sheet depth bias of the garment over the body


def contact_sheet(path: Path, garment_faces, verts, titles: Sequence[str], body_verts=None, body_faces=None) -> Path:
    """Front views (x-y, depth-sorted, shaded faces) of garments verts (n, V, 3) (on their posed bodies
    (n, Vb, 3) when given), SHEET_COLUMNS per row, one shared frame so sizes compare across panels."""
    import matplotlib  # noqa: PLC0415 - pyplot loads in ~0.5 s; a ClothPredictor never draws a sheet

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - as above: only the contact sheet plots
    from matplotlib.collections import PolyCollection  # noqa: PLC0415 - as above: only the contact sheet plots

    n = len(verts)
    cols = min(n, SHEET_COLUMNS)
    rows = -(-n // cols)
    everything = [np.asarray(verts).reshape(-1, 3)] + ([] if body_verts is None else [np.asarray(body_verts)
                                                                                      .reshape(-1, 3)])
    lo, hi = np.min([e.min(0) for e in everything], 0), np.max([e.max(0) for e in everything], 0)
    pad = 0.04 * float((hi - lo)[:2].max())
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.6 * rows * (hi[1] - lo[1] + 2 * pad)
                                                  / (hi[0] - lo[0] + 2 * pad)), squeeze=False)
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    meshes = [(np.asarray(garment_faces), (0.3, 0.5, 0.9))]
    for k, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if k >= n:
            continue
        layers = [(np.asarray(verts[k]), *meshes[0])]
        if body_verts is not None:
            layers.insert(0, (np.asarray(body_verts[k]), np.asarray(body_faces), (0.8, 0.7, 0.6)))
        tris, colors, depth = [], [], []
        for v, f, base in layers:  # one painter's sort over body and garment together
            tri = v[f]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.linalg.norm(nrm, axis=1, keepdims=True) + 1e-12
            # the garment's inside shows through its openings: both sides drawn, the inside darker
            facing = nrm[:, 2] > 0
            shade = np.where(facing, 0.35 + 0.65 * np.clip(nrm @ light, 0, 1), 0.3)
            if f is not layers[-1][1]:  # the body: its back faces are hidden behind its front ones
                tri, shade = tri[facing], shade[facing]
            tris.append(tri)
            colors.append(np.clip(np.asarray(base)[None] * shade[:, None], 0, 1))
            # the cloth lies a few mm off the skin: sorted as if GARMENT_LIFT nearer, so coarse body
            # triangles do not poke through it, while an arm in front of the shirt still covers it
            depth.append(tri[:, :, 2].mean(1) + (GARMENT_LIFT if f is layers[-1][1] else 0.0))
        tri, col = np.concatenate(tris), np.concatenate(colors)
        order = np.argsort(np.concatenate(depth))
        # edges drawn in the face colour close the hairline gaps between neighbouring polygons
        ax.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=col[order], edgecolors=col[order],
                                         linewidths=0.3))
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_title(titles[k], fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


VIDEO_FORMATS = ("mp4", "gif")


BLOCK = 16  # the H.264 macro block: video sides are multiples of it


# barycentric lattice sizes (steps an edge) a face is sampled with: ~1.25x apart, so at most that many more
# steps than needed (the points grow as its square)
LATTICE_STEPS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32, 40, 48, 64, 80, 96, 128)


class FrameObjWriter:
    """OBJ per frame with the garment's UVs and normals (meshio's layout), formatting only what moves."""

    def __init__(self, garment, first: Path, vertices, header: Sequence[str] = ()):
        # the first frame through meshio itself: its text gives the static blocks, in meshio's exact format
        write_garment_mesh(first, garment, vertices, header=header)
        lines = first.read_text().split("\n")
        kinds = [ln.split(" ", 1)[0] for ln in lines]
        self.head = [ln for ln, k in zip(lines, kinds, strict=True) if k == "#"][:1]  # meshio's own first line
        self.vt = "\n".join(ln for ln, k in zip(lines, kinds, strict=True) if k == "vt")
        first_face = next(i for i, k in enumerate(kinds) if k in ("g", "f"))
        self.tail = "\n".join(lines[first_face:])
        self.faces = np.asarray(garment.faces)
        self.num = len(np.asarray(garment.vertices))

    def text(self, vertices, header: Sequence[str] = ()) -> str:
        v = np.asarray(vertices, dtype=np.float64)
        n = vertex_normals(v, self.faces)
        # one %-format over the whole block: ~30x faster than a line at a time (meshio's obj_text)
        vs = ("v %.6f %.6f %.6f\n" * self.num) % tuple(v.ravel().tolist())
        ns = ("vn %.6f %.6f %.6f\n" * self.num) % tuple(n.ravel().tolist())
        head = "\n".join(self.head + [f"# {h}" for h in header])
        return f"{head}\n{vs}{self.vt}\n{ns}{self.tail}"

    def write(self, path: Path, vertices, header: Sequence[str] = ()) -> None:
        write_text(path, self.text(vertices, header))


def camera(points: Tensor, height: int, margin: float) -> tuple[float, float, float, int, int]:
    """A fixed front camera over points (..., 3): (x0, y1, metres per pixel, H, W), sides multiples of 16."""
    p = points.reshape(-1, 3)
    lo, hi = p.min(0).values, p.max(0).values
    ext = (hi - lo)[:2]
    pad = margin * float(ext.max())
    h = max(BLOCK, int(round(height / BLOCK)) * BLOCK)
    scale = (float(ext[1]) + 2 * pad) / h
    w = max(BLOCK, int(np.ceil((float(ext[0]) + 2 * pad) / scale / BLOCK)) * BLOCK)
    x0 = float(lo[0] + hi[0]) / 2 - w * scale / 2
    return x0, float(hi[1]) + pad, scale, h, w


def render_frames(layers: Sequence[tuple[Tensor, Tensor, Sequence[float], float, bool]], cam, light,
                  background) -> np.ndarray:
    """Rasterise B frames at once -> (B, H, W, 3) uint8.

    layers: (vertices (B, V, 3), faces (F, 3), rgb, depth lift (m, the garment over the skin), closed: back
    faces culled (a closed body) or drawn darker (the garment's inside)); cam from `camera`. Each face
    covers the pixels its lattice points fall in (`_splat`; a face longer than 106 pixels may show gaps), the
    nearest face (largest z) wins (scatter amax z-buffer); flat Lambert shading."""
    x0, y1, s, H, W = cam
    light = torch.tensor(light, dtype=torch.float32)
    light = light / light.norm()
    B = layers[0][0].shape[0]
    tris, cols, frame = [], [], []
    for verts, faces, rgb, lift, closed in layers:
        t = verts.float()[:, faces.long()]  # (B, F, 3, 3)
        n = torch.linalg.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0])
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        front = n[..., 2] > 0
        shade = torch.where(front, 0.35 + 0.65 * (n @ light).clamp(0, 1), torch.full_like(n[..., 2], 0.3))
        keep = front if closed else torch.ones_like(front)
        px = torch.stack([(t[..., 0] - x0) / s, (y1 - t[..., 1]) / s, t[..., 2] + lift], -1)
        b_idx = torch.arange(B)[:, None].expand_as(keep)
        tris.append(px[keep])
        cols.append(torch.tensor(rgb, dtype=torch.float32) * shade[keep][:, None])
        frame.append(b_idx[keep])
    tri, col, fr = torch.cat(tris), torch.cat(cols), torch.cat(frame)  # (N, 3, 3), (N, 3), (N,)
    # each face is sampled on a barycentric lattice of n steps an edge, n >= 1.2 x its longest edge in pixels:
    # lattice points lie <= 0.83 px apart, so every pixel centre inside the face has one within 0.48 px
    # (0.83 / sqrt 3), in its own pixel: no holes. Faces are bucketed by n so each bucket is one batched product.
    edge = torch.stack([(tri[:, k, :2] - tri[:, (k + 1) % 3, :2]).norm(dim=-1) for k in range(3)], -1).amax(-1)
    need = (1.2 * edge).ceil().clamp(1, LATTICE_STEPS[-1])
    bucket = torch.bucketize(need, torch.tensor(LATTICE_STEPS, dtype=need.dtype))
    flats, zs, faces = [], [], []
    for b, n in enumerate(LATTICE_STEPS):
        sel = (bucket == b).nonzero().flatten()
        if len(sel):
            f, z, face = _splat(tri[sel], fr[sel], n, H, W)
            flats.append(f)
            zs.append(z)
            faces.append(sel[face])
    flat, z, face = torch.cat(flats), torch.cat(zs), torch.cat(faces)
    zbuf = torch.full((B * H * W,), -float("inf")).scatter_reduce_(0, flat, z, "amax")
    win = (z >= zbuf[flat]).nonzero().flatten()
    img = torch.tensor(background, dtype=torch.float32).repeat(B * H * W, 1)
    img[flat[win]] = col[face[win]]
    return (img.reshape(B, H, W, 3).clamp(0, 1) * 255).round().to(torch.uint8).numpy()


def _splat(tri: Tensor, fr: Tensor, n: int, H: int, W: int) -> tuple[Tensor, Tensor, Tensor]:
    """Faces tri (N, 3, 3) (x, y in pixels, depth) of frames fr (N,) sampled at the P = (n+1)(n+2)/2 points of
    their barycentric lattice: (flat pixel index into (B, H, W), depth, face index into tri), each (N*P,)."""
    i, j = torch.meshgrid(torch.arange(n + 1), torch.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep].float() / n, j[keep].float() / n
    bary = torch.stack([1 - i - j, i, j], 1)  # (P, 3)
    pts = torch.einsum("pk,nkc->ncp", bary, tri)  # (N, 3, P)
    # the camera sees every vertex (`camera`), so a point leaves the image only by rounding: clamped, not tested
    x, y = pts[:, 0].floor_().clamp_(0, W - 1).long(), pts[:, 1].floor_().clamp_(0, H - 1).long()
    flat = (fr[:, None] * H + y) * W + x
    face = torch.arange(len(tri))[:, None].expand_as(flat)
    return flat.reshape(-1), pts[:, 2].reshape(-1), face.reshape(-1)


class VideoWriter:
    """Frames -> path (.mp4: H.264 through imageio-ffmpeg; .gif: Pillow), written atomically on close."""

    def __init__(self, path: Path, fps: float, crf: int = 23):
        self.path, self.fps, self.crf = Path(path), float(fps), int(crf)
        fmt = self.path.suffix.lstrip(".").lower()
        if fmt not in VIDEO_FORMATS:
            raise ValueError(f"{path}: unknown video format {fmt!r}; write one of {VIDEO_FORMATS}")
        self._atomic = atomic_path(self.path)
        self.tmp = self._atomic.__enter__()
        self.gif: list[Image.Image] = []
        self.mp4 = None
        if fmt == "mp4":
            self.mp4 = imageio.get_writer(self.tmp, format="FFMPEG", fps=self.fps, codec="libx264", quality=None,
                                          ffmpeg_params=["-crf", str(self.crf)], pixelformat="yuv420p",
                                          macro_block_size=BLOCK, ffmpeg_log_level="error")

    def append(self, frames: np.ndarray) -> None:
        """frames (B, H, W, 3) uint8."""
        for f in frames:
            if self.mp4 is not None:
                self.mp4.append_data(f)
            else:
                self.gif.append(Image.fromarray(f).quantize(64))

    def close(self, error: BaseException | None = None) -> None:
        try:
            if self.mp4 is not None:
                self.mp4.close()
            elif error is None:
                self.gif[0].save(self.tmp, format="GIF", save_all=True, append_images=self.gif[1:],
                                 duration=int(round(1000 / self.fps)), loop=0)
        finally:
            exc = (type(error), error, error.__traceback__) if error is not None else (None, None, None)
            self._atomic.__exit__(*exc)


def garment_gltf_vertices(garment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The garment's vertices split where its UV charts meet (glTF holds one UV per vertex): (vertex id per
    glTF vertex (G,), its UV (G, 2) in glTF's convention (atlas as the OBJ: front u in [0, 0.5], back in
    [0.5, 1]; v = 0 at the top), faces into them (F, 3))."""
    faces = np.asarray(garment.faces, dtype=np.int64)
    fuv = np.asarray(garment.face_uv, dtype=np.int64)
    uv, side = np.asarray(garment.uv, dtype=np.float64), np.asarray(garment.face_side, dtype=np.int64)
    uv_side = np.zeros(len(uv), dtype=np.int64)
    uv_side[fuv.reshape(-1)] = np.repeat(side, 3)
    atlas = np.stack([(uv[:, 0] + uv_side) / 2, uv[:, 1]], 1)
    pairs = np.stack([faces.reshape(-1), fuv.reshape(-1)], 1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    return uniq[:, 0], atlas[uniq[:, 1]].astype(np.float32), inv.reshape(-1, 3)


def write_glb(path: Path, garment, verts: np.ndarray, times: np.ndarray) -> Path:
    """The garment's frames verts (N, V, 3) (metres) at `times` (N,) seconds as an animated GLB: base shape =
    frame 0, one POSITION morph target per frame (its offset from frame 0), a LINEAR weights animation
    taking target k to 1 at times[k]."""
    ids, uv, faces = garment_gltf_vertices(garment)
    v = np.asarray(verts, dtype=np.float32)[:, ids]  # (N, G, 3)
    N, G = v.shape[:2]
    base = v[0]
    deltas = v - base[None]
    weights = np.eye(N, dtype=np.float32)
    blobs: list[bytes] = []
    views, accessors = [], []

    def add(arr: np.ndarray, kind: str, component: int, target: int | None = None, minmax: bool = False) -> int:
        offset = sum(len(b) for b in blobs)
        data = np.ascontiguousarray(arr).tobytes()
        blobs.append(data + b"\0" * (-len(data) % 4))
        views.append(pygltflib.BufferView(buffer=0, byteOffset=offset, byteLength=len(data), target=target))
        count = len(arr) if kind != "SCALAR" or arr.ndim == 1 else arr.size
        acc = pygltflib.Accessor(bufferView=len(views) - 1, componentType=component, count=int(count), type=kind)
        if minmax:
            acc.min, acc.max = arr.reshape(count, -1).min(0).tolist(), arr.reshape(count, -1).max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    pos = add(base, "VEC3", pygltflib.FLOAT, pygltflib.ARRAY_BUFFER, minmax=True)
    tex = add(uv, "VEC2", pygltflib.FLOAT, pygltflib.ARRAY_BUFFER)
    idx = add(faces.astype(np.uint32).reshape(-1), "SCALAR", pygltflib.UNSIGNED_INT, pygltflib.ELEMENT_ARRAY_BUFFER)
    targets = [pygltflib.Attributes(POSITION=add(deltas[k], "VEC3", pygltflib.FLOAT, pygltflib.ARRAY_BUFFER,
                                                 minmax=True)) for k in range(N)]
    t_in = add(np.asarray(times, dtype=np.float32), "SCALAR", pygltflib.FLOAT, minmax=True)
    w_out = add(weights.reshape(-1), "SCALAR", pygltflib.FLOAT)
    prim = pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=pos, TEXCOORD_0=tex), indices=idx,
                               targets=targets, material=0)
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(generator="pbc.motion", version="2.0"), scene=0,
        scenes=[pygltflib.Scene(nodes=[0])], nodes=[pygltflib.Node(name="garment", mesh=0)],
        meshes=[pygltflib.Mesh(name="garment", primitives=[prim], weights=[0.0] * N)],
        materials=[pygltflib.Material(name="garment", doubleSided=True, pbrMetallicRoughness=pygltflib.
                                      PbrMetallicRoughness(baseColorFactor=[0.3, 0.5, 0.9, 1.0]))],
        animations=[pygltflib.Animation(name="motion", samplers=[pygltflib.AnimationSampler(
            input=t_in, output=w_out, interpolation="LINEAR")], channels=[pygltflib.AnimationChannel(
                sampler=0, target=pygltflib.AnimationChannelTarget(node=0, path="weights"))])],
        accessors=accessors, bufferViews=views)
    blob = b"".join(blobs)
    gltf.buffers = [pygltflib.Buffer(byteLength=len(blob))]
    gltf.set_binary_blob(blob)
    with atomic_path(path) as tmp:
        gltf.save_binary(str(tmp))
    return Path(path)
