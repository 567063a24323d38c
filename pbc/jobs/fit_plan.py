"""How `pbc garment fit` spends a wall-clock budget: the budget's text, the settings (conf/fit.yaml), what the probe
measured (`Costs`) and the plan made of them (`plan_fit` -> `Plan`). Pure: no file is read but conf/fit.yaml, no
process started; pbc.jobs.garment_fit measures and follows.

The plan, for a budget B of which S seconds are spent (inspect, checks, the probe):

  left     = B (1 - margin) - S - preview_s - a command's start per command still to run
  drapes   N = samples.share * left / drape_s, within [samples.min, samples.max]   (or --samples)
  motion   M = motion.share * left / drape_s, within [motion.min, motion.max]       (0 without clips)
  training T = left - (N + M) drape_s, cut among the models by their shares; a model gets the epochs its share
             buys at N's training rows (an epoch's seconds: fixed + per row, from two probe trainings), at most its
             experiment's max_epochs; one that cannot buy min_epochs is left out and its share goes to the rest.

When no model can be trained at N drapes, fewer drapes are planned (down to samples.min); when none can at
samples.min either, the budget is refused naming the smallest one that plans (`smallest_budget`).
"""

from __future__ import annotations

import functools
import math
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import yaml

from pbc.core.paths import CONF_DIR
from pbc.models.progress import duration

FIT_FILE = CONF_DIR / "fit.yaml"
UNITS = {"h": 3600.0, "m": 60.0, "s": 1.0}
BUDGET = re.compile(r"(?:(\d+(?:\.\d+)?)h)?(?:(\d+(?:\.\d+)?)m)?(?:(\d+(?:\.\d+)?)s)?")
TRAIN_FRACTION = 0.8  # of the kept drapes in the training split (pbc.data.dataset's 80/10/10)


def parse_budget(text: str, what: str = "--budget") -> float:
    """Seconds of a budget written as hours, minutes and seconds in that order, each with its unit: ``60m``,
    ``1h30m``, ``1.5h``, ``90s``. One ValueError naming how to write it (``60``: no unit; ``1h30``: the 30's)."""
    s = str(text).strip().lower().replace(" ", "")
    m = BUDGET.fullmatch(s)
    if not s or m is None or not any(m.groups()):
        bare = re.fullmatch(r"\d+(?:\.\d+)?", s)
        tail = re.fullmatch(r"(.*[hm])(\d+(?:\.\d+)?)", s)
        if bare:
            hint = f"{s} has no unit: write {s}m for minutes (or {s}s, {s}h)"
        elif tail:
            unit = "m" if tail.group(1).endswith("h") else "s"
            hint = f"the {tail.group(2)} after {tail.group(1)} has no unit: write {s}{unit}"
        else:
            hint = "write hours, minutes and seconds each with its unit, e.g. 60m, 1h30m, 1.5h or 90s"
        raise ValueError(f"{what} {text}: {hint}")
    seconds = sum(float(v) * UNITS[u] for v, u in zip(m.groups(), "hms", strict=True) if v)
    if seconds <= 0:
        raise ValueError(f"{what} {text}: give a budget above zero, e.g. 60m")
    return seconds


def budget_text(seconds: float) -> str:
    """``5400`` -> ``1h30m``, ``900`` -> ``15m``, ``95`` -> ``1m35s``: a budget as --budget takes it."""
    s = int(math.ceil(seconds))
    h, rest = divmod(s, 3600)
    m, sec = divmod(rest, 60)
    return "".join(f"{v}{u}" for v, u in ((h, "h"), (m, "m"), (sec, "s")) if v) or "0s"


@dataclass(frozen=True)
class ModelSettings:
    """One candidate model of conf/fit.yaml `models`: its experiment, its share of the training time and the
    fewest epochs worth training it for."""
    name: str
    experiment: str
    share: float
    min_epochs: int


@dataclass(frozen=True)
class FitSettings:
    """conf/fit.yaml as typed values (`fit_settings`)."""
    budget_s: float
    min_budget_s: float
    margin: float
    preview_s: float
    probe_drapes: int
    probe_epochs: int
    probe_rows: int
    samples_share: float
    samples_min: int
    samples_max: int
    motion_poses: str | None
    motion_share: float
    motion_min: int
    motion_max: int
    models: tuple[ModelSettings, ...]


