"""Pack a trained whole-shirt run as a pretrained model (`pbc pretrained pack RUN --name NAME`): into the user's
models folder (pbc.pretrained.user_models_dir), where `--pretrained NAME` finds it before a shipped model of the
same name. A shipped model's folder, or a name that would shadow one, is written only when asked (`force`); the
model is written whole or not at all, and a model it replaces is kept beside it (`previous_path`).

What a fresh clone needs to predict, score and flag poses without the dataset (pbc.pretrained says the
layout): the network's weights in half precision (a checkpoint of the state dict only: 3.8M parameters are
7.6 MB instead of 15 MB, and the optimiser state is dropped), the dataset cut to its test split with the
training split's range and mean offsets (pbc.data.trimmed), a run record pointing at that data, and a
model card. The scores on the card are measured on the packed files themselves: the fp16 weights loaded
the way a user loads them, on the shipped test poses, beside the training mean shape on the same poses.
"""

from __future__ import annotations

import os
import platform
import subprocess
import time
import zipfile
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from pbc.core.io import atomic_dir, load_checkpoint, write_text
from pbc.core.runs import VERTEX_ERROR, ModelKind, RunRecord, monitor, read_run
from pbc.data.dataset import dataset_fingerprint, load_dataset, person_kw
from pbc.data.trimmed import check_max_rows, is_trimmed, recorded_mean_offsets, trim_dataset
from pbc.inference.poses import training_pose_range
from pbc.inference.predictor import WHOLE_KINDS, ClothPredictor
from pbc.motion.ranges import SWING_TWIST, range_from_record, range_table_record
from pbc.pixels.frames import from_offsets
from pbc.pretrained import in_shipped_dir, is_model_name, shipped_model_dir, shipped_models, user_models_dir

