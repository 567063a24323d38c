"""`pbc garment inspect|split|fit`: what a garment OBJ is before anything is draped, an outfit in one mesh
cut into its pieces, and a garment file to a trained model in one command.

    pbc garment inspect my.obj|my.mhclo [garment.position_unit=dm garment.uv_unit=cm body=...] [--out DIR]
        one table of charts (id, name, centroid, facing, 3D and UV area, the uv_unit that fits, distance to
        the body, shrink-wrap stretch), the sleeves against the body's rest arms, the settings to paste;
        --out writes uv_layout.png, on_body.png and fitted.obj (the garment as placed on the rest body)
    pbc garment split outfit.obj --out DIR [--position-unit dm]
        one OBJ per connected piece (top.obj, bottom.obj, ...), named by where it sits on the body
    pbc garment fit my.obj|my.mhclo [overrides] [--out DIR] [--budget 60m] [--samples N] [--epochs E]
                    [--motion-frames M] [--until STEP]
        inspect, the checks before any drape, the cage, a plan of the budget (drapes and epochs timed first),
        data, the models (the PCA net, the CNN under L2; the better kept) and a preview of the test poses, each
        step skipped when done (a second call resumes; --until data stops after the drapes); default DIR
        runs/fit/<name> (an outfit's piece: runs/fit/<name>_<piece>)
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.core.config import load_config
from pbc.core.io import require_out_dir
from pbc.core.validate import check_bounds, made_on_rest_problems
from pbc.geometry.body import body_from_config
from pbc.geometry.garment.outfit import split_outfit
from pbc.geometry.inspect import format_report, save_body_picture, save_uv_picture
from pbc.geometry.meshio import not_an_obj_file
from pbc.jobs.garment_fit import STEPS, Fit, default_out, garment_overrides, inspect_file


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="pbc garment", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    ins = sub.add_parser("inspect", help="the charts, fit and settings of a garment OBJ or MakeHuman .mhclo")
    ins.add_argument("obj", help="the garment: an .obj, or a MakeHuman .mhclo (its .obj beside it; on body=anny)")
    ins.add_argument("overrides", nargs="*", help="Hydra overrides: garment.position_unit=dm, body=..., ...")
    ins.add_argument("--out", help="folder for uv_layout.png, on_body.png and fitted.obj")
    ins.add_argument("--no-wrap", action="store_true", help="skip the shrink-wrap (its stretch per chart)")
    spl = sub.add_parser("split", help="one OBJ per connected piece of an outfit, named by where it sits")
    spl.add_argument("obj", help="the outfit OBJ")
    spl.add_argument("--out", required=True, help="folder for the pieces' OBJs")
    spl.add_argument("--position-unit", default="m", help="unit of the v lines (m, dm, cm, mm, in)")
    fit = sub.add_parser("fit", help="a garment file to the best model a budget buys, and a preview (resumable)")
    fit.add_argument("obj", help="the garment: an .obj, or a MakeHuman .mhclo (its .obj beside it)")
    fit.add_argument("overrides", nargs="*", help="Hydra overrides for every step: garment.position_unit=dm, "
                     "body=anny, ...")
    fit.add_argument("--out", help="folder of the fit (default $PBC_ROOT/runs/fit/<garment name>)")
    fit.add_argument("--budget", help="wall-clock time the fit may take, planned into drapes and epochs before any "
                     "drape: 60m (default, conf/fit.yaml), 15m, 1h30m")
    fit.add_argument("--samples", type=int, help="poses to drape (data.num_samples; default: the plan's)")
    fit.add_argument("--epochs", type=int, help="training epochs of each model (trainer.max_epochs; default: the "
                     "plan's); with --samples nothing is planned")
    fit.add_argument("--motion-frames", type=int, help="drapes of held-out motion-capture frames to score on "
                     "(default: the plan's; 0: none)")
    fit.add_argument("--until", choices=STEPS[1:], default=STEPS[-1],
                     help="stop after this step (checks: every check before a drape; data: the drapes); the same "
                          "command without it goes on")
    # overrides may also follow the options (`fit my.obj --samples 4 trainer=smoke`): argparse's subparsers
    # leave them over instead of collecting them
    args, rest = ap.parse_known_args(argv)
    if rest and (args.command != "fit" or any(r.startswith("-") for r in rest)):
        ap.error(f"unrecognized arguments: {' '.join(rest)}")
    path = Path(args.obj)
    problem = not_an_obj_file(path, "garment")  # a folder: its OBJ files named
    if problem is not None:
        raise FileNotFoundError(problem)
    if args.command == "fit":
        out = args.out or default_out(path, Path(os.environ.get("PBC_ROOT", ".")), [*args.overrides, *rest])
        print(Fit(path, [*args.overrides, *rest], out, args.samples, args.epochs, until=args.until,
                  budget=args.budget, motion_frames=args.motion_frames).run())
        return 0
    if args.command == "split":
        if path.suffix.lower() == ".mhclo":
            raise ValueError(f"{path}: MakeHuman clothes are not split into files; each piece of an outfit is "
                             "chosen where it is used: garment.piece=top (bottom, head, feet, top_2, ...; pbc "
                             "garment inspect on the outfit names its pieces)")
        unit = float(args.position_unit) if args.position_unit.replace(".", "", 1).isdigit() else args.position_unit
        for name, target, n in split_outfit(path, args.out, position_unit=unit):
            print(f"{name:<10} {n:>6} polygons  {target}")
        return 0
    if args.out:
        require_out_dir(args.out)  # before the garment is read: the pictures and fitted.obj are written last
    cfg = load_config([*garment_overrides(path, args.overrides), *args.overrides])
    check_bounds(cfg)  # the image sizes its garment node reads (${image.crop_size}) and any sim override given
    if problems := made_on_rest_problems(cfg):  # before the body is turned to it
        raise ValueError("invalid configuration:\n  - " + "\n  - ".join(problems))
    with tempfile.TemporaryDirectory() as scratch:  # MakeHuman clothes' fitted .obj, kept under --out
        report = inspect_file(path, cfg, body_from_config(cfg.body), Path(args.out or scratch),
                              wrap=not args.no_wrap)
        print(format_report(report, dict(cfg.garment.shrinkwrap)))
    if args.out:
        fitted = [Path(args.out) / "fitted.obj"]  # inspect_file writes it for every kind
        for target in (save_uv_picture(report, Path(args.out) / "uv_layout.png"),
                       save_body_picture(report, Path(args.out) / "on_body.png"), *fitted):
            print(f"wrote {target}")
    return 0


main = entry_point("garment", run)

if __name__ == "__main__":
    main()
