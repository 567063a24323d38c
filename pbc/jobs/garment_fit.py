"""`pbc garment fit`: from a garment file (an OBJ, or MakeHuman's `.mhclo`) to a trained whole-garment model and
a preview in one command. The steps, each skipped when its output is complete, so a second call
resumes where the first stopped:

  1. inspect  the chart table and the settings it suggests (pbc.geometry.inspect) -> inspect/; the suggested
              garment.charts / garment.uv_unit fill what the overrides leave unset, and a garment centred below
              the waist on a body with legs gets the legs' data set and the lower body's wrap
  2. checks   the import and the shrink-wrap on the rest body, where every check before a drape runs
              (pbc.geometry.garment.checks: the UV unit, the sleeves against the rest arms, far from the body, the
              wrap's
              stretch; one error naming the part, the number and the fix), and the automatic cage -> cage.json
  3. data     python -m pbc.generate with the garment overrides and data.num_samples -> data/
  4. whole    python -m pbc.train +experiment=whole with the SAME overrides -> whole/
  5. preview  python -m pbc.predict whole/ --poses test -> preview/ (meshes, contact sheet)

then a summary: where everything is, and the test error beside the training mean shape's. ``--until STEP`` stops
after that step (`checks`: every check before a drape; `data`: the drapes, to train by hand or in a sweep); the same
command without it goes on from there. Steps 3-5 are the
commands a user would type, each its own process with its own Hydra run dir (as the main job's steps), run by
the sweep runner's `run_logged`: the whole output goes to logs/<step>.log, and only the progress lines (the
drapes done with their ETA, one line per epoch with its ETA) are echoed. fit.json records what the fit was
asked and the overrides it settled on; an out dir holding another garment's fit (its drapes) is refused, one
whose fit was refused before any drape is taken by a corrected retry.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import shlex
import sys
import time
from pathlib import Path

from pbc.core import stops
from pbc.core.config import load_config
from pbc.core.io import read_json, require_writable_dir, write_json, write_text
from pbc.core.runs import OK, RunRecord
from pbc.core.validate import check_config
from pbc.data.baselines import mean_shape_errors
from pbc.data.dataset import load_dataset
from pbc.data.generate import scene_garment
from pbc.geometry.body import body_from_config
from pbc.geometry.cage.base import save_cage
from pbc.geometry.garment.mhclo import mhclo_mesh
from pbc.geometry.garment.obj_import import UNWRAP_FIX
from pbc.geometry.garment.outfit import TOP_Y
from pbc.geometry.garment.placement import hem, openings
from pbc.geometry.inspect import format_report, inspect_garment, made_on_override, save_body_picture, save_uv_picture
from pbc.geometry.meshio import obj_mesh_text
from pbc.geometry.shrinkwrap import shrinkwrap
from pbc.jobs.sweeps import run_logged
from pbc.models.progress import duration

STEPS = ("inspect", "checks", "data", "whole", "preview")
RECORD = "fit.json"
# what a second call must be asked the same as the first to resume it
ASKED = ("garment", "sha256", "overrides", "samples", "epochs")
# a garment centred below the waist (pbc.geometry.inspect.TOP_Y) on a body with these joints: the legs' data
# set (hips and knees posed: conf/data/skirt_small.yaml) and the lower body's wrap (no arm colliders: the hips
# reach past the arm joints' x), as the procedural skirt's
LEG_JOINTS = ("l_hip", "r_hip", "l_knee", "r_knee")
LOWER_BODY = ("data=skirt_small", "++garment.shrinkwrap.arm_parts=false")
# trousers (a bottom with three openings or more: a waistband and two legs) drape with the trousers' own preset:
# the ankles posed, a softer body contact and a trouser-weight fabric (conf/data/trousers_small.yaml)
TROUSERS_DATA = "data=trousers_small"
# a dress (a top whose hem hangs past the hips) drapes with the trunk, the arms, the hips and the knees posed
DRESS_DATA = "data=dress_small"
# the progress lines of the steps' own output: generate's drape count (with its ETA) and training's epoch line
# (with its ETA), after the log prefix
PROGRESS = re.compile(r"(drape \(\d+ workers?\): \d+/\d+.*|epoch \d+/\d+ .*)$")
# a Hydra override value that needs no quotes
PLAIN = re.compile(r"[\w./+-]+")
CHART_NAME = re.compile(r"[A-Za-z_][\w-]*")


def _key(override: str) -> str:
    return override.lstrip("+~").split("=", 1)[0]


def _value(path: Path) -> str:
    # Hydra's override grammar reads '=', ',' or a space in a path as syntax unless quoted
    return str(path) if PLAIN.fullmatch(str(path)) else f"'{path}'"


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def garment_overrides(path: Path, overrides: list[str]) -> list[str]:
    """The overrides that load the garment file: an OBJ (garment=obj) or MakeHuman clothes (garment=mhclo, on
    Anny unless the overrides name a body: they fit its base mesh only)."""
    path = Path(path).resolve()
    suffix = path.suffix.lower()
    if suffix == ".mhclo":
        body = [] if any(_key(o) == "body" for o in overrides) else ["body=anny"]
        return ["garment=mhclo", f"garment.path={_value(path)}", *body]
    if suffix != ".obj":
        raise ValueError(f"{path}: a garment file is an .obj or a MakeHuman .mhclo (its .obj beside it)")
    return ["garment=obj", f"garment.obj={_value(path)}"]


def inspect_file(garment: Path, cfg, body, folder: Path, wrap: bool = True):
    """`inspect_garment` of a garment file loaded by `garment_overrides` (cfg), with `folder/fitted.obj`, the garment
    as placed on the rest body (what the checks and the drapes see): an OBJ placed by pbc.geometry.garment.placement
    (written after the report); MakeHuman clothes as fitted to `body` (written first, then inspected)."""
    if cfg.garment.get("kind") != "mhclo":
        report = inspect_garment(garment, cfg.garment, body, wrap=wrap)
        write_text(Path(folder) / "fitted.obj", obj_mesh_text(report.mesh, f"{Path(garment).name} placed on the "
                                                              "rest body by pbc garment (metres)"))
        return report
    mesh, _ = mhclo_mesh(cfg.garment, body)
    fitted = Path(folder) / "fitted.obj"
    write_text(fitted, obj_mesh_text(mesh, f"{Path(garment).name} fitted to the body by pbc garment"))
    return inspect_garment(fitted, cfg.garment, body, wrap=wrap)


def empty_splits(manifest: dict, log: Path) -> str | None:
    """What to do when the drapes a dataset kept (its manifest) leave a split empty, else None: with nothing to
    validate or test on, the training would stop on a NaN loss and the preview on an empty split minutes later."""
    empty = [name for name, ids in manifest.get("splits", {}).items() if not ids]
    if not empty:
        return None
    counts = manifest.get("counts", {})
    kept, asked = int(counts.get("kept", 0)), int(counts.get("requested", 0))
    why = ", ".join(f"{k} {v}" for k, v in (counts.get("discarded") or {}).items()) or "none discarded"
    more = math.ceil(3 * max(asked, 1) / max(kept, 1)) + 1
    return (f"only {kept} of {asked} drapes were kept ({why}), which leaves split(s) {', '.join(empty)} empty: a "
            f"fit needs a drape in each of train, val and test. Ask for more (--samples {more}), or see why drapes "
            f"are discarded in {log}")


def is_dress(report, body, below: float) -> bool:
    """Whether the inspected garment (`inspect_garment`'s report) is a dress: a top (a collar above its other
    openings) whose hem (`hem`) hangs more than ``below`` m under the body's hip joints, on a body with legs."""
    names = list(body.skeleton.names)
    if not set(LEG_JOINTS) <= set(names) or (report.placement is not None and report.placement.kind != "top"):
        return False
    ops = openings(report.positions, report.faces)
    if len(ops) < 3:  # a skirt or a tube: two openings
        return False
    hips = body.skeleton.rest_heads[[names.index("l_hip"), names.index("r_hip")], 1].double().numpy()
    return float(hem(ops)["centre"][1]) < float(hips.min()) - below