WEIGHTS = "weights_fp16.ckpt"
CARD = "MODEL_CARD.md"
DATA = "data"
CM = 100.0
PREVIOUS = ".previous-"  # a model a pack replaces is kept beside it as <name>.previous-<time>
ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the weights file's entries' timestamp (zip's earliest): packing is repeatable


def half_state(state: dict) -> dict:
    """A network state dict with every floating tensor in float16. The standardisation buffers too: the mean
    image alone is 1.6 MB in float32 (6 x 256 x 256), which would take the shirt's weights past 8 MB, and
    fp16 keeps 11 bits (0.006 cm at a 10 cm offset)."""
    return {k: (v.half() if v.is_floating_point() else v).clone() for k, v in state.items()}


def save_deflated(obj, path: Path) -> None:
    """`torch.save`, its zip entries then deflated: torch.load reads either. The mean image (mostly the
    padding around the charts) and the fp16 exponents compress, taking the shirt's 3.8M parameters + 0.4M
    buffer values from 8.4 to about 7.1 MB, under the 8 MB a clone should carry. Every entry gets one fixed
    timestamp, so packing the same weights again writes the same bytes (a tracked shipped model does not
    change in git when only its card or record is made again)."""
    tmp = path.with_suffix(".tmp")
    torch.save(obj, tmp)
    with zipfile.ZipFile(tmp) as zi, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zo:
        for entry in zi.infolist():
            info = zipfile.ZipInfo(entry.filename, date_time=ZIP_TIME)
            info.compress_type, info.external_attr = zipfile.ZIP_DEFLATED, entry.external_attr
            zo.writestr(info, zi.read(entry.filename), compresslevel=9)
    tmp.unlink()


def network_words(hparams: dict) -> str:
    """What the packed network is, in words for the card: the whole-garment image CNN, or the fully connected
    net and what it outputs (PCA coefficients or every vertex) in which offset space."""
    net, space = hparams.get("net") or {}, hparams.get("space", "local")
    if hparams.get("kind") == ModelKind.FC.value:
        hidden = " x ".join(str(int(h)) for h in net.get("hidden", ()))
        out = (f"{int(net.get('num_components', 0))} PCA coefficients" if net.get("mode") == "pca"
               else "every vertex's 3 values")
        return f"a fully connected net (hidden {hidden}) predicting {out} of the {space} offsets"
    return f"the whole-garment CNN (its {space} offsets as a cloth image)"


def mean_training_offsets(pred: ClothPredictor, batch: int = 64) -> torch.Tensor:
    """(V, 3) mean of the training split's offsets in the predictor's space (the training mean shape;
    float64 sum, as pbc.data.baselines)."""
    ds = pred.dataset
    idx = ds.split("train")
    if len(idx) == 0:
        raise ValueError(f"dataset {ds.dir} has no training samples: no mean shape to ship")
    total = None
    with torch.inference_mode():
        for i in range(0, len(idx), batch):
            j = idx[i:i + batch]
            off = pred.offsets_of(torch.from_numpy(np.asarray(ds.poses[j], np.float32)),
                                  torch.from_numpy(np.asarray(ds.verts[j], np.float32)), **person_kw(ds, j))[0]
            s = off.sum(0, dtype=torch.float64)
            total = s if total is None else total + s
    return (total / len(idx)).float()


def score(pred: ClothPredictor, poses: torch.Tensor, verts: torch.Tensor, mean: torch.Tensor,
          batch: int = 16) -> dict[str, np.ndarray]:
    """Per-pose mean vertex error (cm) of the model and of the training mean shape `mean` (V, 3) against
    `verts` (N, V, 3), and the model's positions (N, V, 3)."""
    model, base, pos = [], [], []
    with torch.inference_mode():
        for i in range(0, len(poses), batch):
            p, v = poses[i:i + batch], verts[i:i + batch]
            x = pred(p, model="whole")
            anchors, frames = pred.frames(p)
            m = from_offsets(mean.expand(len(p), -1, -1), anchors, frames, pred.space)
            model.append((x - v).norm(dim=-1).mean(1) * CM)
            base.append((m - v).norm(dim=-1).mean(1) * CM)
            pos.append(x)
    return {"model": torch.cat(model).numpy(), "mean_shape": torch.cat(base).numpy(),
            "positions": torch.cat(pos)}


def discarded_count(manifest: dict) -> int:
    """Samples the generation discarded (the manifest counts them per reason)."""
    d = (manifest.get("counts") or {}).get("discarded") or 0
    return int(sum(d.values()) if isinstance(d, dict) else d)


def git_commit(where: Path) -> str:
    """The checkout's commit (+ "-dirty" with uncommitted changes), or "unknown" outside a git checkout."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("-dirty" if dirty else "")


def this_machine() -> str:
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return f"{os.cpu_count()} CPU cores ({platform.machine()}), {gpu}"


def shipped_pose_range(run, ds) -> tuple[dict, str]:
    """The joint-angle range of the run's training poses to ship (RunRecord.pose_range) and where it came
    from: the run's own swing-twist record, or (a run trained before runs recorded it, or that recorded Euler
    angles, whose box misreads hanging arms: pbc.motion.ranges) measured here from its dataset's training
    split."""
    names = ds.body.skeleton.names
    recorded = range_from_record(run.record.pose_range, names)
    if recorded is not None and (recorded.chart == SWING_TWIST or is_trimmed(ds)):
        return run.record.pose_range, "recorded by the training run (its metrics.json pose_range)"
    rng = training_pose_range(ds)
    why = "the run predates the recorded range" if recorded is None else "the run recorded Euler angles"
    return (range_table_record(rng, names, len(ds.split("train"))),
            f"measured by pbc pretrained pack from the run's dataset, swing-twist ({why})")


def pack_destination(name: str, out: str | Path | None = None, force: bool = False) -> Path:
    """The folder `pbc pretrained pack` writes model `name` into: `out`, else the user's models folder's
    <name>. Without `force` it refuses (a ValueError in one line, naming the shipped model and the fix) a folder
    inside pbc's shipped models, and a folder of the user's models named as a shipped model (it would shadow
    it). With `force`, `out` is written where it says and the default is the user's folder, never the package."""
    dest = Path(out) if out is not None else user_models_dir() / name
    if force:
        return dest
    if in_shipped_dir(dest):
        raise ValueError(f"--out {dest} is inside pbc/pretrained, the models shipped with pbc, which pack does not "
                         f"overwrite: leave --out out to pack into your models ({user_models_dir()}), or add --force "
                         "to replace the package's copy (re-making a shipped model in a checkout)")
    if dest.name in shipped_models() and dest.parent.resolve() == user_models_dir().resolve():
        raise ValueError(f"{dest.name!r} is a model shipped with pbc ({shipped_summary(dest.name)}): give yours "
                         f"another --name, or add --force to pack it as your own {dest.name!r} in {dest}, where it "
                         "shadows the shipped one (whose files stay as they are)")
    return dest


