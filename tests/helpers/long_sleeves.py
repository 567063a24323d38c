"""Long-sleeved tops as a MakeHuman asset would hand them over, for tests (made here, never fetched): pbc's
procedural shirt sized to the body, its sleeves long enough to reach the wrist, posed onto the body's rest arms
the way a modeller's rig poses a T-pose garment (each sleeve turned at the shoulder onto the upper arm and at the
elbow onto the forearm, the turn blended in over a few centimetres as skinning weights blend), written as
MakeClothes writes clothes (tests/helpers/mhclo_assets.py): an `.obj` in decimetres with one [0, 1] UV atlas and
a `.mhclo` binding every vertex to the base mesh.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from helpers.mhclo_assets import bind_to_tights, write_mhclo_for_obj
from pbc.core.config import load_config
from pbc.geometry.body.base import Body
from pbc.geometry.body.skeleton import limb_segments
from pbc.geometry.garment import garment_from_config
from pbc.geometry.garment.sizing import sized_config
from pbc.geometry.garment.tshirt import make_tshirt

BLEND = 0.06  # m along the sleeve over which each turn is blended in (shoulder, elbow)
CUFF_PAST_WRIST = 0.0  # m the sleeve reaches past the wrist joint


def _turn(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Axis (3,) and angle of the rotation taking unit vector a onto unit vector b."""
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    return (axis / s if s > 1e-12 else np.array([0.0, 0.0, 1.0])), float(np.arctan2(s, a @ b))