@functools.cache
def fit_settings(path: Path = FIT_FILE) -> FitSettings:
    """conf/fit.yaml, read once a process and held to conf/bounds.yaml's fit section; one ValueError naming the
    file, the key and what it may be."""
    from pbc.core.validate import check_settings_file  # noqa: PLC0415 - validate loads torch; the CLI's door needs none

    node = yaml.safe_load(Path(path).read_text()) or {}
    check_settings_file("fit", node, path)
    models = []
    for name, m in (node.get("models") or {}).items():
        m = m or {}
        if not (isinstance(m.get("experiment"), str) and isinstance(m.get("share"), int | float) and m["share"] > 0
                and isinstance(m.get("min_epochs"), int) and m["min_epochs"] >= 1):
            raise ValueError(f"invalid settings in {path}: models.{name} needs experiment (a name under "
                             "conf/experiment), share (> 0) and min_epochs (an int >= 1)")
        models.append(ModelSettings(str(name), m["experiment"], float(m["share"]), int(m["min_epochs"])))
    if not models:
        raise ValueError(f"invalid settings in {path}: models names no model to train")
    p, s, mo = node["probe"], node["samples"], node["motion"]
    return FitSettings(parse_budget(node["budget"], f"{path} budget"), parse_budget(node["min_budget"],
                       f"{path} min_budget"), float(node["margin"]), float(node["preview_s"]), int(p["drapes"]),
                       int(p["epochs"]), int(p["rows"]), float(s["share"]), int(s["min"]), int(s["max"]),
                       mo.get("poses"), float(mo["share"]), int(mo["min"]), int(mo["max"]), tuple(models))


@dataclass(frozen=True)
class Costs:
    """What the probe measured, in wall seconds on this machine.

    spent_s: the fit so far (inspect, checks, the probe); start_s: a step's command before its work (the process,
    its imports, the scene); drape_s: a drape asked, with the data set's workers; kept: the fraction of drapes
    kept; epoch_row_s: {model: an epoch's seconds per training row} and epoch_fixed_s: {model: an epoch's seconds
    whatever its rows (validation, checkpoints)}, from two probe trainings of two sizes; mirror: whether each
    training drape's mirror image joins the training rows; max_epochs: {model: its experiment's}."""
    spent_s: float
    start_s: float
    drape_s: float
    kept: float
    epoch_row_s: dict[str, float]
    epoch_fixed_s: dict[str, float]
    mirror: bool
    max_epochs: dict[str, int]

    def rows(self, drapes: int) -> float:
        """Training rows of `drapes` asked: the kept ones in the training split, with their mirrors."""
        return max(1.0, drapes * self.kept * TRAIN_FRACTION * (2 if self.mirror else 1))

    def epoch_s(self, model: str, drapes: int) -> float:
        return self.epoch_fixed_s[model] + self.epoch_row_s[model] * self.rows(drapes)


@dataclass
class ModelPlan:
    """A model to train: its experiment, epochs (trainer.max_epochs) and the seconds it may take
    (trainer.max_time), or None for no time cap (epochs given)."""
    name: str
    experiment: str
    epochs: int
    seconds: float | None


@dataclass
class Plan:
    """What the fit will do: drapes asked, held-out motion frames asked, the models, the seconds of each step,
    and what is left out (a model: why, and the budget that would train it)."""
    budget_s: float | None
    samples: int
    motion_frames: int
    models: list[ModelPlan]
    step_s: dict[str, float] = field(default_factory=dict)
    left_out: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    made_at: float = field(default_factory=time.time)
    costs: dict | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Plan:
        return cls(**{**d, "models": [ModelPlan(**m) for m in d["models"]]})

    def lines(self) -> list[str]:
        """The plan as a user reads it: one line per step with its minutes, the finish time, what is left out."""
        out = [f"budget {budget_text(self.budget_s)}" if self.budget_s else
               "as asked (--samples and --epochs): no budget"]
        t = self.made_at
        for step, what in (("data", f"{self.samples} drapes of training poses"),
                           ("motion", f"{self.motion_frames} drapes of held-out motion-capture frames (the real-motion "
                                      "score)"),
                           ("models", "; ".join(f"{m.name} ({m.experiment}): {m.epochs} epochs" +
                                               (f" within {duration(m.seconds)}" if m.seconds else "")
                                               for m in self.models)),
                           ("preview", "meshes of the test poses and the scores")):
            if step == "motion" and not self.motion_frames:
                continue
            s = self.step_s.get(step)
            t += s or 0.0
            when = f"  ({duration(s)}, until {time.strftime('%H:%M', time.localtime(t))})" if s is not None else ""
            out.append(f"  {step}: {what}{when}")
        out += [f"  left out: {name}: {why}" for name, why in self.left_out.items()]
        out += [f"  {n}" for n in self.notes]
        if self.step_s:
            total = sum(self.step_s.values())
            out.append(f"  done about {time.strftime('%H:%M', time.localtime(self.made_at + total))} "
                       f"({duration(total)} from now)")
        return out

    def after(self, step: str) -> float:
        """Planned seconds of the steps after `step` (the finish time of a step's progress lines)."""
        order = list(self.step_s)
        return sum(self.step_s[s] for s in order[order.index(step) + 1:]) if step in order else 0.0