def shipped_summary(name: str) -> str:
    """The shipped model `name` in a few words: its folder and test error, from its record."""
    folder = shipped_model_dir(name)
    info = RunRecord.read(folder).extra.get("pretrained", {})
    if info.get("test_vertex_error_cm") is None:
        return str(folder)
    return f"{folder}, {info['test_vertex_error_cm']} cm over {info.get('test_poses')} test poses"


def previous_path(dest: Path, stamp: str) -> Path:
    """Where a model already at `dest` is kept when a pack replaces it: `<dest>.previous-<stamp>` beside it (a
    name no model has, so `--pretrained` never finds it), with `-2`, `-3`, ... when that one is taken."""
    kept, n = dest.with_name(f"{dest.name}{PREVIOUS}{stamp}"), 1
    while kept.exists() or kept.is_symlink():
        n += 1
        kept = dest.with_name(f"{dest.name}{PREVIOUS}{stamp}-{n}")
    return kept


def pack_run(run_dir: str | Path, name: str, out: str | Path | None = None, data_dir: str | Path | None = None,
             trained_on: str | None = None, command: str | None = None, commit: str | None = None,
             notes: str | Path | None = None, test_poses: int | None = None, force: bool = False) -> dict:
    """Pack the whole-shirt run `run_dir` as model `name` into `out` (default: the user's models folder's
    <name>; `pack_destination` says what is refused without `force`). The model is written in a folder beside
    `out` and renamed onto it when whole: a pack that fails leaves no part of it. A folder already at `out` is
    kept, renamed to `previous_path(out, ...)`, except a shipped model's (forced), which is replaced.

    data_dir: the run's dataset when it moved; trained_on: the training machine in words (the run records none;
    default: its trainer.accelerator and this machine); command: how the run was made (for the card); commit: the
    code the run was trained with (the run records none; default: this checkout's, which packs it); notes: a
    markdown file whose text the card carries after its table (where the data came from, its licence, what was
    measured beyond the test split); test_poses: ship and score the first this many poses of the test split
    (None: all; the split's drapes are most of a model's bytes). Returns the card's numbers (also metrics.json's
    "pretrained" block), with `dir` (where the model is) and `previous` (where the model it replaced is kept;
    None when none is kept) added."""
    t0 = time.time()
    if not is_model_name(name):
        raise ValueError(f"--name {name!r}: give a plain name (letters, digits, - or _), e.g. tshirt")
    dest = pack_destination(name, out, force)  # before anything is read or written
    check_max_rows(test_poses, "test", "--test-poses")
    note_text = _read_notes(notes)
    run = read_run(run_dir)
    if run.kind.value not in WHOLE_KINDS:
        raise ValueError(f"{run.path}: a {run.kind.value!r} run; only a whole-garment run (a whole-shirt CNN or a "
                         "fully connected run) packs as a shipped model")
    full = ClothPredictor.from_runs(run.path, data_dir=data_dir)
    full.mend = None  # a model's scores are of its own output (pbc evaluate's too)
    # a shipped model's folder (forced) is replaced: git or a reinstall has the old one, and a copy kept there ships
    previous = None if in_shipped_dir(dest) else previous_path(dest, time.strftime("%Y%m%d-%H%M%S"))
    with atomic_dir(dest, previous) as staging:
        info = _write_model(staging, name, run, full, trained_on, command, commit, note_text, test_poses,
                            made_again=_pack_words(name, out, force))
        info["pack_seconds"] = round(time.time() - t0, 1)
        _write_card(staging, info)
    info["dir"], info["previous"] = dest, previous if previous is not None and previous.exists() else None
    return info


