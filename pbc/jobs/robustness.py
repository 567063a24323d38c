"""The wrong-body study (paper sec. 1, appendix D.2, Figs. 9-10): does the CNN learn the right cloth when the
body it skins and embeds with is wrong?

A sweep of the runner (`python -m pbc.sweeps robustness scale=...`, conf/sweep/robustness.yaml): keep the
simulated cloth (the base dataset's poses and draped vertices) and change only the body: the sculpted
shapes t in `robustness.shapes` (t = 0 true, 1 = a thicker chest and belly, see pbc/geometry/body/sculpt.py) and
the two painted skinning artifacts. The runner's steps:

1. data: the scale's dataset (pbc.generate), as in every sweep;
2. bodies: `prepare_bodies` gives each trial a dataset dir that links the base arrays and replaces
   body.npz (same mesh connectivity, so the embedding stays valid);
3. train: the Hydra multirun over `robustness.trial` (one whole-shirt model per body, the scale's
   schedule; `robustness.trial=shape_0.0,shape_2.0` runs a subset);
4. report: `build_report` reads the trial runs back (pbc.core.runs) and plots train and test vertex error
   against t (Fig. 9), says whether the error stays roughly constant (within `constant_factor` of the true
   body's), and draws a prediction on the too-thick body and on the artifact body with the body drawn
   through the cloth (Fig. 10), with how much of the predicted cloth sits below the wrong body's surface
   (dn < 0).

Writes under the sweep dir: bodies/<trial>/ (datasets), <trial>/ (run dirs: metrics.json, checkpoints,
TensorBoard), robustness.json, robustness.md, fig9_error_vs_shape.png, fig10_wrong_body.png.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from matplotlib.collections import PolyCollection
from omegaconf import DictConfig, OmegaConf

from pbc.core.config import load_config
from pbc.core.io import hash_arrays, read_json, save_figure, write_json, write_text
from pbc.core.paths import CONF_DIR
from pbc.core.runs import (
    OK,
    SWEEP_RECORD,
    VERTEX_ERROR,
    Run,
    expected_jobs,
    load_run,
    load_runs,
    read_run,
    run_image_config,
    sweep_values,
)
from pbc.data.baselines import mean_shape_errors
from pbc.data.dataset import load_dataset
from pbc.geometry.body import body_from_config
from pbc.geometry.body.base import pose_body, save_body
from pbc.geometry.body.sculpt import paint_weights, sculpt_displacement, shaped_body
from pbc.inference.predictor import load_decoder
from pbc.pixels.frames import to_offsets
from pbc.pixels.target import make_target

SWEEP_CONFIG = CONF_DIR / "sweep" / "robustness.yaml"
LINKED = ("poses.npy", "verts.npy", "garment.obj", "cage.json", "embedding.npz")
CM = 100.0


def trial_names(rob: DictConfig) -> list[str]:
    """shape_<t> for every shape parameter, then the artifact names."""
    return [f"shape_{float(t):.1f}" for t in rob.shapes] + list(rob.artifacts.keys())


PHENOTYPE = "phenotype_"  # trial phenotype_<key>_<delta>: Anny rebuilt with that phenotype value moved


def phenotype_trials(rob: DictConfig) -> list[str]:
    """phenotype_<key>_<delta> for each delta of each key in `robustness.phenotypes` (Anny bodies only, so
    not in the default trial list: name them with robustness.trial=...)."""
    return [f"{PHENOTYPE}{k}_{float(d):.2f}" for k, ds in (rob.get("phenotypes") or {}).items() for d in ds]


def phenotype_of(name: str) -> tuple[str, float] | None:
    """(key, delta) of a phenotype trial name, None for any other trial."""
    if not name.startswith(PHENOTYPE):
        return None
    key, _, delta = name[len(PHENOTYPE):].rpartition("_")
    try:
        return key, float(delta)
    except ValueError:
        raise ValueError(f"trial {name!r}: expected phenotype_<key>_<delta>, e.g. phenotype_height_0.20") from None


def shape_of(name: str) -> float | None:
    """The shape parameter of a trial name (None for an artifact trial)."""
    return float(name[len("shape_"):]) if name.startswith("shape_") else None


def load_settings(overrides: list[str] = ()) -> DictConfig:
    """The `robustness` node of conf/sweep/robustness.yaml with `robustness.*=...` overrides applied."""
    rob = OmegaConf.load(SWEEP_CONFIG).robustness
    dots = [o.split("robustness.", 1)[1] for o in overrides if o.lstrip("+").startswith("robustness.")]
    return OmegaConf.merge(rob, OmegaConf.from_dotlist(dots)) if dots else rob


def trial_body(body, name: str, rob: DictConfig, body_cfg: DictConfig | None = None):
    """The body of one trial: the sculpt at its shape parameter, the true body with painted weights, or (a
    phenotype trial) the body of `body_cfg`, an Anny config, with one phenotype value moved: another person
    on the same mesh connectivity, so the rest embedding stays valid."""
    pheno = phenotype_of(name)
    if pheno is not None:
        return phenotype_body(body, body_cfg, *pheno)
    t = shape_of(name)
    if t is not None:
        sc = OmegaConf.to_container(rob.sculpt, resolve=True)
        return shaped_body(body, sculpt_displacement(body, sc["bumps"], sc.get("part")), t)
    if name not in rob.artifacts:
        raise ValueError(f"unknown trial {name!r}; trials are {trial_names(rob)} and, on Anny, "
                         f"{phenotype_trials(rob)}")
    art = OmegaConf.to_container(rob.artifacts[name], resolve=True)
    return paint_weights(body, art["joint"], art["regions"])


def phenotype_body(body, body_cfg: DictConfig | None, key: str, delta: float):
    """The Anny body of `body_cfg` with phenotype `key` moved by `delta` (checked against its ranges)."""
    if body_cfg is None or str(body_cfg.get("kind")) != "anny":
        raise ValueError(f"trial phenotype_{key}_{delta:.2f} changes Anny's phenotype: run the study on Anny "
                         "(body=anny or body=anny_tpose), or drop the phenotype_* trials")
    # rounded: 0.7 - 0.2 is 0.49999999999999994 in floating point, outside a band that starts at 0.5
    value = round(float(body_cfg.phenotype.get(key, 0.5)) + delta, 9)
    moved = OmegaConf.merge(body_cfg, {"phenotype": {key: value}})
    other = body_from_config(moved)
    if other.vertices.shape != body.vertices.shape or not torch.equal(other.faces, body.faces):
        raise ValueError(f"the phenotype_{key}_{delta:.2f} body has another mesh than the dataset's body: the "
                         "dataset was made with another body config; pass the same body overrides as its data")
    return other


def make_trial_dataset(base_dir: Path, out: Path, body, info: dict) -> Path:
    """A dataset dir holding the base data's cloth (linked) and another body. Idempotent."""
    out.mkdir(parents=True, exist_ok=True)
    for name in LINKED:
        link = out / name
        if link.is_symlink() or link.exists():
            link.unlink()
        os.symlink((base_dir / name).resolve(), link)
    save_body(body, out / "body.npz")
    manifest = read_json(base_dir / "manifest.json", "dataset manifest")
    manifest["body_hash"] = hash_arrays(body.vertices, body.faces, body.weights, body.parts)
    manifest["robustness"] = {"base_dataset": str(base_dir.resolve()), **info}
    write_json(out / "manifest.json", manifest)  # written last: a dir with a manifest is complete
    return out


