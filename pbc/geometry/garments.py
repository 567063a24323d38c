"""The garments a config can name, through one door: the procedural T-shirt, the necktie (appendix F),
or a user's OBJ with its cage file or the automatic cage.

One job: choose and build. The garment data and pbc's own OBJ format live in `garment.py`, other
tools' OBJ files in `obj_import.py`, the automatic cage in `autocage.py`, the tie in `necktie.py`;
this module sits above them all (so none of them imports another's door).

    pbc cage garment=obj garment.obj=my.obj garment.uv_unit=cm --out patches/my.json
        writes the automatic cage of a garment as editable JSON (patches/ format)
"""

from __future__ import annotations

from pathlib import Path

from pbc.geometry.autocage import auto_cage
from pbc.geometry.body import Body
from pbc.geometry.cage import Cage, load_cage
from pbc.geometry.garment import Garment, _is_pbc_obj, load_garment_obj, make_tshirt
from pbc.geometry.lowerbody import BUILDERS as LOWER_BODY
from pbc.geometry.lowerbody import make_lower_body
from pbc.geometry.mhclo import mhclo_garment
from pbc.geometry.necktie import make_necktie
from pbc.geometry.obj_import import import_garment
from pbc.geometry.sizing import fits_to_body, fitted_config
from pbc.paths import resolve_path


def load_any_obj(path, **options) -> Garment:
    """A garment OBJ of any origin: a file pbc wrote is read exactly (`load_garment_obj`), any other goes
    through the importer with ``options`` (charts, uv_unit, position_unit, position_offset, uv_padding)."""
    path = Path(path)
    return load_garment_obj(path) if _is_pbc_obj(path) else import_garment(path, **options)[0]


def obj_options(gcfg) -> dict:
    """The import options of a user's garment OBJ from its config node (conf/garment/obj.yaml)."""
    out = {}
    for key in ("uv_unit", "position_unit", "uv_padding", "uv_unit_tolerance"):
        if gcfg.get(key) is not None:
            out[key] = gcfg[key]
    if gcfg.get("position_offset") is not None:
        out["position_offset"] = tuple(float(x) for x in gcfg.position_offset)
    if gcfg.get("charts") is not None:
        out["charts"] = {str(k): int(v) for k, v in dict(gcfg.charts).items()}
    return out


def garment_needs_body(gcfg) -> bool:
    """Whether `garment_from_config` needs the body for this garment config (its sizes come from the body)."""
    lower_body = not gcfg.get("obj") and gcfg.get("kind") in LOWER_BODY  # the skirt, the trousers
    return fits_to_body(gcfg) or gcfg.get("kind") == "mhclo" or lower_body


def garment_from_config(gcfg, body: Body | None = None) -> tuple[Garment, Cage]:
    """The garment and its cage through one door, from the garment config node (and the body it is worn on,
    needed when `garment_needs_body(gcfg)`: a procedural garment sized to the body, pbc.geometry.sizing).

    ``obj`` set: a user's OBJ (pbc's own files read exactly, others imported with obj_options) with
    the cage file ``cage``, or, when ``cage`` is ``auto`` / null, the automatic cage
    (pbc.geometry.autocage). ``kind: mhclo``: MakeHuman clothes (``path``: the .mhclo) fitted to the Anny
    body, with a cage the same way. ``kind: necktie``: the procedural necktie. Otherwise the T-shirt.
    """
    if fits_to_body(gcfg):
        if body is None:
            raise ValueError("garment.fit_to_body.enabled=true sizes the garment to the body: build it with the "
                             "body (garment_from_config(gcfg, body))")
        gcfg = fitted_config(gcfg, body)
    image = (int(gcfg.patch_resolution), int(gcfg.crop_size), int(gcfg.margin))
    cage_path = gcfg.get("cage", None)
    auto = cage_path is None or str(cage_path) == "auto"
    if gcfg.get("obj") or gcfg.get("kind") == "mhclo":
        names = charts = None
        if gcfg.get("kind") == "mhclo":  # MakeHuman clothes fitted to the body (pbc.geometry.mhclo)
            garment, names, charts, _ = mhclo_garment(gcfg, body, obj_options(gcfg))
        elif _is_pbc_obj(path := resolve_path(gcfg.obj)):
            garment = load_garment_obj(path)
        else:
            garment, names, charts = import_garment(path, **obj_options(gcfg))
        if auto:
            return garment, auto_cage(garment, *image, chart_names=names, face_chart=charts,
                                      **dict(gcfg.get("autocage") or {}))
        try:
            return garment, load_cage(resolve_path(cage_path), garment, *image)
        except ValueError as exc:
            if "made for a garment of" not in str(exc):
                raise
            raise ValueError(f"{exc}: the cage file {cage_path} belongs to another garment; pass this garment's "
                             "cage (garment.cage=...) or make one (garment=obj, or garment.cage=auto)") from None
    if gcfg.get("kind") == "necktie":
        return make_necktie(gcfg)
    if gcfg.get("kind") in LOWER_BODY:  # the skirt, the trousers: always sized to the body (its legs)
        if body is None:
            raise ValueError(f"garment.kind={gcfg.kind} is sized to the body's legs: build it with the body "
                             "(garment_from_config(gcfg, body))")
        return make_lower_body(gcfg, body)
    return make_tshirt(gcfg)
