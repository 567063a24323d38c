"""How much of a clip a data config's sampled poses cover, before any drape: the clip's frames flagged against
the swing-twist range of N poses the config's sampler draws (pruned as generation prunes them), per sampler
setting, side by side. Seconds, where a generation is an hour: it says which sampler to drape.

    python docs/results/starter/sampler_coverage.py --model tshirt --n 1650 \
        --variant "" --variant "body.sampling.modes.swinging_arms.fraction=0"

Each --variant is a space-separated list of overrides on the model's data config (`data=tshirt_anny` for the
shirt; `data.seed=1` draws other poses). Prints a table and, last, one JSON line. A drape keeps about two
thirds of these poses and mirroring adds their mirror images, so a shipped model's own range (bench/starter.py)
is close to, not equal to, this.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO))

from bench.starter import CLIPS, clip_frames, open_model  # noqa: E402
from pbc.geometry.body import body_from_config  # noqa: E402
from pbc.motion.ranges import PoseRange, angle_range, range_report  # noqa: E402
from pbc.motion.retarget import motion_settings  # noqa: E402
from pbc.sim.poses import sample_poses, sampling_settings_from_config  # noqa: E402

DATA = {"tshirt": "tshirt_anny", "trousers": "trousers_anny"}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="tshirt", help="a shipped model: its body, the joints it reads, its clips")
    ap.add_argument("--n", type=int, default=1650, help="poses drawn per variant")
    ap.add_argument("--variant", action="append", default=None, help="overrides of the data config (repeatable)")
    args = ap.parse_args(argv)
    pred, _ = open_model(args.model)
    names = list(pred.dataset.body.skeleton.names)
    unread = [j for j in range(len(names)) if j not in pred.read_joints()]
    clips = {p.name: clip_frames(pred, p, 10)[0].astype(np.float64) for p in CLIPS}
    tol = float(motion_settings().range_tolerance_deg)  # as pbc predict and bench/starter.py flag
    out = {}
    print(f"| variant (on data={DATA[args.model]}) | pruned / drawn | " + " | ".join(f"{c} flagged" for c in clips)
          + " | worst (deg) |\n| --- | --- |" + " --- |" * (len(clips) + 1))
    for variant in args.variant or [""]:
        with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=None):
            cfg = compose(config_name="config", overrides=[f"data={DATA[args.model]}", *variant.split()])
        body = body_from_config(cfg.body)
        poses, stats = sample_poses(body.skeleton, args.n, int(cfg.data.seed), body,
                                    sampling_settings_from_config(cfg.body.sampling))
        rng = angle_range(poses.numpy().astype(np.float64))
        deg = rng.deg.copy()
        deg[unread, :, 0], deg[unread, :, 1] = -180.0, 180.0  # as predict: joints the model ignores never flag
        rng = PoseRange(deg, rng.chart)
        rep = {c: range_report(p, rng, names, tol) for c, p in clips.items()}
        worst = max((d for r in rep.values() for f in r["distance_deg"].values() for d in f.values()), default=0.0)
        out[variant or "(config as is)"] = {"pruned": stats["pruned"], "drawn": stats["candidates"],
                                            "worst_deg": round(worst, 2),
                                            **{c: {"flagged": r["num_outside"], "frames": r["num_frames"],
                                                   "axes": r["joint_axes_outside"]} for c, r in rep.items()}}
        print(f"| {variant or '(config as is)'} | {stats['pruned']} / {stats['candidates']} | "
              + " | ".join(f"{r['num_outside']} of {r['num_frames']}" for r in rep.values()) + f" | {worst:.2f} |",
              flush=True)
    print(json.dumps({"model": args.model, "n": args.n, "variants": out}))
    return out


if __name__ == "__main__":
    main()