def make_bodies(base_dir: Path, sweep_dir: Path, rob: DictConfig, trials: list[str],
                body_cfg: DictConfig | None = None) -> dict[str, Path]:
    """One dataset dir per trial under <sweep_dir>/bodies/ (`body_cfg`: the base data's body config, which
    phenotype trials rebuild)."""
    base = load_dataset(base_dir)
    if base.shapes is not None:  # a trial swaps the one body its cloth was draped on: here there are several
        raise ValueError(f"{base_dir} was draped on {len(base.shapes)} people (data.body_shape): a robustness trial "
                         "re-skins one body's data on another body, so it needs a dataset of one body; make the "
                         "base data without data.body_shape (the phenotype trials move Anny's shape for you)")
    bodies = {name: trial_body(base.body, name, rob, body_cfg) for name in trials}  # every trial checked first
    dirs = {}
    for name, body in bodies.items():
        moved = (body.vertices - base.body.vertices).norm(dim=-1)
        painted = (body.weights - base.body.weights).abs().sum(1)
        info = {"trial": name, "shape": shape_of(name), "max_vertex_move_cm": float(moved.max()) * CM,
                "painted_vertices": int((painted > 1e-6).sum())}
        dirs[name] = make_trial_dataset(Path(base_dir), sweep_dir / "bodies" / name, body, info)
    return dirs