def _clamp(x: float, lo: int, hi: int) -> int:
    return int(min(max(math.floor(x), lo), hi))


def _slots(costs: Costs, models: list[ModelSettings], drapes: int, seconds: float) -> dict[str, float]:
    """{model: seconds}: `seconds` cut by the models' shares, where a model whose max_epochs take less than its share
    gets what they take and the rest goes to the others by their shares."""
    slots, todo, left = {}, list(models), seconds
    while todo:
        total = sum(m.share for m in todo)
        full = {m.name: costs.max_epochs[m.name] * costs.epoch_s(m.name, drapes) for m in todo}
        capped = [m for m in todo if full[m.name] <= left * m.share / total]
        if not capped:
            slots.update({m.name: left * m.share / total for m in todo})
            return slots
        for m in capped:
            slots[m.name] = full[m.name]
            left -= slots[m.name]
        todo = [m for m in todo if m not in capped]
    return slots


def _train(costs: Costs, settings: FitSettings, drapes: int, seconds: float) -> tuple[list[ModelPlan], dict]:
    """The models `seconds` of training buys at `drapes` asked (`_slots`), and {model: why} for those left out:
    a model whose slot buys fewer than its min_epochs, whose time goes to the rest."""
    chosen, left_out = list(settings.models), {}
    while chosen:
        slots = _slots(costs, chosen, drapes, seconds)
        plans, short = [], []
        for m in chosen:
            epochs = min(int(slots[m.name] // costs.epoch_s(m.name, drapes)), costs.max_epochs[m.name])
            if epochs >= m.min_epochs:
                plans.append(ModelPlan(m.name, m.experiment, epochs, slots[m.name]))
                continue
            short.append(m)
            need = m.min_epochs * costs.epoch_s(m.name, drapes)
            left_out[m.name] = (f"{m.min_epochs} epochs at {drapes} drapes take about {duration(need)}, its share "
                                f"of the training {duration(max(slots[m.name], 0))}")
        if not short or not plans:
            return plans, left_out
        chosen = [m for m in chosen if m not in short]
    return [], left_out


def plan_fit(budget_s: float, costs: Costs, settings: FitSettings, samples: int | None = None,
             motion: bool = True) -> Plan:
    """The plan for `budget_s` (see the module's docstring); `samples` fixes the drapes (--samples); `motion`:
    whether held-out motion frames are draped. ValueError naming `smallest_budget` when none plans."""
    left = budget_s * (1 - settings.margin) - costs.spent_s - settings.preview_s - _starts(costs, settings, motion)
    frames = _clamp(settings.motion_share * left / costs.drape_s, settings.motion_min, settings.motion_max) \
        if motion else 0
    n = samples if samples is not None else _clamp(settings.samples_share * left / costs.drape_s,
                                                    settings.samples_min, settings.samples_max)
    while True:
        models, out = _train(costs, settings, n, left - (n + frames) * costs.drape_s)
        if models or samples is not None or n <= settings.samples_min:
            break
        n = max(settings.samples_min, int(n * 0.8))
    # time the models cannot use (their max_epochs reached, a model left out) buys more drapes
    for _ in range(8 if models and samples is None else 0):
        slack = left - _used(costs, n, frames, models)
        per_drape = costs.drape_s + sum(m.epochs * costs.epoch_row_s[m.name] * costs.rows(1) for m in models)
        more = min(settings.samples_max, n + int(slack / per_drape))
        if slack < 0.01 * left or more <= n:
            break
        more_models, more_out = _train(costs, settings, more, left - (more + frames) * costs.drape_s)
        if not more_models or _used(costs, more, frames, more_models) > left:
            break
        n, models, out = more, more_models, more_out
    if not models:
        need = smallest_budget(costs, settings, samples, motion)
        raise ValueError(f"--budget {budget_text(budget_s)} is too small for this garment on this machine: "
                         f"{duration(costs.drape_s)} a drape and {duration(costs.spent_s)} spent before the plan "
                         f"leave no time to train a model on {n} drapes; give --budget {budget_text(need)} or more")
    # a model left out with the rest trained: say what would train it
    for name in out:
        m = next(x for x in settings.models if x.name == name)
        extra = _share_for_min_epochs(costs, settings, m, n)
        out[name] += f"; --budget {budget_text(budget_s + extra / (1 - settings.margin))} would train it"
    step_s = {"data": costs.start_s + n * costs.drape_s}
    if frames:
        step_s["motion"] = costs.start_s + frames * costs.drape_s
    step_s["models"] = _training_s(costs, n, models) + costs.start_s * len(models)
    step_s["preview"] = costs.start_s + settings.preview_s
    return Plan(budget_s, n, frames, models, step_s, out, costs=asdict(costs))


def _starts(costs: Costs, settings: FitSettings, motion: bool) -> float:
    """Seconds the commands still to run take to start: data, motion (with `motion`), each model, preview."""
    return costs.start_s * (2 + (1 if motion else 0) + len(settings.models))


def _share_for_min_epochs(costs: Costs, settings: FitSettings, model: ModelSettings, drapes: int) -> float:
    """Seconds of training whose share for `model` buys its min_epochs at `drapes` asked."""
    return model.min_epochs * costs.epoch_s(model.name, drapes) * sum(x.share for x in settings.models) / model.share


def _training_s(costs: Costs, drapes: int, models: list[ModelPlan]) -> float:
    """Seconds the models' planned epochs take at `drapes` asked, each at most its time cap (no command starts)."""
    return sum(min(m.seconds, m.epochs * costs.epoch_s(m.name, drapes)) for m in models)


def _used(costs: Costs, drapes: int, frames: int, models: list[ModelPlan]) -> float:
    """Seconds the drapes, the motion frames and the models' planned epochs take (no command starts)."""
    return (drapes + frames) * costs.drape_s + _training_s(costs, drapes, models)


def smallest_budget(costs: Costs, settings: FitSettings, samples: int | None = None, motion: bool = True) -> float:
    """The smallest budget (s) `plan_fit` plans with these costs: the fewest drapes and the cheapest model's
    min_epochs, with every fixed step and the margin."""
    n = samples if samples is not None else settings.samples_min
    frames = settings.motion_min if motion else 0
    cheapest = min(_share_for_min_epochs(costs, settings, m, n) for m in settings.models)
    need = (costs.spent_s + settings.preview_s + _starts(costs, settings, motion) + (n + frames) * costs.drape_s
            + cheapest)
    # the drape share of the time left decides n above samples.min: the smallest budget keeps n at the minimum
    return need / (1 - settings.margin) + 1.0


def replan_training(plan: Plan, settings: FitSettings, kept: int, seconds_left: float) -> bool:
    """After the drapes: the models' epochs and minutes again, for the `kept` drapes made and the `seconds_left` of
    the budget (less the margin), when that trains more than the plan did (the drapes took less time than timed,
    or fewer were kept). Updates `plan` in place; whether it changed."""
    if plan.costs is None or plan.budget_s is None:
        return False
    costs = Costs(**plan.costs)
    starts = costs.start_s * (len(settings.models) + 1)
    left = seconds_left - settings.preview_s - starts
    asked = max(settings.samples_min, int(round(kept / max(costs.kept, 1e-6))))  # the rows of the kept drapes
    models, out = _train(costs, settings, asked, left)
    planned = {m.name: m.seconds or 0.0 for m in plan.models}
    if not models or ({m.name for m in models} <= set(planned) and sum(m.seconds for m in models) <= sum(
            planned.values()) + 1.0):
        return False
    plan.models, plan.left_out = models, out
    plan.step_s["models"] = _training_s(costs, asked, models) + costs.start_s * len(models)
    return True


def as_asked(samples: int, epochs: int, settings: FitSettings, motion_frames: int) -> Plan:
    """The plan of a fit given both --samples and --epochs: every model for those epochs, no time cap."""
    return Plan(None, samples, motion_frames, [ModelPlan(m.name, m.experiment, epochs, None) for m in settings.models])