def _rotate(p: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: points p (N, 3) about axis (3,) by angle (N,)."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return p * c + np.cross(axis, p) * s + axis * (p @ axis)[:, None] * (1 - c)


def _ramp(t: np.ndarray) -> np.ndarray:
    """0 before -BLEND/2, 1 after +BLEND/2, smooth in between."""
    x = np.clip(t / BLEND + 0.5, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def long_sleeve_shirt(body: Body, garment: str = "tshirt_coarse", cuff: float = 1.0):
    """(positions (V, 3) m, faces (F, 3), uv atlas (T, 2) in [0, 1], face_uv (F, 3)): the shirt sized to `body`,
    sleeves to the wrists, narrowed to `cuff` times their width at the wrist (1: the short sleeve's opening all the
    way, a bell sleeve), posed onto the body's rest arms (any rest pose: T or A)."""
    gcfg = load_config([f"garment={garment}", "garment.size_to_body.enabled=true"]).garment
    sk = body.skeleton
    heads = sk.rest_heads.double().numpy()
    shoulder, elbow, wrist = (heads[sk.index(f"l_{j}")] for j in ("arm", "forearm", "hand"))
    upper, fore = np.linalg.norm(elbow - shoulder), np.linalg.norm(wrist - elbow)
    sized = sized_config(gcfg, body)
    half = 0.25 * float(sized.chest_girth) + float(sized.chest_ease)  # the panel's half width: the side seam
    sized.sleeve_length = float(shoulder[0] + upper + fore + CUFF_PAST_WRIST - half)
    g, _ = make_tshirt(sized)
    p = g.vertices.double().numpy().copy()
    for sgn in (1.0, -1.0):
        j = heads[[sk.index(f"{'l' if sgn > 0 else 'r'}_{n}") for n in ("arm", "forearm")]]
        s, e = j[0], j[1]
        underarm = float(sized.shoulder_height) - 0.5 * float(sized.sleeve_opening)
        # the sleeve, and the panel's shoulder above the underarm out from the shoulder joint
        sel = (sgn * p[:, 0] > half) | ((sgn * p[:, 0] > abs(s[0])) & (p[:, 1] > underarm))
        t = sgn * p[sel, 0] - abs(s[0])  # along the T-pose sleeve from the shoulder joint
        if cuff != 1.0:  # about the T-pose sleeve's axis, from the side seam (1) to the wrist (cuff)
            axis_yz = np.array([float(sized.shoulder_height), float(sized.center_z)])
            k = 1.0 + (cuff - 1.0) * np.clip((sgn * p[sel, 0] - half) / (abs(s[0]) + upper + fore - half), 0.0, 1.0)
            p[np.ix_(np.flatnonzero(sel), [1, 2])] = axis_yz + k[:, None] * (p[sel][:, [1, 2]] - axis_yz)
        out = np.array([sgn, 0.0, 0.0])
        d1 = (e - s) / np.linalg.norm(e - s)
        w = heads[sk.index(f"{'l' if sgn > 0 else 'r'}_hand")]
        d2 = (w - e) / np.linalg.norm(w - e)
        a1, th1 = _turn(out, d1)
        a2, th2 = _turn(d1, d2)
        centre = np.array([s[0], float(sized.shoulder_height), s[2]])
        q = centre + _rotate(p[sel] - centre, a1, th1 * _ramp(t - 0.5 * BLEND))
        knee = centre + d1 * upper  # the elbow on the posed sleeve's axis
        q = knee + _rotate(q - knee, a2, th2 * _ramp(t - upper))
        p[sel] = q
    return p, g.faces.numpy(), *_sleeve_charts(g, half)


def _sleeve_charts(g, half: float) -> tuple[np.ndarray, np.ndarray]:
    """One [0, 1] atlas (T', 2), v up, and face_uv (F, 3) in which each sleeve half (front, back) is its own
    chart, cut from its panel at the side seam (|x| = half in the T-pose), as a tailor's pattern has them."""
    uv, fuv = g.uv.double().numpy(), g.face_uv.numpy()
    x = g.vertices.double().numpy()[g.faces.numpy()].mean(1)[:, 0]
    region = np.where(x > half, 1, np.where(x < -half, 2, 0))  # torso, left sleeve, right sleeve
    chart = 3 * g.face_side.numpy() + region  # (F,) six charts
    keys = chart[:, None] * len(uv) + fuv  # a uv corner per (chart, pattern point)
    uniq, new_fuv = np.unique(keys.ravel(), return_inverse=True)
    c, t = uniq // len(uv), uniq % len(uv)
    out = uv[t].copy()
    for k in range(6):  # each chart in its own cell of a 3 x 2 grid, one common scale
        sel = c == k
        out[sel] = 0.3 * (out[sel] - out[sel].min(0)) + np.array([(k % 3) / 3 + 0.01, (k // 3) / 2 + 0.01])
    out[:, 1] = 1.0 - out[:, 1]  # v up, as files have it
    return out, new_fuv.reshape(-1, 3)


def obj_text(p: np.ndarray, faces: np.ndarray, uv: np.ndarray, face_uv: np.ndarray, unit: float = 0.1,
             header: str = "# MakeClothes") -> str:
    """The OBJ as a MakeHuman asset: positions in `unit` metres (decimetres), one atlas, no groups."""
    lines = [header, "mtllib blouse.mtl", "o blouse"]
    lines += [f"v {x / unit:.6f} {y / unit:.6f} {z / unit:.6f}" for x, y, z in p]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += ["usemtl cloth", "s off"]
    lines += ["f " + " ".join(f"{a + 1}/{b + 1}" for a, b in zip(f, t, strict=True))
              for f, t in zip(faces, face_uv, strict=True)]
    return "\n".join(lines) + "\n"


def bent_elbow_blouse_obj(body: Body, cuff: float = 0.55) -> str:
    """A long-sleeved blouse modelled on `body`'s rest (Anny's own A-pose: its elbows bent forward), its sleeves
    narrowing to the wrist, as a pattern tool exports it: metres in the body's frame, one [0, 1] atlas."""
    p, f, uv, fuv = long_sleeve_shirt(body, "tshirt", cuff=cuff)
    return obj_text(p, f, uv, fuv, unit=1.0, header="# Marvelous Designer export, Anny avatar in its own A-pose")


def cape_sleeves(p: np.ndarray, f: np.ndarray, uv: np.ndarray, fuv: np.ndarray, body: Body, min_reach: float = 0.36):
    """The shirt with each sleeve's back half cut away (the faces beyond ``min_reach`` m from the midplane behind
    the arm's bones): cloth lying along the arms that closes round neither, a cape's flaps. Unused vertices and
    uvs dropped; the same tuple."""
    sk = body.skeleton
    centre = p[f].mean(1)
    back = np.zeros(len(f), bool)
    for side in ("l", "r"):
        segs = limb_segments(sk, f"{side}_arm")
        a, b = segs[:, 0], segs[:, 1]
        t = np.clip(np.einsum("nsk,sk->ns", centre[:, None] - a[None], b - a) / ((b - a) ** 2).sum(1), 0, 1)
        q = a[None] + t[..., None] * (b - a)[None]
        k = np.linalg.norm(centre[:, None] - q, axis=2).argmin(1)
        behind = centre[:, 2] < q[np.arange(len(f)), k, 2]
        sgn = 1.0 if side == "l" else -1.0
        back |= (sgn * centre[:, 0] > min_reach) & behind
    f, fuv = f[~back], fuv[~back]
    used, remap = np.unique(f, return_inverse=True)
    tused, tremap = np.unique(fuv, return_inverse=True)
    return p[used], remap.reshape(-1, 3), uv[tused], tremap.reshape(-1, 3)


COLLAR_REACH = 0.06  # m from the neckline the folded collar covers
CUFF_REACH = 0.06  # m from each sleeve's hem the turned-back cuff covers


def collar_and_cuffs(p: np.ndarray, f: np.ndarray, uv: np.ndarray, fuv: np.ndarray, body: Body, gap: float = 0.006):
    """The shirt with a folded collar and two turned-back cuffs lying on it, as a modeller makes them: pieces of
    their own (the shirt's faces reaching within COLLAR_REACH of the neckline and CUFF_REACH of each sleeve's hem,
    copied `gap` m out along the shirt's normals, away from the body), each in charts of its own. The atlas is scaled by
    one half (the shirt's aspect and relative size kept) and the pieces' charts packed beside it.
    -> the same tuple with the pieces appended, and a (V',) mask of the pieces' vertices."""
    from pbc.data.mirror import surface_points  # noqa: PLC0415 - a test helper's one closest-point query
    from pbc.geometry.meshops import boundary_loops  # noqa: PLC0415

    loops = boundary_loops(f)
    neck = max(loops, key=lambda lp: p[lp, 1].mean())
    hems = [max(loops, key=lambda lp: p[lp, 0].mean()), min(loops, key=lambda lp: p[lp, 0].mean())]
    near = np.zeros(len(p), bool)
    for loop, reach in ((neck, COLLAR_REACH), *((h, CUFF_REACH) for h in hems)):
        near |= np.linalg.norm(p[:, None] - p[loop][None], axis=2).min(1) < reach
    sel = near[f].any(1)
    used, remap = np.unique(f[sel], return_inverse=True)
    normals = trimesh.Trimesh(p, f, process=False).vertex_normals[used]
    _, tri, w = surface_points(p[used], body.vertices.double().numpy(), body.faces.numpy())
    on_body = np.einsum("nk,nkd->nd", w, body.vertices.double().numpy()[body.faces.numpy()[tri]])
    normals *= np.sign(np.einsum("nd,nd->n", normals, p[used] - on_body))[:, None]  # away from the body
    piece = p[used] + gap * normals
    tused, tremap = np.unique(fuv[sel], return_inverse=True)
    atlas = 0.5 * uv
    piece_uv = 0.5 * uv[tused] + np.array([0.5, 0.0])  # the pieces' charts beside the shirt's, same scale
    faces = np.concatenate([f, len(p) + remap.reshape(-1, 3)])
    face_uv = np.concatenate([fuv, len(uv) + tremap.reshape(-1, 3)])
    mask = np.concatenate([np.zeros(len(p), bool), np.ones(len(used), bool)])
    return np.concatenate([p, piece]), faces, np.concatenate([atlas, piece_uv]), face_uv, mask


def long_sleeve_mhclo(folder, body: Body, base: np.ndarray, garment: str = "tshirt_coarse", cape: bool = False,
                      layers: bool = False) -> Path:
    """The long-sleeved shirt as MakeHuman clothes bound to `base` (the MakeHuman base mesh (N, 3) of the body,
    metres, pbc's frame): `blouse.obj` and `blouse.mhclo` in folder; the .mhclo's path. ``cape``: its sleeves cut
    open into flaps (`cape_sleeves`); ``layers``: a folded collar and turned-back cuffs on it (`collar_and_cuffs`)."""
    p, f, uv, fuv = long_sleeve_shirt(body, garment)
    if cape:
        p, f, uv, fuv = cape_sleeves(p, f, uv, fuv, body)
    if layers:
        p, f, uv, fuv, _ = collar_and_cuffs(p, f, uv, fuv, body)
    refs, w, o = bind_to_tights(p, base)
    return write_mhclo_for_obj(folder, obj_text(p, f, uv, fuv), refs, w, o, "blouse")


def trousers_mhclo(folder, body: Body, base: np.ndarray) -> Path:
    """pbc's trousers sized to `body` as MakeHuman clothes (`trousers.obj` in decimetres with its atlas scaled into
    [0, 1], `trousers.mhclo` bound to `base`); the .mhclo's path."""
    gcfg = load_config(["garment=trousers"]).garment
    g, _ = garment_from_config(gcfg, body)
    uv, fuv, side = g.uv.double().numpy(), g.face_uv.numpy(), g.face_side.numpy()
    keys = side[:, None] * len(uv) + fuv  # front and back: charts of their own, side by side in one atlas
    uniq, new_fuv = np.unique(keys.ravel(), return_inverse=True)
    atlas = uv[uniq % len(uv)] + np.array([1.05, 0.0]) * (uniq // len(uv))[:, None]
    atlas = (atlas - atlas.min(0)) / float((atlas.max(0) - atlas.min(0)).max()) * 0.98 + 0.01  # one scale
    p = g.vertices.double().numpy()
    refs, w, o = bind_to_tights(p, base)
    return write_mhclo_for_obj(folder, obj_text(p, g.faces.numpy(), atlas, new_fuv.reshape(-1, 3)), refs, w, o,
                               "trousers")
