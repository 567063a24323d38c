"""Joint limits from a file over the body config's own (`+body.limits_file=NAME_OR_FILE`): a limits file (layout of
conf/body's `joints`: `- {name: l_arm, limits: {x: [lo, hi], y: [lo, hi], z: [lo, hi]}}`, e.g. the limits
`pbc motion limits` measures from motion, conf/body/limits/anny_cmu.yaml) replaces the limits of each joint it
lists, axis by axis; every other joint, and every other key, keeps the body config's value. Without the key the
body config is used as it is. Degrees, relative to the body's bind rest pose, as the body config's own limits
(a turned rest re-expresses both alike: pbc.geometry.body.anny.rested_limits)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import yaml
from omegaconf import DictConfig, OmegaConf

from pbc.core.paths import CONF_DIR
from pbc.geometry.body.skeleton import AXES

LIMITS_KEY = "limits_file"
LIMITS_DIR = CONF_DIR / "body" / "limits"
LAYOUT = ("a limits file is YAML: 'joints:', a list of {name: JOINT, limits: {x: [lo, hi], y: [lo, hi], z: [lo, hi]}} "
          "in degrees, as conf/body/limits/anny_cmu.yaml")


def limits_path(name_or_path: str | Path) -> Path:
    """A shipped limits file by name (conf/body/limits/<name>.yaml) or a .yaml path (a relative one from the
    current folder); one ValueError naming the shipped files when there is none."""
    p = Path(str(name_or_path))
    if p.suffix not in (".yaml", ".yml"):
        p = LIMITS_DIR / f"{name_or_path}.yaml"
    if not p.is_file():
        shipped = ", ".join(sorted(f.stem for f in LIMITS_DIR.glob("*.yaml"))) or "none"
        raise ValueError(f"body.{LIMITS_KEY}={name_or_path}: no such limits file; give a .yaml file "
                         f"(`pbc motion limits CLIPS --out FILE.yaml` writes one) or a shipped one ({shipped})")
    return p


def read_limits_file(name_or_path: str | Path) -> dict[str, dict[str, list[float]]]:
    """{joint: {axis: [lo, hi]}} of a limits file (`limits_path`), checked: one ValueError naming the file, the
    row and `LAYOUT`."""
    p = limits_path(name_or_path)
    try:
        node = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ValueError(f"body.{LIMITS_KEY}: {p} is not YAML ({type(e).__name__}); {LAYOUT}") from None
    rows = node.get("joints") if isinstance(node, dict) else None
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"body.{LIMITS_KEY}: {p} has no 'joints:' list; {LAYOUT}")
    table: dict[str, dict[str, list[float]]] = {}
    for i, row in enumerate(rows):
        lim = row.get("limits") if isinstance(row, dict) else None
        name = row.get("name") if isinstance(row, dict) else None
        if not isinstance(name, str) or not isinstance(lim, dict) or not lim or set(lim) - set(AXES):
            raise ValueError(f"body.{LIMITS_KEY}: {p} joints[{i}] = {row!r}; {LAYOUT}")
        axes = {}
        for a, pair in lim.items():
            ok = (isinstance(pair, list) and len(pair) == 2
                  and all(isinstance(v, int | float) and not isinstance(v, bool) for v in pair))
            if not ok or pair[0] > pair[1]:
                raise ValueError(f"body.{LIMITS_KEY}: {p} joint {name!r} axis {a}: {pair!r} is not [min, max] "
                                 f"degrees with min <= max; {LAYOUT}")
            axes[a] = [float(pair[0]), float(pair[1])]
        if name in table:
            raise ValueError(f"body.{LIMITS_KEY}: {p} lists joint {name!r} twice; keep one row per joint")
        table[name] = axes
    return table


def merged_limits(cfg, table: Mapping[str, Mapping[str, list[float]]], where: str = "the limits file") -> DictConfig:
    """The body config `cfg` with each joint of `table` ({joint: {axis: [lo, hi]}}) given those limits, axis by
    axis. One ValueError naming the joints the body lacks."""
    plain = OmegaConf.to_container(cfg, resolve=True) if OmegaConf.is_config(cfg) else dict(cfg)
    names = [str(j["name"]) for j in plain["joints"]]
    unknown = [n for n in table if n not in names]
    if unknown:
        raise ValueError(f"body.{LIMITS_KEY}: {where} names joints {unknown} that body.kind="
                         f"{plain.get('kind', 'mannequin')!r} lacks (its joints: {names}); measure limits on this "
                         "body (pbc motion limits --body) or drop those rows")
    for joint in plain["joints"]:
        if joint["name"] in table:
            joint["limits"] = {**joint["limits"], **{a: list(v) for a, v in table[joint["name"]].items()}}
    return OmegaConf.create(plain)


def with_limits_file(cfg):
    """`cfg` with the limits of its `limits_file` merged over its joints' (`merged_limits`); `cfg` itself when it
    names none."""
    name = cfg.get(LIMITS_KEY)
    if name is None:
        return cfg
    return merged_limits(cfg, read_limits_file(name), str(limits_path(name)))


def resolved_limits(cfg) -> dict[str, dict[str, list[float]]]:
    """{joint: {axis: [lo, hi]}} the body config's joints end with, its limits file merged (`with_limits_file`)."""
    plain = with_limits_file(cfg)
    return {str(j["name"]): {a: [float(v) for v in j["limits"][a]] for a in AXES} for j in plain["joints"]}