def _pack_words(name: str, out, force: bool) -> str:
    """The card's `pbc pretrained pack` arguments after the run: how this very destination is written again."""
    words = f"--name {name}"
    if out is not None and in_shipped_dir(out):
        words += f" --out pbc/pretrained/{Path(out).name}"
    return words + (" --force" if force else "")


def _write_model(out: Path, name: str, run, full: ClothPredictor, trained_on, command, commit, note_text,
                 test_poses, made_again: str) -> dict:
    """Write the model of `run` (opened as `full`) into the empty folder `out`: fp16 weights, the trimmed data,
    the record; its numbers measured on those files (pack_run's card numbers, less pack_seconds)."""
    ds = full.dataset
    ck = load_checkpoint(run.checkpoint)
    net_state = {k: v for k, v in ck["state_dict"].items() if k.startswith("net.")}
    (out / "checkpoints").mkdir(parents=True)
    save_deflated({"state_dict": half_state(net_state), "hyper_parameters": ck["hyper_parameters"],
                   "pbc_pretrained": {"name": name, "source_checkpoint": run.checkpoint.name}},
                  out / "checkpoints" / WEIGHTS)
    mean = mean_training_offsets(full)
    pose_range, range_source = shipped_pose_range(run, ds)
    trim_dataset(ds, out / DATA, range_from_record(pose_range, ds.body.skeleton.names), mean, full.space, "test",
                 test_poses)
    shipped = load_dataset(out / DATA)
    record = run.record
    info = {
        "name": name, "kind": run.kind.value, "network": network_words(ck["hyper_parameters"]),
        "source_run": str(Path(run.path).resolve()), "source_checkpoint": run.checkpoint.name,
        "dataset": {"dir": str(Path(ds.dir).resolve()), "name": Path(ds.dir).name,
                    "fingerprint": dataset_fingerprint(ds), "kept": int(len(ds)),
                    "mirrored": int((ds.manifest.get("counts") or {}).get("mirrored") or 0),
                    "discarded": discarded_count(ds.manifest),
                    "splits": {s: int(len(ds.split(s))) for s in ("train", "val", "test")},
                    "num_vertices": int(len(ds.garment.vertices))},
        "epochs": record.epochs, "train_seconds": record.seconds,
        "schedule": {k: OmegaConf.select(OmegaConf.create(run.config), k) for k in
                     ("trainer.max_epochs", "model.optimizer.lr", "datamodule.batch_size", "model.scheduler")},
        "trained_on": trained_on or f"trainer.accelerator={run.cfg('trainer.accelerator', '?')} (the run records "
                                    f"no machine; packed on {this_machine()})",
        "commit": commit or f"{git_commit(Path(__file__).parent)} (the checkout that packed it)",
        "command": command,
        # every float the state dict holds: weights and BatchNorm statistics, and the standardisation buffers
        "parameters": int(sum(v.numel() for v in net_state.values() if v.is_floating_point())),
        "recorded_fp32_test_vertex_error_cm": record.metric("test", VERTEX_ERROR),
        "pose_range_source": range_source,
        "notes": note_text,
        "pack_arguments": made_again,
    }
    RunRecord(kind=run.kind, optimized_metric=monitor(run.kind), best_checkpoint=WEIGHTS,
              identity=dict(run.identity), config=dict(run.config), epochs=record.epochs, seconds=record.seconds,
              data={"dir": DATA, "fingerprint": dataset_fingerprint(shipped)}, pose_range=pose_range,
              extra={"pretrained": info}).write(out)
    # the scores of what ships: the packed folder opened as a user opens it, fp16 weights and trimmed data
    packed = ClothPredictor.from_runs(out)
    packed.mend = None
    mean_back, _ = recorded_mean_offsets(packed.dataset)
    poses = torch.from_numpy(np.array(shipped.poses, np.float32))
    verts = torch.from_numpy(np.array(shipped.verts, np.float32))
    s16 = score(packed, poses, verts, mean_back)
    s32 = score(full, poses, verts, mean)
    diff = (s16["positions"] - s32["positions"]).norm(dim=-1)
    info.update({
        "test_poses": int(len(poses)),
        "test_split_poses": int(len(ds.split("test"))),
        "test_vertex_error_cm": round(float(s16["model"].mean()), 4),
        "test_vertex_error_cm_std": round(float(s16["model"].std()), 4),
        "mean_shape_test_vertex_error_cm": round(float(s16["mean_shape"].mean()), 4),
        "fp32_test_vertex_error_cm": round(float(s32["model"].mean()), 4),
        "fp16_vs_fp32_max_vertex_cm": round(float(diff.max()) * CM, 4),
        "fp16_vs_fp32_mean_vertex_cm": round(float(diff.mean()) * CM, 5),
        "poses_beating_mean_shape": int((s16["model"] < s16["mean_shape"]).sum()),
    })
    return info


