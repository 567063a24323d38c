"""The corpus bench: every motion clip of ../shared/corpus through pbc's motion door and the starter models.

    python bench/corpus.py [--models tshirt trousers] [--per-clip 6] [--no-drape] [--out docs/results/corpus]

One row per corpus clip (CMU in three releases, Bandai Namco, MakeHuman poses, as their tools wrote them):

- **read**: its dialect, units, rest (or the frame standing in for it), the sanity of the retargeted clip, or
  the refusal's reason;
- per model, on every frame: the frames **flagged** past the model's data (pbc.motion.known: the nearest
  training pose farther than the model's own test poses are) and the **shattered** frames (the predicted
  garment's longest edge past 3x its usual length, the median over the model's shipped drapes), as asked, under
  the default guard, and under the guard mended as by default (`ClothPredictor.mend`, conf/mend.yaml); under
  the guard unmended past the model's worst stretch on its own test poses, and as asked
  with the garment skinned through every joint (`ClothPredictor.hold_unread` off: a shirt's hem follows the
  thighs it never learnt);
- with drapes (not --no-drape), on K frames spread over each clip: the drapes **kept** by pbc's simulator
  (the model's own data config) and the model's vertex error against them beside the training mean shape's,
  on the kept frames, for the clips the model trained on, the clips held out of its training and the clips of
  other sources.

Drapes are cached per model scene and clip under --cache (they depend on the pose, the body, the garment and
the simulator, not on the model), so a second run measures the models alone. The targets (the corpus issue):
0 shattered frames under the guard and the mend, every clip read or refused with a reason, at most 10% of the frames of
the clips a model trained on flagged, the starters at most 0.5x the mean shape on held-out frames, at least
90% of frames kept. Prints a table per model, one line per target, and as its last line one JSON object of
the figures with the device.
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.starter import open_model  # noqa: E402
from pbc.core.runs import RunRecord  # noqa: E402
from pbc.data.generate import Scene, drape_pose  # noqa: E402
from pbc.geometry.meshops import edge_stretch  # noqa: E402
from pbc.inference.poses import read_motion, run_known  # noqa: E402
from pbc.inference.scores import mean_shape  # noqa: E402
from pbc.jobs.predict import guard_frames  # noqa: E402
from pbc.motion.bvh import read_bvh  # noqa: E402
from pbc.motion.retarget import motion_settings  # noqa: E402

CORPUS = ROOT.parent / "shared" / "corpus"
TARGETS = {"shattered": 0, "flagged_trained": 0.10, "held_out_over_mean_shape": 0.5, "kept": 0.90}
SHATTER = 3.0  # a predicted edge this many times its usual length
CM = 100.0


def corpus_clips(corpus: Path) -> list[Path]:
    return sorted((corpus / "motion").rglob("*.bvh"))


def read_row(path: Path, dataset) -> tuple[dict, object | None]:
    """A clip's read columns and its Motion (None: refused, the reason in the row)."""
    bvh = read_bvh(path)
    row = {"clip": str(path.relative_to(CORPUS / "motion")), "frames": bvh.num_frames}
    try:
        m = read_motion(path, dataset)
    except ValueError as e:
        return dict(row, read="refused", reason=str(e).split(": ", 1)[-1][:160]), None
    rest = m.rest_pose + ("" if m.rest_frame is None else f" (frame {m.rest_frame})")
    return dict(row, read="read", dialect=m.table.dialect, units=m.units, height_m=round(m.height_m, 2), rest=rest,
                fps=round(m.fps, 2), sanity="ok" if not m.sanity["problems"] else "; ".join(m.sanity["problems"])), m


def clip_role(clip: str, cfg) -> str:
    """'trained', 'held out' (data.poses_holdout) or 'other' for a corpus clip and a model's run config."""
    data = cfg.data
    if not data.get("poses") or "bandai" in clip:
        return "other"
    root = Path(str(data.poses)).name  # the folder data.poses names (motion/cmu)
    if not clip.startswith(root + "/"):
        return "other"
    name = clip[len(root) + 1:]
    if any(fnmatch.fnmatch(name, p) for p in (data.get("poses_holdout") or ())):
        return "held out"
    return "trained"


