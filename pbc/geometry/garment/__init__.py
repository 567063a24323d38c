"""Garments through one door: ``garment_from_config(cfg.garment, body)`` builds the kind the config names
(``BUILDERS``, keyed by ``garment_kind``): the paper's T-shirt, the necktie (appendix F), the skirt and the
trousers (sized to the body's legs), a user's OBJ, or MakeHuman clothes (``.mhclo``) fitted to Anny.

The garment type and pbc's own garment file live in ``base``; one module per kind (``tshirt``, ``necktie``,
``lowerbody``) or importer (``obj_import``, ``mhclo``); the pattern helpers they share in ``patterns``; the
pre-drape checks in ``checks``; garments sized to a body in ``sizing``; outfits in ``outfit``. This module
sits above them all (none of them imports the door).

    pbc cage garment=obj garment.obj=my.obj garment.uv_unit=cm --out patches/my.json
        writes the automatic cage of a garment as editable JSON (patches/ format)
"""

from __future__ import annotations

from pathlib import Path

from pbc.core.paths import resolve_path
from pbc.geometry.body.base import Body
from pbc.geometry.cage.auto import auto_cage
from pbc.geometry.cage.base import Cage, load_cage
from pbc.geometry.garment.base import Garment, garment_kind, is_pbc_obj, load_garment_obj
from pbc.geometry.garment.lowerbody import make_lower_body
from pbc.geometry.garment.mhclo import mhclo_garment
from pbc.geometry.garment.necktie import make_necktie
from pbc.geometry.garment.obj_import import garment_from_mesh, import_garment
from pbc.geometry.garment.placement import placed_mesh
from pbc.geometry.garment.sizing import is_sized_to_body, sized_config
from pbc.geometry.garment.tshirt import make_tshirt


def load_any_obj(path, **options) -> Garment:
    """A garment OBJ of any origin: a file pbc wrote is read exactly (`load_garment_obj`), any other goes
    through the importer with ``options`` (charts, uv_unit, position_unit, position_offset, uv_padding)."""
    path = Path(path)
    return load_garment_obj(path) if is_pbc_obj(path) else import_garment(path, **options)[0]


def obj_options(gcfg) -> dict:
    """The import options of a user's garment OBJ from its config node (conf/garment/obj.yaml)."""
    out = {}
    for key in ("uv_unit", "position_unit", "uv_padding", "uv_unit_tolerance"):
        if gcfg.get(key) is not None and not (key == "position_unit" and gcfg[key] == "auto"):
            out[key] = gcfg[key]
    if gcfg.get("position_offset") is not None:
        out["position_offset"] = tuple(float(x) for x in gcfg.position_offset)
    if gcfg.get("charts") is not None:
        out["charts"] = {str(k): int(v) for k, v in dict(gcfg.charts).items()}
    return out


# the garments worn on the legs: sized to the body's legs, always built with the body
LEG_KINDS = ("skirt", "trousers")


def garment_needs_body(gcfg) -> bool:
    """Whether `garment_from_config` needs the body for this garment config (its sizes come from the body)."""
    placed = garment_kind(gcfg) == "obj" and bool((gcfg.get("placement") or {}).get("enabled", False))
    return placed or is_sized_to_body(gcfg) or garment_kind(gcfg) in ("mhclo", *LEG_KINDS)


def _with_cage(garment: Garment, gcfg, names=None, charts=None) -> tuple[Garment, Cage]:
    """A garment read from a file with its cage: the cage file ``garment.cage``, or, when it is ``auto`` / null,
    the automatic cage (pbc.geometry.cage.auto) of its charts."""
    image = (int(gcfg.patch_resolution), int(gcfg.crop_size), int(gcfg.margin))
    cage_path = gcfg.get("cage", None)
    if cage_path is None or str(cage_path) == "auto":
        return garment, auto_cage(garment, *image, chart_names=names, face_chart=charts,
                                  **dict(gcfg.get("autocage") or {}))
    try:
        return garment, load_cage(resolve_path(cage_path), garment, *image)
    except ValueError as exc:
        if "made for a garment of" not in str(exc):
            raise
        garment_file = f" (garment {gcfg.obj})" if gcfg.get("obj") else ""
        raise ValueError(f"{exc}: the cage file {cage_path} belongs to another garment{garment_file}; pass this "
                         "garment's "
                         "cage (garment.cage=...) or make one (garment=obj, or garment.cage=auto)") from None


def _from_obj(gcfg, body: Body | None) -> tuple[Garment, Cage]:
    """A user's OBJ: pbc's own files read exactly, others placed on the body (pbc.geometry.garment.placement)
    and imported with obj_options."""
    if is_pbc_obj(path := resolve_path(gcfg.obj)):
        return _with_cage(load_garment_obj(path), gcfg)
    mesh, _ = placed_mesh(path, gcfg, body)
    options = {k: v for k, v in obj_options(gcfg).items() if k not in ("position_unit", "position_offset")}
    garment, names, charts = garment_from_mesh(mesh, str(path), **options)
    return _with_cage(garment, gcfg, names, charts)


def _from_mhclo(gcfg, body: Body | None) -> tuple[Garment, Cage]:
    """MakeHuman clothes fitted to the body (pbc.geometry.garment.mhclo)."""
    garment, names, charts, _ = mhclo_garment(gcfg, body, obj_options(gcfg))
    return _with_cage(garment, gcfg, names, charts)


def _on_legs(gcfg, body: Body | None) -> tuple[Garment, Cage]:
    if body is None:
        raise ValueError(f"garment.kind={gcfg.kind} is sized to the body's legs: build it with the body "
                         "(garment_from_config(gcfg, body))")
    return make_lower_body(gcfg, body)


# garment kind -> builder (gcfg, body) -> (garment, cage)
BUILDERS = {
    "tshirt": lambda gcfg, body: make_tshirt(gcfg),
    "necktie": lambda gcfg, body: make_necktie(gcfg),
    **dict.fromkeys(LEG_KINDS, _on_legs),
    "obj": _from_obj,
    "mhclo": _from_mhclo,
}


def garment_from_config(gcfg, body: Body | None = None) -> tuple[Garment, Cage]:
    """The garment and its cage through one door, from the garment config node (and the body it is worn on,
    needed when `garment_needs_body(gcfg)`: a garment sized to the body, pbc.geometry.garment.sizing; the
    skirt and trousers; MakeHuman clothes). The builder is ``BUILDERS[garment_kind(gcfg)]``."""
    kind = garment_kind(gcfg)
    if kind not in BUILDERS:
        raise ValueError(f"garment.kind={kind!r} is not a garment pbc builds; use one of {', '.join(BUILDERS)} "
                         "(or garment.obj=PATH for a garment file)")
    if is_sized_to_body(gcfg):
        if body is None:
            raise ValueError("garment.size_to_body.enabled=true sizes the garment to the body: build it with the "
                             "body (garment_from_config(gcfg, body))")
        gcfg = sized_config(gcfg, body)
    return BUILDERS[kind](gcfg, body)