def default_out(path: Path, root: Path, overrides: list[str] = ()) -> Path:
    """Where a fit goes without --out: `<root>/runs/fit/<garment name>` (fixed, so a second call resumes), and
    `<name>_<piece>` for one piece of an outfit (`garment.piece=top`), so its pieces' fits do not collide."""
    pieces = [o.split("=", 1)[1] for o in overrides if _key(o) == "garment.piece" and "=" in o]
    piece = pieces[-1].strip("'\"") if pieces else ""
    name = Path(path).stem + (f"_{piece}" if piece and piece not in ("all", "null") else "")
    return Path(root) / "runs" / "fit" / name


class Fit:
    """One `pbc garment fit`: its out dir, the overrides every step shares, and the steps (`run`)."""

    def __init__(self, garment, overrides: list[str], out, samples: int | None = None, epochs: int | None = None,
                 python: str = sys.executable, until: str = STEPS[-1]):
        self.garment = Path(garment).resolve()
        if not self.garment.is_file():
            raise FileNotFoundError(f"{garment}: no such garment file")
        if samples is not None and samples < 3:
            raise ValueError(f"--samples {samples}: give at least 3 (80/10/10 train/validation/test splits)")
        if epochs is not None and epochs < 1:
            raise ValueError(f"--epochs {epochs}: give at least 1")
        if until not in STEPS[1:]:
            raise ValueError(f"--until {until}: one of {', '.join(STEPS[1:])}")
        self.until = until  # not asked of the fit's outputs: a later call without it goes on
        self.user = list(overrides)
        self.out = Path(out).resolve()
        self.asked = {"garment": str(self.garment), "sha256": sha256(self.garment), "overrides": self.user,
                      "samples": samples, "epochs": epochs}
        self.python = python
        self.t0 = time.time()
        self.overrides: list[str] = []  # every step's: the garment's, the settings inspect chose, the user's, data
        self.here: stops.Step | None = None  # the step a stop is reported in, while `run` runs
        self.notes: dict[str, str] = {}

    # ------------------------------------------------------------------------------------------ helpers
    @property
    def data_dir(self) -> Path:
        return self.out / "data"

    def say(self, step: str, text: str) -> None:
        """A line of `step`, which a stop (SIGINT, SIGTERM) from here on is reported in (`run`)."""
        where = f"step {STEPS.index(step) + 1}/{len(STEPS)} {step}"
        if self.here is not None and not self.here.where.startswith(where):
            self.here.where = where
        print(f"[fit {STEPS.index(step) + 1}/{len(STEPS)}] {step}: {text}", flush=True)

    def has_drapes(self) -> bool:
        """Whether this out dir holds drapes: the dataset, or a finished drape of an unfinished one."""
        samples = self.data_dir / "work" / "samples"
        return (self.data_dir / "manifest.json").is_file() or (samples.is_dir() and any(samples.iterdir()))

    def _recorded(self) -> dict | None:
        """fit.json when this out dir holds this fit (the same garment and settings asked), None when it holds
        none or only one refused before any drape (which a corrected retry replaces); ValueError naming what
        differs when it holds drapes made for another garment or other settings."""
        path = self.out / RECORD
        if not path.is_file():
            return None
        rec = read_json(path, "garment fit record")
        diff = [k for k in ASKED if rec.get("asked", {}).get(k) != self.asked[k]]
        if diff and not self.has_drapes():
            return None  # refused before a drape (at checks, or generate's own door): inspect and check it again
        if diff:
            what = ", ".join(f"{k} {rec.get('asked', {}).get(k)!r} -> {self.asked[k]!r}" for k in diff)
            raise ValueError(f"{self.out} holds the fit of another garment or other settings ({what}): give this "
                             f"fit another --out, or delete {self.out} to start it again")
        return rec

    # ------------------------------------------------------------------------------------------ steps 1-2
    def inspect_and_check(self) -> None:
        """Steps 1 and 2 (seconds): the table and the settings, the checks and the cage; fit.json after both."""
        rec = self._recorded()
        if rec is not None:
            self.overrides = list(rec["overrides"])
            for step in ("inspect", "checks"):
                self.say(step, f"skipped (done: {self.out / RECORD})")
            return
        base = garment_overrides(self.garment, self.user)
        cfg = load_config(base + self.user)
        check_config(cfg)  # the overrides every step gets (sim.fps=0): refused before the fit's folder is made
        require_writable_dir(self.out, "garment fit folder", "give the fit a writable folder with --out DIR "
                             "(the default is runs/fit/<name> under PBC_ROOT, else the current folder)")
        self.say("inspect", f"{self.garment.name} with {' '.join(base + self.user)}")
        body = body_from_config(cfg.body)
        report = inspect_file(self.garment, cfg, body, self.out / "inspect", wrap=False)  # the checks wrap it
        derived = self.derived_settings(report, body, float(cfg.garment.dress_hem_below_hips))
        text = format_report(report, dict(cfg.garment.shrinkwrap))
        text += "\n\nused by pbc garment fit: " + (" ".join(derived) or "the overrides as given")
        write_text(self.out / "inspect" / "report.txt", text + "\n")
        save_uv_picture(report, self.out / "inspect" / "uv_layout.png")
        save_body_picture(report, self.out / "inspect" / "on_body.png")
        print(text, flush=True)
        self.overrides = self.step_overrides(base + derived, cfg)

        self.say("checks", "import, cage and shrink-wrap on the rest body (every check before a drape)")
        cfg = load_config(self.overrides)
        garment, cage, _ = scene_garment(cfg, body)
        _, stats = shrinkwrap(garment, cage, body, cfg.garment)
        save_cage(cage, self.out / "cage.json", garment.num_vertices)
        self.say("checks", f"passed: {garment.num_vertices} vertices, {len(cage.patches)} cage patches "
                           f"(cage.json); wrapped/pattern area per face mean {stats['area_after_mean']:.2f}, "
                           f"most stretched patch {stats.get('patch_stretch_worst')} "
                           f"{stats.get('patch_stretch_max', float('nan')):.2f}x")
        write_json(self.out / RECORD, {"asked": self.asked, "overrides": self.overrides})

    def derived_settings(self, report, body, dress_below: float) -> list[str]:
        """The overrides inspect chose, for what the user's overrides leave unset: the suggested charts and UV
        unit, the rest pose to make a garment on whose sleeves alone are off the body's rest arms
        (garment.made_on_rest), for a garment centred below the waist on a body with legs `LOWER_BODY`, and for a
        dress (`is_dress`: a top whose hem hangs ``dress_below`` m past the hip joints) `DRESS_DATA`."""
        given = {_key(o) for o in self.user}
        out = []
        charts = report.suggest_charts
        if charts is None:  # no chart mapping keeps the file's UVs apart: the mesh is unwrapped anew
            if "garment.uvs" not in given:
                out.append(UNWRAP_FIX)
        elif "garment.charts" not in given and all(CHART_NAME.fullmatch(n) for n in charts):
            out.append("garment.charts={" + ",".join(f"{k}:{v}" for k, v in charts.items()) + "}")
        if "garment.uv_unit" not in given and report.suggest_unit != "auto":
            out.append(f"garment.uv_unit={report.suggest_unit}")
        if "garment.made_on_rest" not in given and report.suggest_made_on is not None:
            out.append(made_on_override(report.suggest_made_on))
        area = sum(r.area_3d for r in report.rows)
        centre_y = sum(r.centroid[1] * r.area_3d for r in report.rows) / max(area, 1e-12)
        if centre_y < TOP_Y and set(LEG_JOINTS) <= set(body.skeleton.names):
            legs = len(openings(report.positions, report.faces)) >= 3
            out += [TROUSERS_DATA if legs and o == LOWER_BODY[0] else o for o in LOWER_BODY if _key(o) not in given]
        elif "data" not in given and is_dress(report, body, dress_below):
            out.append(DRESS_DATA)
        return out

    def step_overrides(self, garment: list[str], cfg) -> list[str]:
        """What every later step gets: the garment's and the derived overrides, the user's, then the data set's
        name and place (inside the out dir) and its size."""
        samples = self.asked["samples"]
        data = [f"data.name={Path(self.garment).stem}", f"data.dir={_value(self.data_dir)}"]
        if samples is not None:
            data.append(f"data.num_samples={samples}")
        return [*garment, *self.user, *data]

    # ------------------------------------------------------------------------------------------ steps 3-5
    def command(self, step: str, argv: list[str], log_name: str) -> None:
        """Run one step's command; its output in logs/<step>.log, its progress lines echoed. A failed command
        is one error naming the step, its own error line and the log."""
        log = self.out / "logs" / f"{log_name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        self.say(step, f"python {shlex.join(argv[1:])}  (log: {log})")
        if self.here is not None:
            self.here.where += f" (python -m {argv[2]}, its log: {log})"
        t0 = time.time()
        prefix = f"[fit {STEPS.index(step) + 1}/{len(STEPS)}] {step}: "
        code, error = run_logged(argv, log, show=lambda line: (m := PROGRESS.search(line.rstrip())) and
                                 f"{prefix}{m.group(1)}\n")
        if code:
            where = f"(exit {code}); its log: {log}"
            msg = f"step {step} stopped: {error} {where}" if error else f"step {step} failed {where}"
            raise (ValueError if code == 2 else RuntimeError)(msg)  # 2: the command's user error, one line
        self.say(step, f"done in {duration(time.time() - t0)}")

    def data(self) -> None:
        if (self.data_dir / "manifest.json").is_file():
            self.say("data", f"skipped (complete: {self.data_dir / 'manifest.json'})")
            return
        self.command("data", [self.python, "-m", "pbc.generate", *self.overrides,
                              f"hydra.run.dir={_value(self.out / 'logs' / 'generate')}"], "data")

    def check_splits(self) -> None:
        """One line when the drapes kept leave a split empty (`empty_splits`)."""
        manifest = json.loads((self.data_dir / "manifest.json").read_text())
        if (msg := empty_splits(manifest, self.out / "logs" / "data.log")) is not None:
            raise ValueError(msg)

    def whole(self) -> None:
        self.check_splits()
        run = self.out / "whole"
        if (run / "metrics.json").is_file() and RunRecord.read(run / "metrics.json").status == OK:
            self.say("whole", f"skipped (trained: {run / 'metrics.json'})")
            return
        extra = [f"trainer.max_epochs={self.asked['epochs']}"] if self.asked["epochs"] else []
        if (run / "checkpoints" / "last.ckpt").is_file():
            extra.append("ckpt_path=last")  # a killed or failed training continues (pbc.train checks it is the same)
        self.command("whole", [self.python, "-m", "pbc.train", *self.overrides, "+experiment=whole", *extra,
                               f"hydra.run.dir={_value(run)}"], "whole")

    def preview(self) -> None:
        out = self.out / "preview"
        if (out / "predict.json").is_file():
            self.say("preview", f"skipped (done: {out / 'predict.json'})")
            return
        self.command("preview", [self.python, "-m", "pbc.predict", str(self.out / "whole"), "--poses", "test",
                                 "--out", str(out)], "preview")

    # ------------------------------------------------------------------------------------------ the end
    def _where(self, last: str, kept, asked) -> list[str]:
        """One line per output of the steps up to `last`, with the dataset's drapes kept of asked."""
        o, done = self.out, STEPS[:STEPS.index(last) + 1]
        lines = [f"  {o / 'inspect'}/  report.txt (the chart table, the settings used), uv_layout.png, on_body.png",
                 f"  {o / 'cage.json'}  the automatic cage (to edit: then add garment.cage={o / 'cage.json'})"]
        lines += [line for step, line in (
            ("data", f"  {o / 'data'}/  the dataset: {kept} drapes kept of {asked}"),
            ("whole", f"  {o / 'whole'}/  the whole-garment model (metrics.json, checkpoints/, tensorboard/)"),
            ("preview", f"  {o / 'preview'}/  meshes of the test poses, contact_sheet.png")) if step in done]
        return [*lines, *([f"  {o / 'logs'}/  each step's full output"] if "data" in done else [])]

    def summary(self) -> str:
        """Where everything is, and the test error beside the training mean shape's on the same poses."""
        record = RunRecord.read(self.out / "whole" / "metrics.json")
        ds = load_dataset(record.data["dir"], check=False)
        model_cm = record.test.get("vertex_error_cm", float("nan"))
        mean_cm = mean_shape_errors(ds, ("test",))["test"]
        counts = ds.manifest.get("counts", {})
        kept, asked = counts.get("kept", len(ds.poses)), counts.get("requested", len(ds.poses))
        g = " ".join(self.overrides)  # as `$G` in a shell: word-split, never re-quoted
        return "\n".join([
            f"pbc garment fit: done in {duration(time.time() - self.t0)}; everything is under {self.out}",
            *self._where(STEPS[-1], kept, asked),
            f"test vertex error over {len(ds.split('test'))} test poses: {model_cm:.3f} cm (whole model), "
            f"{mean_cm:.3f} cm (the training mean shape)",
            f"the overrides of every step (patch models: python -m pbc.train $G +experiment=patches): G=\"{g}\"",
        ])

    def stopped(self) -> str:
        """The summary of a fit stopped by --until: what is there, and how to go on."""
        counts = {}
        if STEPS.index(self.until) >= STEPS.index("data"):
            counts = read_json(self.data_dir / "manifest.json", "dataset manifest").get("counts", {})
        return "\n".join([
            f"pbc garment fit: stopped after {self.until} (--until) in {duration(time.time() - self.t0)}; everything "
            f"so far is under {self.out}; the same command without --until goes on from there",
            *self._where(self.until, counts.get("kept"), counts.get("requested")),
            f"the overrides of every step: G=\"{' '.join(self.overrides)}\""])

    def run(self) -> str:
        """Every step up to --until, then the summary. A stop (SIGINT, SIGTERM) stops the step's command and its
        processes (run_logged), and the stop line names the step; the same command goes on from there."""
        with stops.step(f"step 1/{len(STEPS)} inspect", "the same command goes on from the last finished step; "
                        "a stopped step's finished drapes or last checkpoint are kept") as self.here:
            self.inspect_and_check()
            for step, go in (("data", self.data), ("whole", self.whole), ("preview", self.preview)):
                if STEPS.index(step) > STEPS.index(self.until):
                    return self.stopped()
                go()
            return self.summary()
