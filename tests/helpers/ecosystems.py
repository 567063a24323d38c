"""Garments written as other ecosystems write them, for tests (made here, never fetched): pbc's procedural
shirt re-exported the way each tool would hand it over.

- `smpl_top_obj`: a long-sleeve top modelled on a SMPL T-pose body in SMPL's frame (metres, the body's feet at
  y = -1.1, so its collar sits 25 cm lower than on pbc's bodies), quads, a `.mtl` that is not there, `usemtl`;
- `pattern_tee_obj`: a tee from a sewing-pattern generator exported by Maya: centimetres at 3x life size, UVs in
  pattern units from about -160 to 189, `vn` lines, CRLF line ends, and 142 vertices used by no face;
- `no_uv_shirt_obj`: a mannequin garment from a neural cloth simulator: metres, the mannequin's feet at y = 0,
  triangles with no `vt` at all;
- `a_pose_shirt_obj`: the MakeHuman-style shirt as an OBJ in decimetres with its sleeves 40 degrees down
  (tests/helpers/a_pose.py);
- `anny_tee_obj`: a short-sleeved tee modelled on T-posed Anny in Anny's own frame (metres), UVs its pattern in
  centimetres, as a pattern tool exports it: it sits on A-posed Anny but for its straight-out sleeves.
"""

from __future__ import annotations

import numpy as np

from helpers.a_pose import outfit_obj
from pbc.core.config import load_config
from pbc.geometry.body import body_from_config
from pbc.geometry.garment import garment_from_config
from pbc.geometry.garment.tshirt import make_tshirt

# where each file puts pbc's shirt (its collar made for the mannequin, neck joint at y = 0.46 m): SMPL's
# T-posed neck sits about 0.25 m lower in SMPL's frame; a mannequin standing on y = 0 puts it 1.0 m higher
SMPL_SHIFT = (0.0, -0.25, 0.0)
FLOOR_SHIFT = (0.0, 1.0, 0.0)
LOOSE = 142


def shirt(garment: str = "tshirt_coarse", *overrides: str):
    """pbc's procedural shirt: (positions (V, 3) m, faces (F, 3), uv (T, 2) pattern m, face_uv (F, 3))."""
    g, _ = make_tshirt(load_config([f"garment={garment}", *overrides]).garment)
    return (g.vertices.double().numpy(), g.faces.numpy(), g.pattern().double().numpy().reshape(-1, 2),
            np.arange(3 * len(g.faces)).reshape(-1, 3))


def _v(points, scale=1.0, shift=(0.0, 0.0, 0.0)) -> list[str]:
    q = (np.asarray(points) + np.asarray(shift)) * scale
    return [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in q]


def smpl_top_obj(garment: str = "tshirt_coarse") -> str:
    """The long-sleeve T-pose top in SMPL's frame; pairs of triangles written as quads where they share an
    edge in the same UV order (as Blender exports a quad mesh)."""
    p, f, uv, fuv = shirt(garment, "garment.sleeve_length=0.45", "garment.cage=null")
    lines = ["# Blender 3.6 export, SMPL T-pose frame (metres)", "mtllib top.mtl", "o LongSleeveTop",
             *_v(p, 1.0, SMPL_SHIFT)]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += ["usemtl Fabric", "s off"]
    k = 0
    while k < len(f):  # consecutive triangles (a, b, c), (a, c, d) of one grid cell -> the quad (a, b, c, d)
        a, b = f[k], f[k + 1] if k + 1 < len(f) else None
        if b is not None and b[0] == a[0] and b[1] == a[2]:
            ids = [a[0], a[1], a[2], b[2]]
            ts = [fuv[k][0], fuv[k][1], fuv[k][2], fuv[k + 1][2]]
            k += 2
        else:
            ids, ts = list(a), list(fuv[k])
            k += 1
        lines.append("f " + " ".join(f"{i + 1}/{t + 1}" for i, t in zip(ids, ts, strict=True)))
    return "\n".join(lines) + "\n"