def selected_trials(rob: DictConfig, overrides: list[str] = ()) -> list[str]:
    """The trials a sweep runs: a `robustness.trial=a,b` override (Hydra's sweep grammar) replaces the
    sweep's list of every trial."""
    picked = [o.split("=", 1)[1] for o in overrides if o.lstrip("+").startswith("robustness.trial=")]
    return sweep_values("robustness.trial", picked[-1]) if picked else trial_names(rob)


def prepare_bodies(sweep_dir: Path, base_overrides: list[str], overrides: list[str] = ()) -> dict[str, Path]:
    """The runner's `bodies` step: one dataset dir per selected trial under <sweep_dir>/bodies/, from the base
    dataset that `base_overrides` (`+scale=...` and the data keys) select, which the `data` step made.

    overrides: the sweep's own (`robustness.*=...`, `robustness.trial=a,b`)."""
    rob = load_settings(overrides)
    base_cfg = load_config(["+experiment=whole", *base_overrides])
    base_dir = Path(base_cfg.data.dir)
    if not (base_dir / "manifest.json").is_file():
        raise FileNotFoundError(f"no base dataset at {base_dir}: the sweep's data step (python -m pbc.generate) "
                                "makes it")
    return make_bodies(base_dir, Path(sweep_dir), rob, selected_trials(rob, overrides), base_cfg.body)


# ----------------------------------------------------------------------------- report
def trial_runs(sweep_dir: Path) -> dict[str, Run]:
    """The sweep's trial runs by trial name (the newest when a trial ran twice)."""
    runs = [r for r in load_runs(sweep_dir, events=False) if r.get("robustness.trial") or r.cfg("robustness.trial")]
    return {str(r.get("robustness.trial") or r.cfg("robustness.trial")): r for r in runs}


def collect(sweep_dir: Path, runs: dict[str, Run], trials: list[str]) -> list[dict]:
    """Per trial: shape, train/test vertex error (cm) from its run record, or why there is none."""
    rows = []
    for name in trials:
        run = runs.get(name)
        row = {"trial": name, "shape": shape_of(name)}
        if run is None:
            row["status"] = "missing"
        else:
            row["status"] = run.status
            if run.status == OK:
                for split in ("train", "test"):
                    value = run.record.metric(split, VERTEX_ERROR)
                    row[f"{split}_cm"] = float("nan") if value is None else value
                row["seconds"] = run.record.seconds
            else:
                row["error"] = run.error
        body_m = sweep_dir / "bodies" / name / "manifest.json"
        if body_m.is_file():
            row["mean_baseline"] = mean_baseline(body_m.parent)
            row.update({k: v for k, v in read_json(body_m).get("robustness", {}).items()
                        if k in ("max_vertex_move_cm", "painted_vertices")})
        rows.append(row)
    return rows