def _write_card(out: Path, info: dict) -> None:
    """Complete the model in `out`: its sizes into `info`, `info` into the record, and MODEL_CARD.md."""
    sizes = {str(p.relative_to(out)): p.stat().st_size for p in sorted(out.rglob("*")) if p.is_file()}
    info["bytes"] = {"weights": sizes[f"checkpoints/{WEIGHTS}"], "data": sum(v for k, v in sizes.items()
                                                                            if k.startswith(DATA + "/"))}
    rec = RunRecord.read(out)
    rec.test = {VERTEX_ERROR: info["test_vertex_error_cm"], f"{VERTEX_ERROR}_std": info["test_vertex_error_cm_std"]}
    rec.extra["pretrained"] = info
    rec.write(out)
    write_text(out / CARD, model_card(info, rec.pose_range))
    info["bytes"]["total"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())


def _read_notes(notes) -> str | None:
    if notes is None:
        return None
    try:
        return Path(notes).read_text().strip()
    except OSError as exc:
        raise ValueError(f"--notes {notes}: cannot read it ({exc.strerror}); give a markdown file for the "
                         "card") from None


def model_card(i: dict, pose_range: dict | None = None) -> str:
    """MODEL_CARD.md from the numbers `pack_run` measured, and the training poses' range (RunRecord.pose_range)."""
    d, sch, n = i["dataset"], i["schedule"], i["test_poses"]
    split_n = i.get("test_split_poses", n)
    which = f"the {n} test poses" if split_n == n else f"the first {n} of the {split_n} test poses"
    sched = "none" if not sch["model.scheduler"] else "yes (metrics.json config)"
    rows = [
        ("network", i.get("network") or "the whole-garment CNN"),
        ("data", f"`{d['name']}`: {d['kept'] - d.get('mirrored', 0)} drapes kept ({d['discarded']} discarded by the "
                 "distortion check)" + (f" and {d['mirrored']} mirror images of training drapes" if d.get("mirrored")
                                        else "") + f", the {d['num_vertices']:,}-vertex garment; splits train "
                 f"{d['splits']['train']} / val {d['splits']['val']} / test {d['splits']['test']}"),
        ("training", f"{i['epochs']} epochs (trainer.max_epochs {sch['trainer.max_epochs']}), lr "
                     f"{sch['model.optimizer.lr']}, batch {sch['datamodule.batch_size']}, scheduler {sched}; "
                     f"{_time(i['train_seconds'])}"),
        ("device", i["trained_on"]),
        ("commit", i["commit"]),
        ("weights", f"{i['parameters']:,} parameter and buffer values in float16, a deflated torch file: "
                    f"{i['bytes']['weights'] / 1e6:.2f} MB"),
        ("test vertex error", f"**{i['test_vertex_error_cm']:.3f} cm** (std {i['test_vertex_error_cm_std']:.3f}) "
                              f"over {which}, fp16 weights"),
        ("training mean shape", f"{i['mean_shape_test_vertex_error_cm']:.3f} cm on the same poses (the training "
                                "split's mean offsets, skinned)"),
        ("fp16 vs fp32", f"fp32 checkpoint {i['fp32_test_vertex_error_cm']:.3f} cm; positions differ by "
                         f"{i['fp16_vs_fp32_mean_vertex_cm']:.4f} cm mean, {i['fp16_vs_fp32_max_vertex_cm']:.4f} "
                         "cm at most"),
        ("beats the mean shape", f"on {i['poses_beating_mean_shape']} of {n} test poses"),
        ("training pose range", f"{i.get('pose_range_source') or 'not recorded'}; per joint below"),
    ]
    table = "\n".join(f"| {k} | {v} |" for k, v in rows)
    notes = f"{i['notes']}\n\n" if i.get("notes") else ""
    made = i["command"] or "python -m pbc.main   # the README's main job: data, whole model, patch 7"
    return f"""# Shipped model `{i['name']}`: {i.get('network') or 'the whole-garment CNN'}

Load it with `pbc predict --pretrained {i['name']} --poses test`, `pbc view --pretrained {i['name']}`,
`pbc evaluate whole_run=pretrained:{i['name']} patch_runs=null` or
`ClothPredictor.from_pretrained("{i['name']}")`. Written by `pbc pretrained pack` (pbc/pretrained/pack.py);
every number here was measured by it on the packed files.

| | |
| --- | --- |
{table}

{notes}The model saw {d['splits']['train']} training rows: far from the paper's 16K (0.44 cm there). A clip's frame
farther from every training pose (`data/known_poses.npy`, over the joints the model reads) than its own test poses
are is flagged by `pbc predict --poses clip.bvh` and `pbc view --sequence clip.bvh`, and guarded by default: turned
towards its nearest training pose to that limit, its joints clamped into the range below (`--guard`; pbc.motion.known).
{range_section(pose_range)}
What ships beside the weights (`data/`): the garment, cage, body and embedding of the run's dataset, the
{n} test poses with their draped vertices (`--poses test`), and of the training split its mean
offsets (the baseline), joint-angle range and poses (float16). Only the whole model ships: no patch models.

## Made again

```bash
{made}
pbc pretrained pack runs/main/latest/whole {i.get('pack_arguments') or '--name ' + i['name']}
```

Source run: `{i['source_run']}` ({i['source_checkpoint']}); dataset manifest hash
`{d['fingerprint'].get('manifest_hash')}`, seed {d['fingerprint'].get('seed')}.
"""


def range_section(pose_range: dict | None) -> str:
    """The card's table of the training poses' joint angles: [min, max] degrees per joint and axis."""
    if not pose_range:
        return ""
    rows = "\n".join(f"| {j} | " + " | ".join(f"{lo:.1f} to {hi:.1f}" for lo, hi in (axes[a] for a in "xyz")) + " |"
                     for j, axes in pose_range["deg"].items())
    return f"""
## Training poses' joint angles

[min, max] degrees over the {pose_range['poses']} poses of the {pose_range['split']} split, per joint and axis:
{pose_range['angles']}. A clip's frame with a joint whose rotation is more than `range_tolerance_deg`
(conf/motion/sequence.yaml) from every rotation these angles hold is moved to the nearest one by the guard
(`--guard nearest` or `range`).

| joint | x | y | z |
| --- | --- | --- | --- |
{rows}
"""


def _time(seconds) -> str:
    if seconds is None:
        return "training time not recorded"
    return f"{float(seconds) / 60:.1f} min of training"