def pattern_tee_obj(garment: str = "tshirt_coarse") -> str:
    """The pattern generator's tee: 3x life size in centimetres, UVs in its pattern units, loose vertices."""
    p, f, uv, fuv = shirt(garment)
    pattern = uv * 300.0 * np.array([1.0, -1.0]) + np.array([-160.0, 189.0])  # v up, the generator's origin
    rng = np.random.default_rng(0)
    loose = rng.uniform(-60.0, 60.0, (LOOSE, 3))  # construction points a pattern tool leaves in the file
    lines = ["# Maya 2024 OBJ export", "mtllib tee.mtl", "g tee", *_v(p, 300.0), *_v(loose)]
    lines += [f"vt {u:.4f} {v:.4f}" for u, v in pattern]
    normals = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    lines += [f"vn {a:.4f} {b:.4f} {c:.4f}" for a, b, c in normals]
    lines += ["usemtl lambert2SG"]
    lines += ["f " + " ".join(f"{i + 1}/{t + 1}/{i + 1}" for i, t in zip(a, b, strict=True))
              for a, b in zip(f, fuv, strict=True)]
    return "\r\n".join(lines) + "\r\n"


def no_uv_shirt_obj(garment: str = "tshirt_coarse") -> str:
    """The simulator's shirt: metres, feet at y = 0, faces `f a b c` with no texture coordinates."""
    p, f, _, _ = shirt(garment)
    lines = ["# exported by a neural cloth simulator", *_v(p, 1.0, FLOOR_SHIFT)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    return "\n".join(lines) + "\n"


def a_pose_shirt_obj(garment: str = "tshirt_coarse") -> str:
    """The decimetre A-pose shirt (sleeves 40 degrees down), one [0, 1] atlas, no groups."""
    return outfit_obj(40.0, trousers=False, unit=0.1, garment=garment)


def _pattern_tool_obj(g, header: str, name: str) -> str:
    """A pbc Garment as a pattern tool (CLO, Marvelous Designer) exports it: metres as placed, UVs the pattern
    pieces in centimetres (the back piece beside the front), `o`, `g front` / `g back`, triangles `f v/vt`."""
    p, f, side = g.vertices.double().numpy(), g.faces.numpy(), g.face_side.numpy()
    corners = 100.0 * g.pattern().double().numpy()  # (F, 3, 2) cm
    corners[side == 1, :, 0] += 1.2 * np.ptp(corners[..., 0])  # the back piece laid out beside the front
    lines = [header, f"o {name}", *_v(p)]
    lines += [f"vt {u:.4f} {v:.4f}" for u, v in corners.reshape(-1, 2)]
    for group, s in (("front", 0), ("back", 1)):
        lines.append(f"g {group}")
        lines += [f"f {a + 1}/{3 * k + 1} {b + 1}/{3 * k + 2} {c + 1}/{3 * k + 3}"
                  for k, (a, b, c) in enumerate(f) if side[k] == s]
    return "\n".join(lines) + "\n"


def anny_tee_obj(garment: str = "tshirt_coarse") -> str:
    """pbc's shirt sized to T-posed Anny, as a pattern tool exports it (`_pattern_tool_obj`), in Anny's frame."""
    cfg = load_config(["body=anny_tpose", f"garment={garment}", "garment.size_to_body.enabled=true"])
    g, _ = garment_from_config(cfg.garment, body_from_config(cfg.body))
    return _pattern_tool_obj(g, "# Marvelous Designer export, Anny T-pose avatar (metres; UVs: pattern cm)", "Tee")


def legs_apart_trousers_obj(legs_apart_deg: float = 15.0) -> str:
    """pbc's trousers made on Anny with each thigh turned `legs_apart_deg` outward, as a pattern tool exports them
    (`_pattern_tool_obj`), in Anny's frame: trousers modelled on a wider stance."""
    cfg = load_config(["data=trousers_anny", f"body.rest.legs_apart_deg={legs_apart_deg}"])
    g, _ = garment_from_config(cfg.garment, body_from_config(cfg.body))
    return _pattern_tool_obj(g, "# Marvelous Designer export, Anny avatar, legs apart (metres; UVs: pattern cm)",
                             "Trousers")


ECOSYSTEMS = {"smpl_top": smpl_top_obj, "pattern_tee": pattern_tee_obj, "no_uv_shirt": no_uv_shirt_obj,
              "a_pose_shirt": a_pose_shirt_obj, "anny_tee": anny_tee_obj}