def mean_baseline(data_dir: Path) -> dict:
    """The no-model baseline of one body (pbc.data.baselines): {train_cm, test_cm}. A model at this level has
    learnt nothing beyond the mean shape, and an unchanged error across bodies then says little."""
    errs = mean_shape_errors(load_dataset(data_dir), ("train", "test"))
    return {f"{k}_cm": v for k, v in errs.items()}


def verdict(rows: list[dict], factor: float) -> dict:
    """Does the test error stay within `factor` of the true body's (t = 0) for every trial?"""
    ok = [r for r in rows if r.get("status") == "ok" and np.isfinite(r.get("test_cm", np.nan))]
    ref = next((r for r in ok if r["shape"] == 0.0), None)
    if ref is None:
        return {"holds": None, "why": "the true body's trial (shape_0.0) did not finish"}
    ratios = {r["trial"]: r["test_cm"] / ref["test_cm"] for r in ok}
    worst = max(ratios, key=lambda k: abs(np.log(ratios[k])))
    holds = all(1 / factor <= v <= factor for v in ratios.values())
    return {"holds": bool(holds), "reference_test_cm": ref["test_cm"], "ratios": ratios, "worst": worst,
            "worst_ratio": ratios[worst], "factor": factor,
            "test_cm_range": [min(r["test_cm"] for r in ok), max(r["test_cm"] for r in ok)],
            "trials_done": len(ok), "trials": len(rows)}


