"""`pbc cage [garment overrides] --out FILE`: a garment's automatic cage as an editable JSON (the patches/
format), compared with the garment config's own cage file when it has one.

    pbc cage garment=obj garment.obj=my.obj garment.uv_unit=cm --out patches/my.json
    pbc cage garment=tshirt --out /tmp/tshirt_auto.json
    pbc cage body=anny garment=mhclo garment.path=shirt.mhclo --out patches/shirt.json   # MakeHuman clothes
    pbc cage --regenerate conf/garment/tshirt.yaml conf/garment/tshirt_coarse.yaml   # the committed cages
"""

from __future__ import annotations

import argparse

from pbc.cli.errors import entry_point
from pbc.core.config import load_config, load_garment_config
from pbc.core.paths import resolve_path
from pbc.data.generate import made_on_body
from pbc.geometry.cage.auto import auto_cage, cage_summary
from pbc.geometry.cage.base import load_cage, save_cage
from pbc.geometry.garment import garment_from_config, garment_needs_body
from pbc.geometry.garment.tshirt import write_tshirt_cage


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc cage", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. garment=obj garment.obj=my.obj")
    ap.add_argument("--out", help="where to write the automatic cage JSON")
    ap.add_argument("--regenerate", nargs="+", metavar="GARMENT_YAML",
                    help="rewrite the committed cage JSON of these procedural-shirt garment configs instead")
    args = ap.parse_args(argv)
    if args.regenerate:
        for path in args.regenerate:
            print(f"{path}: wrote {write_tshirt_cage(load_garment_config(path))}")
        return 0
    if not args.out:
        ap.error("give --out FILE (or --regenerate GARMENT_YAML ...)")
    cfg = load_config(args.overrides)
    gcfg = cfg.garment
    body = made_on_body(cfg) if garment_needs_body(gcfg) else None  # its vertex ids: the garment as made
    image = (int(gcfg.patch_resolution), int(gcfg.crop_size), int(gcfg.margin))
    own = gcfg.get("cage")
    gcfg.cage = "auto"
    if gcfg.get("obj") or gcfg.get("kind") in ("necktie", "mhclo"):
        garment, cage = garment_from_config(gcfg, body)
    else:  # the procedural shirt: its mesh with the automatic cage
        garment, _ = garment_from_config(gcfg, body)
        cage = auto_cage(garment, *image)
    save_cage(cage, args.out, garment.num_vertices)
    print(f"wrote {args.out}: automatic cage {cage_summary(cage)}")
    if own and str(own) != "auto" and body is None and resolve_path(own).exists():
        print(f"{own}: {cage_summary(load_cage(resolve_path(own), garment, *image))}")
    return 0


main = entry_point("cage", run)

if __name__ == "__main__":
    main()
