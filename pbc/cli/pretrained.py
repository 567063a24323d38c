"""`pbc pretrained list | pack RUN --name NAME`: the models shipped inside pbc (pbc/pretrained/<name>/), and
how one is made from a trained whole-shirt run (pbc.pretrained.pack does the work)."""

from __future__ import annotations

import argparse

from pbc.cli.errors import entry_point
from pbc.core.runs import RunRecord
from pbc.pretrained import SHIPPED_DIR, pretrained_dir, shipped_models
from pbc.pretrained.pack import CARD, pack_run

EXAMPLES = """examples:
  pbc pretrained list                                            # the shipped models and their test errors
  pbc pretrained pack runs/main/latest/whole --name tshirt       # replace the shipped tshirt model
  pbc predict --pretrained tshirt --poses test                   # use it
"""


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="pbc pretrained", formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=EXAMPLES, description="The models shipped with pbc (--pretrained NAME in "
                                 "pbc predict and pbc view, whole_run=pretrained:NAME in pbc evaluate), and "
                                 "packing a trained whole-shirt run as one: fp16 weights, the dataset's test "
                                 "split and training summary, a model card.")
    sub = ap.add_subparsers(dest="action", required=True)
    sub.add_parser("list", help="the shipped models, their test error and the training mean shape's")
    pk = sub.add_parser("pack", help="pack a whole-shirt run dir as a shipped model")
    pk.add_argument("run", help="a finished whole-shirt training run dir (e.g. runs/main/latest/whole)")
    pk.add_argument("--name", required=True, help="the shipped model's name (e.g. tshirt)")
    pk.add_argument("--out", help=f"where to write it (default {SHIPPED_DIR}/<name>, replaced)")
    pk.add_argument("--data", metavar="DIR", help="the run's dataset, when it moved from where the run recorded it")
    pk.add_argument("--trained-on", metavar="TEXT", help="the training machine in words, for the model card "
                    "(the run records none; default: its trainer.accelerator and this machine)")
    pk.add_argument("--command", metavar="TEXT", help="the command that trained the run, for the model card")
    pk.add_argument("--notes", metavar="FILE", help="a markdown file the model card carries after its table (the "
                    "data's provenance and licence, scores beyond the test split)")
    pk.add_argument("--test-poses", metavar="N", type=int, help="ship (and score the card on) the first N poses of "
                    "the test split (default: all; their drapes are most of a shipped model's bytes, and it should "
                    "stay under 8 MB)")
    pk.add_argument("--commit", metavar="TEXT", help="the commit the run was trained with, for the model card (the "
                    "run records none; default: this checkout's)")
    return ap


def run(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    if args.action == "list":
        names = shipped_models()
        if not names:
            print("no shipped models")
        for name in names:
            info = RunRecord.read(pretrained_dir(name)).extra.get("pretrained", {})
            print(f"{name}: test vertex error {info.get('test_vertex_error_cm')} cm (training mean shape "
                  f"{info.get('mean_shape_test_vertex_error_cm')} cm) over {info.get('test_poses')} test poses of "
                  f"{info.get('dataset', {}).get('name')}; {pretrained_dir(name) / CARD}")
        return 0
    info = pack_run(args.run, args.name, args.out, args.data, args.trained_on, args.command, args.commit, args.notes,
                    args.test_poses)
    out = args.out or SHIPPED_DIR / args.name
    print(f"{args.name} -> {out}: {info['bytes']['total'] / 1e6:.2f} MB (weights {info['bytes']['weights'] / 1e6:.2f} "
          f"MB); test vertex error {info['test_vertex_error_cm']:.3f} cm (fp16) vs the training mean shape's "
          f"{info['mean_shape_test_vertex_error_cm']:.3f} cm over {info['test_poses']} test poses; fp16 vs fp32 at "
          f"most {info['fp16_vs_fp32_max_vertex_cm']:.4f} cm; {CARD} written ({info['pack_seconds']:.0f} s)")
    return 0


main = entry_point("pretrained", run)

if __name__ == "__main__":
    main()
