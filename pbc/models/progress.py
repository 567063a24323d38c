"""Training feedback that reads as well in a log file as on a terminal.

- :class:`EpochLine`: a Lightning callback (``conf/callbacks/default.yaml``, ``minimal.yaml``). Off a
  terminal (a log file, a cluster job) it logs one plain line per epoch -- epoch/max, train loss, the
  validation vertex error in cm, seconds per epoch, ETA -- turns Lightning's progress bar off, whose
  carriage-return redraws are noise in a file, and swaps its Rich model summary for the plain one. On a
  terminal it does nothing: the bar stays.
- :func:`metric_table`: the scores of ``pbc.train`` as a plain table with full metric names (Lightning's
  Rich table truncates them and wraps at 80 columns in a file).
- :func:`silence_training_noise`: the one place that filters messages of dependencies that carry nothing
  for a pbc run (Lightning's product tips, a worker warning that does not apply, deprecations inside
  Lightning).
"""

from __future__ import annotations

import logging
import sys
import time
import warnings

import lightning as L
from lightning.pytorch.callbacks import ModelSummary, RichModelSummary
from lightning.pytorch.utilities.warnings import PossibleUserWarning

from pbc.core.runs import monitor

log = logging.getLogger(__name__)

# Lightning's tips advertise its cloud products (litlogger, litmodels); they are logged at INFO through
# this logger on every run, so only these lines are dropped, never its other INFO lines
LIGHTNING_INFO_LOGGER = "lightning.pytorch.utilities.rank_zero"
TIP_PREFIX = "💡 Tip:"
# (message regex, category, why it does not apply to a pbc run)
NOISE_WARNINGS = (
    # the datamodule keeps num_workers=0 on purpose: samples are a few floats already in memory and the
    # images are rendered per batch on the device (conf/datamodule/default.yaml), so workers only add
    # start-up cost; Lightning suggests them on any machine with more than 2 cores
    (r"The '\w+' does not have many workers", PossibleUserWarning),
    # raised inside Lightning's own pytree helper (lightning/pytorch/utilities/_pytree.py) on torch >= 2.10:
    # nothing a pbc user can change
    (r"`isinstance\(treespec, LeafSpec\)` is deprecated", FutureWarning),
)


class _DropTips(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(TIP_PREFIX)


_DROP_TIPS = _DropTips()


def silence_training_noise() -> None:
    """Filter Lightning's tips and the warnings of :data:`NOISE_WARNINGS`; idempotent (called by
    ``pbc.jobs.train.train`` before the Trainer is built, since the litlogger tip is logged by its constructor)."""
    for message, category in NOISE_WARNINGS:
        warnings.filterwarnings("ignore", message=message, category=category)
    info = logging.getLogger(LIGHTNING_INFO_LOGGER)
    if _DROP_TIPS not in info.filters:
        info.addFilter(_DROP_TIPS)


def on_terminal() -> bool:
    """Whether a person watches a terminal: the log lines (stdout) and the progress bar (stderr) both go to
    one; redirecting either to a file means the bar's redraws land in a file nobody watches live."""
    return all(getattr(s, "isatty", lambda: False)() for s in (sys.stdout, sys.stderr))


def duration(seconds: float) -> str:
    """``95`` -> ``1m35s``, ``3725`` -> ``1h02m``, ``7.4`` -> ``7s``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class EpochLine(L.Callback):
    """One plain log line per training epoch when not on a terminal (``tty=None``: :func:`on_terminal`
    decides; True/False force it), e.g.::

        epoch 3/20  train loss 0.1234  val/vertex_error_cm 2.491  12.3 s/epoch  ETA 3m27s

    The validation metric is the checkpoint monitor of the module's kind (``pbc.core.runs.monitor``: a patch
    model's ``val/patch_vertex_error_cm``); "-" in an epoch without validation.
    """

    def __init__(self, tty: bool | None = None) -> None:
        self.tty = tty
        self._times: list[float] = []
        self._start: float | None = None
        self._val_epoch: int | None = None  # the last epoch that ran validation (not the sanity check)

    def active(self) -> bool:
        return not (on_terminal() if self.tty is None else self.tty)

    def setup(self, trainer, pl_module, stage: str) -> None:
        if not self.active():
            return
        if trainer.progress_bar_callback is not None:
            trainer.progress_bar_callback.disable()
        # Lightning picks the Rich model summary whenever rich is installed: box drawing padded to 80
        # columns in a file; the plain one logs the same rows as text (it runs at fit start, after setup)
        for i, cb in enumerate(trainer.callbacks):
            if isinstance(cb, RichModelSummary):
                trainer.callbacks[i] = ModelSummary(max_depth=cb._max_depth)

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._start = time.perf_counter()

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        if not trainer.sanity_checking:
            self._val_epoch = trainer.current_epoch

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        # validation of this epoch has run by now (Lightning validates before on_train_epoch_end)
        if self._start is None:
            return
        self._times.append(time.perf_counter() - self._start)
        self._start = None
        if self.active() and trainer.is_global_zero:
            log.info("%s", self.line(trainer, pl_module))

    def line(self, trainer, pl_module) -> str:
        m = trainer.callback_metrics
        epoch, last = trainer.current_epoch + 1, trainer.max_epochs
        parts = [f"epoch {epoch}/{last}" if last and last > 0 else f"epoch {epoch}"]
        loss = m.get("train/loss_epoch", m.get("train/loss"))
        parts.append(f"train loss {float(loss):.4g}" if loss is not None else "train loss -")
        key = monitor(str(pl_module.hparams.get("kind", "whole")))
        # callback_metrics keeps the last validation's value: shown only in the epoch that produced it
        val = m.get(key) if self._val_epoch == trainer.current_epoch else None
        parts.append(f"{key} {float(val):.3f}" if val is not None else f"{key} -")
        per = sum(self._times) / len(self._times)
        parts.append(f"{per:.1f} s/epoch")
        if last and last > 0:
            parts.append(f"ETA {duration(per * max(last - epoch, 0))}")
        return "  ".join(parts)


def metric_table(scores: dict[str, dict[str, float]]) -> str:
    """{split: {metric: value}} (``pbc.jobs.train.score``) -> a plain table, one row per metric with its full
    name, one column per split; a metric a split lacks is blank."""
    splits = [s for s in scores if scores[s]]
    names = sorted({k for s in splits for k in scores[s]})
    if not names:
        return "(no metrics)"
    rows = [["metric", *splits]] + [[n, *(f"{scores[s][n]:.6g}" if n in scores[s] else "" for s in splits)]
                                     for n in names]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = ["  ".join([r[0].ljust(widths[0]), *(c.rjust(w) for c, w in zip(r[1:], widths[1:], strict=True))])
             for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines)
