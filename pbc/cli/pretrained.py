"""`pbc pretrained list | pack RUN --name NAME`: the pretrained models `--pretrained NAME` finds (the user's, in
pbc.pretrained.user_models_dir(), before the ones shipped inside pbc), and how one is made from a trained
whole-shirt run (pbc.pretrained.pack does the work)."""

from __future__ import annotations

import argparse

from pbc.cli.errors import entry_point
from pbc.core.runs import RunRecord
from pbc.pretrained import (
    MODELS_ENV,
    SHIPPED,
    PretrainedModel,
    all_models,
    shipped_model_dir,
    shipped_models,
    user_models_dir,
)
from pbc.pretrained.pack import CARD, pack_run

EXAMPLES = f"""examples:
  pbc pretrained list                                            # the models, where each lives, their test errors
  pbc pretrained pack runs/main/latest/whole --name myshirt      # your model, in your models folder
  pbc pretrained pack runs/main/latest/whole --name tshirt --force   # yours, shadowing the shipped tshirt
  pbc predict --pretrained myshirt --poses test                  # use it

Your models folder: ${MODELS_ENV}, else $PBC_ROOT/models, else ~/.local/share/pbc/models (now {{models}}).
"""


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="pbc pretrained", formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=EXAMPLES.format(models=user_models_dir()),
                                 description="The pretrained models (--pretrained NAME in pbc predict and pbc "
                                 "view, whole_run=pretrained:NAME in pbc evaluate): yours, in your models folder, "
                                 "and the ones shipped with pbc, which pbc never overwrites; and packing a "
                                 "trained whole-shirt run as one of yours: fp16 weights, the dataset's test split "
                                 "and training summary, a model card.")
    sub = ap.add_subparsers(dest="action", required=True)
    sub.add_parser("list", help="your models and the shipped ones: where each lives, which shadows which, their "
                   "test error and the training mean shape's")
    pk = sub.add_parser("pack", help="pack a whole-shirt run dir as your model")
    pk.add_argument("run", help="a finished whole-shirt training run dir (e.g. runs/main/latest/whole)")
    pk.add_argument("--name", required=True, help="the model's name (e.g. myshirt); a shipped model's name needs "
                    "--force")
    pk.add_argument("--out", help=f"where to write it (default: your models folder, {user_models_dir()}/<name>); "
                    "a model already there is kept beside it as <name>.previous-<time>")
    pk.add_argument("--force", action="store_true", help="pack under a shipped model's name: yours goes to your "
                    "models folder and shadows it, the shipped files stay; with --out inside pbc/pretrained, "
                    "replace the package's copy (re-making a shipped model in a checkout)")
    pk.add_argument("--data", metavar="DIR", help="the run's dataset, when it moved from where the run recorded it")
    pk.add_argument("--trained-on", metavar="TEXT", help="the training machine in words, for the model card "
                    "(the run records none; default: its trainer.accelerator and this machine)")
    pk.add_argument("--command", metavar="TEXT", help="the command that trained the run, for the model card")
    pk.add_argument("--notes", metavar="FILE", help="a markdown file the model card carries after its table (the "
                    "data's provenance and licence, scores beyond the test split)")
    pk.add_argument("--test-poses", metavar="N", type=int, help="ship (and score the card on) the first N poses of "
                    "the test split (default: all; their drapes are most of a model's bytes, and a shipped one "
                    "should stay under 8 MB)")
    pk.add_argument("--commit", metavar="TEXT", help="the commit the run was trained with, for the model card (the "
                    "run records none; default: this checkout's)")
    return ap


def where_words(model: PretrainedModel) -> str:
    """Where `model` lives and what it hides or is hidden by, in a few words: "shipped", "yours, shadows the
    shipped NAME", "shipped, shadowed by yours"."""
    if model.kind == SHIPPED:
        return "shipped, shadowed by yours" if model.shadowed else "shipped"
    return f"yours, shadows the shipped {model.name}" if model.shadows else "yours"


def model_line(model: PretrainedModel) -> str:
    """One line of `pbc pretrained list`: the model, where it lives, its scores and its card."""
    info = RunRecord.read(model.path).extra.get("pretrained", {})
    return (f"{model.name} ({where_words(model)}): test vertex error {info.get('test_vertex_error_cm')} cm (training "
            f"mean shape {info.get('mean_shape_test_vertex_error_cm')} cm) over {info.get('test_poses')} test poses "
            f"of {info.get('dataset', {}).get('name')}; {model.path / CARD}")


def packed_line(info: dict) -> str:
    """What `pbc pretrained pack` says it made: where, its size and scores, and the model it replaced or hides."""
    name, out = info["name"], info["dir"]
    kept = f"; the model there before is kept as {info['previous']}" if info.get("previous") else ""
    in_user_dir = out.parent.resolve() == user_models_dir().resolve()
    shadows = (f"; it shadows the shipped {out.name} ({shipped_model_dir(out.name)}, unchanged)"
               if in_user_dir and out.name in shipped_models() else "")
    return (f"{name} -> {out}: {info['bytes']['total'] / 1e6:.2f} MB (weights {info['bytes']['weights'] / 1e6:.2f} "
            f"MB); test vertex error {info['test_vertex_error_cm']:.3f} cm (fp16) vs the training mean shape's "
            f"{info['mean_shape_test_vertex_error_cm']:.3f} cm over {info['test_poses']} test poses; fp16 vs fp32 at "
            f"most {info['fp16_vs_fp32_max_vertex_cm']:.4f} cm; {CARD} written ({info['pack_seconds']:.0f} s)"
            f"{kept}{shadows}")


def run(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    if args.action == "list":
        models = all_models()
        if not models:
            print("no pretrained models")
        for model in models:
            print(model_line(model))
        print(f"your models folder: {user_models_dir()} (${MODELS_ENV} sets it)")
        return 0
    info = pack_run(args.run, args.name, args.out, args.data, args.trained_on, args.command, args.commit, args.notes,
                    args.test_poses, force=args.force)
    print(packed_line(info))
    return 0


main = entry_point("pretrained", run)

if __name__ == "__main__":
    main()
