"""`pbc preview DATASET [OUT_DIR] [overrides]`: the cloth-image figures of a dataset (cloth images, crop
windows, round-trip error) as a run with those overrides would see them. The dataset's own preview
(figures and meshes) is `pbc generate ... preview=true`."""

from __future__ import annotations

import argparse
from pathlib import Path

from pbc.cli.errors import entry_point
from pbc.core.config import load_config
from pbc.data.dataset import load_dataset
from pbc.pixels.preview import preview as cloth_image_preview


def run(argv: list[str]) -> None:
    """The cloth-image figures of a dataset (under DATASET_DIR/preview_pixels unless OUT_DIR is given)."""
    ap = argparse.ArgumentParser(prog="pbc preview",
                                 description="Cloth images, crop windows and round-trip error of a dataset.")
    ap.add_argument("dataset")
    ap.add_argument("out", nargs="?", default=None)
    ap.add_argument("--samples", type=int, default=3)
    ap.add_argument("overrides", nargs="*", help="config overrides giving the image and offset space the figures "
                    "show, as a run's (e.g. +experiment=necktie: its 64 x 256 window in the root frame)")
    args, extra = ap.parse_known_args(argv)
    overrides = [*args.overrides, *extra]
    if args.out and "=" in args.out:  # `preview DATASET +experiment=necktie`: an override, not OUT_DIR
        overrides, args.out = [args.out, *overrides], None
    cfg = load_config(overrides)
    out = args.out or Path(args.dataset) / "preview_pixels"
    for p in cloth_image_preview(load_dataset(args.dataset), out, cfg.image, args.samples, str(cfg.model.space)):
        print(p)


main = entry_point("preview", run)

if __name__ == "__main__":
    main()