def scene_key(cfg) -> str:
    """What a drape depends on besides the pose: the body, the garment and the simulator's settings."""
    text = json.dumps({k: OmegaConf.to_container(cfg[k], resolve=False) for k in ("body", "garment", "sim")},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_drapes(cache: Path, scene: Scene, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(drapes (n, V, 3) float32, kept (n,) bool) of poses (n, J, 3, 3), each read from `cache` (a folder per
    scene) when draped before."""
    cache.mkdir(parents=True, exist_ok=True)
    drapes, kept = [], []
    for p in poses:
        f = cache / (hashlib.sha256(np.ascontiguousarray(p, np.float32).tobytes()).hexdigest()[:20] + ".npz")
        if f.is_file():
            with np.load(f) as z:
                drapes.append(z["drape"])
                kept.append(bool(z["ok"]))
            continue
        r = drape_pose(scene, p.astype(np.float32), 0)
        drapes.append(np.asarray(r["positions"], np.float32))
        kept.append(bool(r["ok"]))
        tmp = f.with_name(f.stem + ".part.npz")
        np.savez(tmp, drape=drapes[-1], ok=kept[-1])
        tmp.replace(f)
    return np.stack(drapes), np.array(kept)


def predict(pred, poses: np.ndarray, mend: bool = True) -> np.ndarray:
    """The whole model's garments (N, V, 3) at poses (N, J, 3, 3), mended as by default or (mend=False) as the
    model gives them."""
    settings = pred.mend
    pred.mend = settings if mend else None
    try:
        with torch.inference_mode():
            return pred(torch.from_numpy(np.asarray(poses, np.float32)), model="whole").numpy()
    finally:
        pred.mend = settings


def model_rows(name: str, clips: list[Path], per_clip: int, drape: bool, cache: Path) -> tuple[list[dict], dict]:
    """One model over every clip: per clip its flags, shattered frames and (with `drape`) drapes and errors."""
    pred, run_dir = open_model(name)
    cfg = OmegaConf.create(RunRecord.read(run_dir).config)
    ds = pred.dataset
    edges, usual = pred.edge_lengths()
    known = run_known(pred, float(motion_settings().known.quantile))
    own = float(edge_stretch(predict(pred, np.asarray(ds.poses)[np.asarray(ds.split("test"))], mend=False), edges,
                             usual).max())
    scene = Scene(ds.body, ds.garment, ds.cage, ds.embedding, cfg.sim) if drape else None
    rows = []
    for path in clips:
        row, m = read_row(path, ds)
        row["role"] = clip_role(row["clip"], cfg)
        if m is None:
            rows.append(row)
            continue
        t0 = time.time()
        guarded, report = guard_frames(pred, m.poses)
        flagged = np.zeros(len(m.poses), bool)
        k = report.get("known")
        flagged[k["flagged"] if k else report["frames_outside"]] = True
        raw = edge_stretch(predict(pred, m.poses, mend=False), edges, usual)
        safe = edge_stretch(predict(pred, guarded, mend=False), edges, usual)
        mended = edge_stretch(predict(pred, guarded), edges, usual)
        pred.hold_unread = False
        unheld = edge_stretch(predict(pred, m.poses, mend=False), edges, usual)
        pred.hold_unread = True
        row.update(flagged=int(flagged.sum()), shattered_raw=int((raw > SHATTER).sum()),
                   shattered_guarded=int((safe > SHATTER).sum()), stretch_guarded_max=round(float(safe.max()), 2),
                   shattered=int((mended > SHATTER).sum()), stretch_max=round(float(mended.max()), 2),
                   past_own=int((safe > own).sum()), shattered_unheld=int((unheld > SHATTER).sum()),
                   stretch_unheld_max=round(float(unheld.max()), 2),
                   stretch_raw_max=round(float(raw.max()), 2), guard=report["guard"],
                   distance_median_deg=None if not k else round(float(np.median(k["distance_deg"])), 2))
        if drape:
            pick = np.unique(np.linspace(0, len(m.poses) - 1, min(per_clip, len(m.poses))).round().astype(int))
            drapes, kept = cached_drapes(cache / scene_key(cfg), scene, m.poses[pick])
            x = predict(pred, guarded[pick])
            err = np.linalg.norm(x - drapes, axis=-1).mean(1) * CM
            base = np.linalg.norm(mean_shape(pred, m.poses[pick]).numpy() - drapes, axis=-1).mean(1) * CM
            row.update(draped=len(pick), kept=int(kept.sum()), model_cm=err[kept].round(4).tolist(),
                       mean_shape_cm=base[kept].round(4).tolist(), flagged_draped=flagged[pick][kept].tolist(),
                       distance_deg=None if not k else np.asarray(k["distance_deg"])[pick][kept].round(2).tolist())
        row["seconds"] = round(time.time() - t0, 1)
        rows.append(row)
        print(f"{name:9s} {row['clip'][:44]:44s} {row['role']:8s} flagged {row['flagged']:4d}/{len(m.poses):<4d} "
              f"shattered {row['shattered_raw']:4d} -> guarded {row['shattered_guarded']:4d} -> mended "
              f"{row['shattered']:3d} (guarded past own {row['past_own']:3d}; "
              f"every joint skinned {row['shattered_unheld']:4d})"
              + (f"  kept {row['kept']}/{row['draped']}" if drape else "") + f"  {row['seconds']:.0f} s", flush=True)
    info = {"model": name, "known_limit_deg": None if known is None else round(known.limit_deg, 3),
            "training_poses": None if known is None else len(known.poses), "read_joints": len(pred.read_joints()),
            "held_joints": [ds.body.skeleton.names[j] for j in pred.held_joints()],
            "own_test_stretch_max": round(own, 3)}
    return rows, info


def summarise(rows: list[dict], drape: bool) -> dict:
    """The model's figures over its rows: shattered frames, flags on trained clips, kept, errors per role, and
    the flags' calibration (error of flagged vs unflagged draped frames)."""
    read = [r for r in rows if r["read"] == "read"]
    frames = sum(r["frames"] for r in read)
    out = {"clips": len(rows), "refused": len(rows) - len(read), "frames": frames,
           "shattered_raw": sum(r["shattered_raw"] for r in read),
           "shattered_guarded": sum(r["shattered_guarded"] for r in read),
           "shattered": sum(r["shattered"] for r in read),
           "stretch_max": max((r["stretch_max"] for r in read), default=0.0),
           "past_own": sum(r["past_own"] for r in read),
           "shattered_unheld": sum(r["shattered_unheld"] for r in read),
           "flagged": sum(r["flagged"] for r in read)}
    trained = [r for r in read if r["role"] == "trained"]
    out["flagged_trained_rate"] = (round(sum(r["flagged"] for r in trained) / max(1, sum(r["frames"] for r in trained)),
                                         3) if trained else None)
    if not drape:
        return out
    out["draped"] = sum(r["draped"] for r in read)
    out["kept"] = sum(r["kept"] for r in read)
    out["kept_rate"] = round(out["kept"] / max(1, out["draped"]), 3)
    for role in ("trained", "held out", "other"):
        m = np.concatenate([r["model_cm"] for r in read if r["role"] == role] or [np.zeros(0)])
        b = np.concatenate([r["mean_shape_cm"] for r in read if r["role"] == role] or [np.zeros(0)])
        if len(m):
            out[role.replace(" ", "_")] = {"frames": len(m), "model_cm": round(float(m.mean()), 4),
                                           "mean_shape_cm": round(float(b.mean()), 4),
                                           "ratio": round(float(m.mean() / b.mean()), 3)}
    m = np.concatenate([r["model_cm"] for r in read])
    b = np.concatenate([r["mean_shape_cm"] for r in read])
    f = np.concatenate([r["flagged_draped"] for r in read]).astype(bool)
    out["calibration"] = {
        which: {"frames": int(sel.sum()),
                "ratio": None if not sel.any() else round(float(m[sel].mean() / b[sel].mean()), 3),
                "model_cm": None if not sel.any() else round(float(m[sel].mean()), 4)}
        for which, sel in (("flagged", f), ("unflagged", ~f))}
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", default=["tshirt", "trousers"], help="shipped models or run dirs")
    ap.add_argument("--per-clip", type=int, default=6, help="drape K frames spread over each clip (default 6)")
    ap.add_argument("--no-drape", action="store_true", help="read, flags and shattered frames only")
    ap.add_argument("--clips", default="*", help="a glob on the clips' names (default: every clip)")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "pbc" / "corpus_drapes")
    ap.add_argument("--out", type=Path, help="write results.json here")
    args = ap.parse_args(argv)
    from bench.drape import device_name  # noqa: PLC0415 - the sibling benchmark's device line, after sys.path

    if not (CORPUS / "README.md").is_file():
        raise SystemExit(f"the corpus is missing at {CORPUS}: put ../shared/corpus beside the repository")
    clips = [c for c in corpus_clips(CORPUS) if fnmatch.fnmatch(c.name, args.clips)]
    device = device_name(None)
    print(f"# device: {device}; {len(clips)} corpus clips; drapes "
          f"{'off' if args.no_drape else f'{args.per_clip} a clip'}")
    figures = {"device": device, "per_clip": args.per_clip, "drape": not args.no_drape, "models": {}}
    all_rows = {}
    for name in args.models:
        rows, info = model_rows(name, clips, args.per_clip, not args.no_drape, args.cache)
        all_rows[name] = rows
        figures["models"][name] = dict(info, **summarise(rows, not args.no_drape))
    for name, fig in figures["models"].items():
        print(f"\n## {name}: limit {fig['known_limit_deg']} degrees over {fig['read_joints']} joints, "
              f"{fig['training_poses']} training poses; held at rest: {', '.join(fig['held_joints']) or 'none'}; "
              f"worst stretch on its test poses {fig['own_test_stretch_max']:.2f}x")
        print("| clip | role | read | units | rest | sanity | flagged | shattered (as asked -> guarded -> mended) | "
              "guarded past its test poses | as asked, every joint skinned |"
              + (" kept | model / mean shape (cm) |" if not args.no_drape else ""))
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
              + (" --- | --- |" if not args.no_drape else ""))
        for r in all_rows[name]:
            if r["read"] != "read":
                print(f"| {r['clip']} | {r['role']} | refused: {r['reason']} | | | | | | | |")
                continue
            cells = (f"| {r['clip']} | {r['role']} | {r['dialect']} | {r['units']} | {r['rest']} | {r['sanity']} | "
                     f"{r['flagged']}/{r['frames']} | {r['shattered_raw']} -> {r['shattered_guarded']} -> "
                     f"{r['shattered']} | {r['past_own']} | "
                     f"{r['shattered_unheld']} |")
            if not args.no_drape:
                mc = np.mean(r["model_cm"]) if r["model_cm"] else float("nan")
                bc = np.mean(r["mean_shape_cm"]) if r["mean_shape_cm"] else float("nan")
                cells += f" {r['kept']}/{r['draped']} | {mc:.2f} / {bc:.2f} |"
            print(cells)
        t = {"shattered": fig["shattered"] <= TARGETS["shattered"]}
        if fig["flagged_trained_rate"] is not None:
            t["flagged_trained"] = fig["flagged_trained_rate"] <= TARGETS["flagged_trained"]
        if not args.no_drape:
            t["kept"] = fig["kept_rate"] >= TARGETS["kept"]
            if "held_out" in fig:
                t["held_out_over_mean_shape"] = fig["held_out"]["ratio"] <= TARGETS["held_out_over_mean_shape"]
        fig["targets"] = {k: {"target": TARGETS[k], "pass": bool(v)} for k, v in t.items()}
        for k, v in fig["targets"].items():
            print(f"# {name} target {k} ({v['target']}): {'pass' if v['pass'] else 'FAIL'}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps({**figures, "rows": all_rows}, indent=1) + "\n")
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
