"""Length units: the one table of named units, a stated unit read from the config, and the UV unit a
pattern's area implies (measured against the 3D area, named where it matches a named unit)."""

from __future__ import annotations

import numpy as np

# metres per unit of each length unit a config may name; "inch" is a second spelling of "in", so a measured
# scale is named by the first name of its value
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "in": 0.0254, "inch": 0.0254}


def uv_unit_from_areas(area_3d: float, area_uv: float) -> float:
    """Metres per UV unit that makes the pattern's area equal the 3D area."""
    return float(np.sqrt(area_3d / max(area_uv, 1e-30)))


def name_unit(metres: float, tolerance: float = 1.25) -> str:
    """The config value of a scale in metres per UV unit: a named unit within ``tolerance`` x, else the number."""
    for name, m in UNITS.items():
        if max(metres / m, m / metres) <= tolerance:
            return name
    return f"{metres:.4g}"


def check_uv_unit(stated: float, area_3d: float, area_uv: float, unit_text: str, tolerance: float,
                  where: str, uv_range: float | None = None) -> None:
    """Refuse a stated UV unit whose pattern area disagrees with the 3D area by more than ``tolerance`` x.

    stated: metres per UV unit; area_3d (m^2) / area_uv (UV units^2): the whole garment's. The draped
    cloth's area is its pattern's (a cloth barely stretches), so a unit that makes them disagree by 2x
    is a wrong unit, which would otherwise surface minutes later as every drape discarded (area_stretched).
    """
    ratio = area_3d / max(stated * stated * area_uv, 1e-30)
    if max(ratio, 1.0 / max(ratio, 1e-30)) <= tolerance:
        return
    fit = uv_unit_from_areas(area_3d, area_uv)
    atlas = uv_range is not None and uv_range <= 1.0
    span = "" if uv_range is None else f" (the UVs span {uv_range:.3g} units{', a [0, 1] atlas' if atlas else ''})"
    fits = name_unit(fit)
    hint = "auto" if uv_range is not None and uv_range <= 1.0 else fits
    raise ValueError(
        f"{where}: garment.uv_unit={unit_text} makes the flat pattern {1.0 / ratio:.3g}x the garment's 3D area "
        f"(pattern {stated * stated * area_uv:.4g} m^2 vs 3D {area_3d:.4g} m^2{span}); the unit that fits is "
        f"{fit:.4g} m per UV unit: set garment.uv_unit={hint}"
        + (f" (or {fits})" if hint != fits else "")
        + f" (more than garment.uv_unit_tolerance = {tolerance:g}x off)")


def metres_per_unit(unit, what: str) -> float:
    """A stated unit (``m``/``cm``/``mm``/``in`` or metres per unit as a number) -> metres per unit."""
    if isinstance(unit, int | float) and not isinstance(unit, bool):
        if unit <= 0:
            raise ValueError(f"{what}: must be positive metres per unit, got {unit}")
        return float(unit)
    if str(unit) in UNITS:
        return UNITS[str(unit)]
    raise ValueError(f"{what}: unknown unit {unit!r}; use one of {sorted(UNITS)}, 'auto' (uv only), "
                     "or metres per unit as a number")