def _shape_panel(ax, shp: list[dict], arts: list[dict]) -> None:
    """Fig. 9's sculpt panel: error against the shape parameter, artifact trials as separate markers."""
    x = [r["shape"] for r in shp]
    ax.plot(x, [r["train_cm"] for r in shp], "o-", label="train")
    ax.plot(x, [r["test_cm"] for r in shp], "s-", label="test")
    mb = [r.get("mean_baseline", {}).get("test_cm", np.nan) for r in shp]
    ax.plot(x, mb, "--", color="gray", lw=1, label="test, mean-offsets baseline (no model)")
    xa = max(x, default=2.0) + 0.6
    for i, r in enumerate(arts):
        ax.plot([xa + 0.35 * i] * 2, [r["train_cm"], r["test_cm"]], "k:", lw=0.8)
        ax.plot(xa + 0.35 * i, r["train_cm"], "o", color="C0")
        ax.plot(xa + 0.35 * i, r["test_cm"], "s", color="C1")
        ax.annotate(r["trial"], (xa + 0.35 * i, r["test_cm"]), fontsize=6, rotation=60,
                    xytext=(2, 4), textcoords="offset points")
    ax.axvline(0.0, color="gray", lw=0.6, ls="--")
    ax.set_xlabel("body shape parameter (0 = true body, 1 = sculpted); right: skinning artifacts", fontsize=8)
    ax.set_ylabel("mean vertex error (cm)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("sculpted bodies and painted skinning weights", fontsize=9)


def _phenotype_panel(ax, true_body: list[dict], pheno: list[dict]) -> None:
    """Fig. 9's Anny panel: the true body's error beside each phenotype trial's."""
    cats = true_body + pheno
    xs = np.arange(len(cats))
    ax.plot(xs, [r["train_cm"] for r in cats], "o", label="train")
    ax.plot(xs, [r["test_cm"] for r in cats], "s", label="test")
    ax.plot(xs, [r.get("mean_baseline", {}).get("test_cm", np.nan) for r in cats], "_", color="gray", ms=14,
            label="test, mean-offsets baseline")
    names = [phenotype_of(r["trial"]) for r in cats]
    ax.set_xticks(xs, ["true body" if n is None else f"{n[0]} {n[1]:+.2f}" for n in names], rotation=45,
                  ha="right", fontsize=7)
    ax.set_ylabel("mean vertex error (cm)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title("Anny: the same cloth skinned on another person (phenotype moved)", fontsize=9)


def fig9(path: Path, rows: list[dict]) -> Path:
    """Train and test vertex error against the shape parameter (artifact trials as separate markers), and the
    phenotype trials (Anny) in a panel of their own beside the true body's. The sculpt panel is left out when
    it would hold the true body alone (a phenotype study)."""
    import matplotlib  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    ok = [r for r in rows if r.get("status") == "ok"]
    shp = sorted((r for r in ok if r["shape"] is not None), key=lambda r: r["shape"])
    pheno = [r for r in ok if phenotype_of(r["trial"])]
    arts = [r for r in ok if r["shape"] is None and not phenotype_of(r["trial"])]
    left = len(shp) > 1 or bool(arts) or not pheno
    panels = int(left) + bool(pheno)
    fig, axes = plt.subplots(1, panels, figsize=(6 * panels, 3.8), squeeze=False)
    if left:
        _shape_panel(axes[0, 0], shp, arts)
    if pheno:
        _phenotype_panel(axes[0, -1], [r for r in shp if r["shape"] == 0.0], pheno)
    fig.suptitle("Fig. 9: error of models trained with wrong bodies", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def predict_on(run_dir: Path, data_dir: Path, index: int):
    """A trial model's prediction for dataset sample `index`: (pred (V, 3), gt (V, 3), pred/gt local offsets,
    posed trial body (Vb, 3), dataset)."""
    ds = load_dataset(data_dir)
    info = read_run(run_dir)
    net, hp = load_decoder(info.checkpoint)
    image_cfg = run_image_config(info)
    if image_cfg is None:
        raise ValueError(f"{run_dir}: metrics.json records no config.image (train the trial with pbc.train)")
    # the run's own image config and offset space: the operators exactly as its training built them
    target = make_target(ds, image_cfg, "whole", space=hp.get("space", "local"))
    pose = torch.from_numpy(np.array(ds.poses[index], np.float32))[None]
    with torch.inference_mode():
        img = net(pose.reshape(1, -1)).float()
    anchors, frames = target.skinner(pose)
    pred = target.positions(img, {"anchors": anchors, "frames": frames})
    gt = torch.from_numpy(np.array(ds.verts[index], np.float32))[None]
    return (pred[0], gt[0], to_offsets(pred, anchors, frames)[0], to_offsets(gt, anchors, frames)[0],
            pose_body(ds.body, pose)[0], ds)


def penetration(offsets: torch.Tensor) -> dict:
    """Cloth below the skinned body surface, from local offsets (V, 3): dn < 0 -> share and depth (cm)."""
    dn = offsets[..., 2]
    inside = dn < 0
    depth = -dn[inside] * CM if inside.any() else dn.new_zeros(1)
    return {"fraction": float(inside.float().mean()), "mean_depth_cm": float(depth.mean()),
            "max_depth_cm": float(depth.max())}


def _draw_scene(ax, body_v, body_f, cloth_v, cloth_f, title):
    """Front view of body and cloth in one painter's pass, so a body that pokes through the cloth shows."""
    tris, cols = [], []
    light = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    for v, f, base in ((body_v, body_f, (0.85, 0.65, 0.5)), (cloth_v, cloth_f, (0.35, 0.55, 0.9))):
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
        shade = 0.35 + 0.65 * np.abs(n @ light)
        tris.append(tri)
        cols.append(np.clip(np.asarray(base)[None] * shade[:, None], 0, 1))
    tri, col = np.concatenate(tris), np.concatenate(cols)
    order = np.argsort(tri[:, :, 2].mean(1))
    ax.add_collection(PolyCollection(tri[order][:, :, :2], facecolors=col[order], linewidths=0))
    ax.set_xlim(cloth_v[:, 0].min() - 0.05, cloth_v[:, 0].max() + 0.05)
    ax.set_ylim(cloth_v[:, 1].min() - 0.05, cloth_v[:, 1].max() + 0.12)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title(title, fontsize=8)


def fig10(path: Path, sweep_dir: Path, trials: list[str], index: int) -> dict:
    """Predictions on the thickest body and on the artifact body, with the body drawn through the cloth."""
    import matplotlib  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415 - Agg must be chosen before pyplot loads, only when plotting

    out, panels = {}, []
    for name in trials:
        run = sweep_dir / name
        if load_run(run, sweep_dir, events=False).status != OK:
            continue
        pred, gt, off_p, off_g, body_v, ds = predict_on(run, sweep_dir / "bodies" / name, index)
        out[name] = {"sample": int(index), "predicted": penetration(off_p), "ground_truth": penetration(off_g),
                     "vertex_error_cm": float((pred - gt).norm(dim=-1).mean()) * CM}
        panels.append((name, pred, gt, body_v, ds))
    if not panels:
        return out
    fig, axes = plt.subplots(1, 2 * len(panels), figsize=(3.3 * 2 * len(panels), 4.2), squeeze=False)
    for i, (name, pred, gt, body_v, ds) in enumerate(panels):
        bf, cf = ds.body.faces.numpy(), ds.garment.faces.numpy()
        # each panel states its own cloth's numbers: the error is the prediction's (against the simulation),
        # the penetration of each panel is of the cloth drawn in it
        p, g = out[name]["predicted"], out[name]["ground_truth"]
        _draw_scene(axes[0, 2 * i], body_v.numpy(), bf, pred.numpy(), cf,
                    f"{name}: prediction ({out[name]['vertex_error_cm']:.2f} cm error)\n"
                    f"{100 * p['fraction']:.0f}% of vertices below the body (dn<0)")
        _draw_scene(axes[0, 2 * i + 1], body_v.numpy(), bf, gt.numpy(), cf,
                    f"{name}: simulated cloth\n{100 * g['fraction']:.0f}% of vertices below the body (dn<0)")
    fig.suptitle("Fig. 10: predictions on wrong bodies (the body shows where it pokes through the cloth)",
                 fontsize=9)
    save_figure(fig, path, dpi=90)
    return out


def report(sweep_dir: Path, out_dir: Path | None = None) -> dict:
    """robustness.json / .md and Figs. 9-10 of a sweep dir, from its trial runs' records and body datasets;
    the settings are those the runs were configured with (their recorded `robustness` node)."""
    sweep_dir = Path(sweep_dir)
    out = Path(out_dir) if out_dir else sweep_dir
    runs = trial_runs(sweep_dir)
    recorded = next((r.cfg("robustness") for r in runs.values() if isinstance(r.cfg("robustness"), dict)), None)
    rob = OmegaConf.create(recorded) if recorded else load_settings()
    # the trials the multirun was launched with (a killed one is listed as missing), then any other run
    trials = expected_jobs(sweep_dir).get("robustness.trial") or trial_names(rob)
    trials = list(trials) + sorted(set(runs) - set(trials))
    rows = collect(sweep_dir, runs, trials)
    v = verdict(rows, float(rob.constant_factor))
    fig9(out / "fig9_error_vs_shape.png", rows)
    thick = max((r for r in rows if r["shape"] is not None and r.get("status") == OK),
                key=lambda r: r["shape"], default=None)
    shown = ([thick["trial"]] if thick else []) + [r["trial"] for r in rows
                                                    if r["shape"] is None and r.get("status") == OK][-1:]
    pen = fig10(out / "fig10_wrong_body.png", sweep_dir, shown, _test_sample(sweep_dir, shown, rob))
    scales = {r.get("scale") for r in runs.values()} - {None}
    record = sweep_dir / SWEEP_RECORD
    result = {"scale": ",".join(sorted(scales)) or None, "rows": rows, "verdict": v, "penetration": pen,
              "seconds": read_json(record).get("seconds") if record.is_file() else None,
              "settings": OmegaConf.to_container(rob, resolve=True)}
    write_json(out / "robustness.json", result)
    write_text(out / "robustness.md", markdown(result))
    return result


def build_report(sweep_dir: Path, out_dir: Path | None = None) -> Path:
    """The runner's report step for this sweep (what pbc.jobs.report.build_report is for the others)."""
    report(sweep_dir, out_dir)
    return Path(out_dir or sweep_dir) / "robustness.md"


def _test_sample(sweep_dir: Path, shown: list[str], rob: DictConfig) -> int:
    if not shown:
        return 0
    m = read_json(sweep_dir / "bodies" / shown[0] / "manifest.json", "dataset manifest")
    test = m["splits"]["test"] or m["splits"]["train"]
    return int(test[min(int(rob.figure_sample), len(test) - 1)])


def markdown(res: dict) -> str:
    v = res["verdict"]
    lines = [f"# The wrong-body study (appendix D.2) at scale={res['scale']}", "",
             "Same simulated cloth in every trial; only the body used for skinning and embedding changes.", "",
             "| trial | shape t | body change | train cm | test cm | test / true body "
             "| mean-offsets baseline: train / test cm |",
             "|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        pheno = phenotype_of(r["trial"])
        change = (f"max {r.get('max_vertex_move_cm', 0):.1f} cm move" if r["shape"] is not None
                  else f"phenotype {pheno[0]} {pheno[1]:+.2f}, max {r.get('max_vertex_move_cm', 0):.1f} cm move"
                  if pheno else f"{r.get('painted_vertices', 0)} vertices repainted")
        if r.get("status") == "ok":
            ratio = v.get("ratios", {}).get(r["trial"])
            mb = r.get("mean_baseline", {})
            base = f"{mb.get('train_cm', float('nan')):.3f} / {mb.get('test_cm', float('nan')):.3f}"
            lines.append(f"| {r['trial']} | {'' if r['shape'] is None else r['shape']} | {change} | "
                         f"{r['train_cm']:.3f} | {r['test_cm']:.3f} | {'' if ratio is None else f'{ratio:.3f}'} | "
                         f"{base} |")
        else:
            lines.append(f"| {r['trial']} | {r['shape']} | {change} | {r.get('status')} | {r.get('error', '')} | |")
    lines.append("")
    if v.get("holds") is None:
        lines.append(f"Verdict: undecided ({v.get('why')}).")
    else:
        lines.append(f"Verdict: the test error {'stays' if v['holds'] else 'does NOT stay'} roughly constant "
                     f"(within x{v['factor']} of the true body's {v['reference_test_cm']:.3f} cm): range "
                     f"{v['test_cm_range'][0]:.3f}-{v['test_cm_range'][1]:.3f} cm over {v['trials_done']} of "
                     f"{v['trials']} trials; the farthest is {v['worst']} at x{v['worst_ratio']:.3f}.")
    ok = [r for r in res["rows"] if r.get("status") == "ok" and r.get("mean_baseline", {}).get("test_cm")]
    if ok:
        gain = [r["mean_baseline"]["test_cm"] - r["test_cm"] for r in ok]
        lines.append(f"The models beat the mean-offsets baseline on the test split by {min(gain):.3f} to "
                     f"{max(gain):.3f} cm" + (" (they learnt little beyond the mean shape: the verdict is weak "
                                              "evidence at this scale)." if max(gain) < 0.1 else "."))
    for name, p in res.get("penetration", {}).items():
        lines.append(f"- {name}, sample {p['sample']}: {100 * p['predicted']['fraction']:.1f}% of the predicted "
                     f"cloth lies below the wrong body's surface (mean {p['predicted']['mean_depth_cm']:.2f} cm, "
                     f"max {p['predicted']['max_depth_cm']:.2f} cm; simulated cloth: "
                     f"{100 * p['ground_truth']['fraction']:.1f}%), vertex error {p['vertex_error_cm']:.2f} cm.")
    if res.get("seconds"):
        lines.append(f"\nWall time: {res['seconds']:.0f} s.")
    lines += ["", "![Fig. 9](fig9_error_vs_shape.png)", "", "![Fig. 10](fig10_wrong_body.png)", ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- entry point
