"""Training feedback in a log file: per-epoch lines off a terminal, the image panel at the end of a short
fit, the score table with full metric names, and bf16 only where the device runs it natively. Synthetic:
a linear model on random data, 2-epoch Trainers of a second or two."""

from __future__ import annotations

import logging
import re
import sys
from types import SimpleNamespace

import lightning as L
import pytest
import torch
from lightning.pytorch.callbacks import ModelSummary, RichModelSummary
from torch.utils.data import DataLoader

LINE = re.compile(r"^epoch (\d+)/(\d+)  train loss (\S+)  (val/\S+) (\S+)  (\d+\.\d) s/epoch  ETA (\d+s|\d+m\d\ds)$")
SIZE, V = 8, 5  # image side, vertices of the stand-in garment


class Target:
    """What ImagePanel reads of a cloth target: an image size and a mesh (one triangle fan)."""

    image_size = (SIZE, SIZE)
    faces = torch.tensor([[0, 1, 2], [0, 2, 3], [0, 3, 4]])
    vertices = None
    patch_id = None


class Tiny(L.LightningModule):
    """pose (B, 4) -> a (B, 6, SIZE, SIZE) image, logging the metric names ClothModule logs."""

    def __init__(self, kind: str = "whole"):
        super().__init__()
        self.save_hyperparameters()
        self.net = torch.nn.Linear(4, 6 * SIZE * SIZE)
        self.target = Target()

    def forward(self, pose):
        return self.net(pose).reshape(-1, 6, SIZE, SIZE)

    def targets(self, batch):
        return {"image": batch["image"], "mask": torch.ones(1, 6, SIZE, SIZE), "verts": batch["verts"]}

    def positions(self, pred, t):
        return t["verts"] + pred.mean((1, 2, 3))[:, None, None]

    def _err(self, batch):
        return (self(batch["pose"]) - batch["image"]).abs().mean()

    def training_step(self, batch, batch_idx):
        loss = self._err(batch)
        self.log("train/loss", loss, on_step=True, on_epoch=True)
        return loss

    def validation_step(self, batch, batch_idx):
        from pbc.core.runs import monitor

        self.log(monitor(self.hparams.kind), 100 * self._err(batch))

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.01)


class Data(L.LightningDataModule):
    def __init__(self):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.samples = [{"pose": torch.randn(4, generator=g), "image": torch.randn(6, SIZE, SIZE, generator=g),
                         "verts": torch.randn(V, 3, generator=g)} for _ in range(8)]

    def train_dataloader(self):
        return DataLoader(self.samples, batch_size=4)

    def val_dataloader(self):
        return DataLoader(self.samples[:4], batch_size=4)


def fit(callbacks, tmp_path, logger=False, kind="whole", max_epochs=2, **kw) -> L.Trainer:
    kw.setdefault("enable_model_summary", False)
    trainer = L.Trainer(max_epochs=max_epochs, callbacks=callbacks, logger=logger, enable_checkpointing=False,
                        default_root_dir=tmp_path, **kw)
    trainer.fit(Tiny(kind), datamodule=Data())
    return trainer


# ------------------------------------------------------------------------------------------ epoch lines
@pytest.mark.parametrize("kind", ["whole", "patch"])
def test_epoch_line_off_a_terminal(tmp_path, caplog, kind):
    from pbc.models.progress import EpochLine

    records = []

    class Keep(L.Callback):  # the validation metric each epoch really logged, to compare with the line
        def on_train_epoch_end(self, trainer, pl_module):
            records.append({k: float(v) for k, v in trainer.callback_metrics.items()})

    with caplog.at_level(logging.INFO, logger="pbc.models.progress"):
        trainer = fit([EpochLine(tty=False), Keep()], tmp_path, kind=kind, enable_model_summary=True)
    lines = [r.getMessage() for r in caplog.records if r.name == "pbc.models.progress"]
    assert len(lines) == 2, lines
    want = "val/patch_vertex_error_cm" if kind == "patch" else "val/vertex_error_cm"
    for epoch, (line, metrics) in enumerate(zip(lines, records, strict=True), 1):
        m = LINE.match(line)
        assert m, line
        assert (int(m[1]), int(m[2]), m[4]) == (epoch, 2, want)
        assert float(m[3]) == pytest.approx(metrics["train/loss_epoch"], rel=1e-3)
        assert float(m[5]) == pytest.approx(metrics[want], abs=1e-3)
    assert LINE.match(lines[-1])[7] == "0s"  # nothing left after the last epoch
    # the progress bar's redraws would land in the file too: it is off; the model summary is plain text
    assert trainer.progress_bar_callback.is_disabled
    summaries = [type(cb).__name__ for cb in trainer.callbacks if isinstance(cb, ModelSummary)]
    assert summaries == ["ModelSummary"]


def test_epoch_line_says_when_an_epoch_did_not_validate(tmp_path, caplog):
    """callback_metrics keeps the last validation value: an epoch without validation must not repeat it."""
    from pbc.models.progress import EpochLine

    with caplog.at_level(logging.INFO, logger="pbc.models.progress"):
        fit([EpochLine(tty=False)], tmp_path, max_epochs=3, check_val_every_n_epoch=2)
    lines = [r.getMessage() for r in caplog.records if r.name == "pbc.models.progress"]
    vals = [LINE.match(line)[5] for line in lines]
    assert vals[0] == "-" and vals[1] != "-" and vals[2] == "-", lines


def test_on_a_terminal_the_bar_stays_and_no_lines(tmp_path, caplog):
    from pbc.models.progress import EpochLine

    with caplog.at_level(logging.INFO, logger="pbc.models.progress"):
        trainer = fit([EpochLine(tty=True)], tmp_path, enable_model_summary=True)
    assert not [r for r in caplog.records if r.name == "pbc.models.progress"]
    assert not trainer.progress_bar_callback.is_disabled
    assert any(isinstance(cb, RichModelSummary) for cb in trainer.callbacks)


@pytest.mark.parametrize("out,err,want", [(True, True, True), (False, True, False), (True, False, False)])
def test_terminal_means_both_streams(monkeypatch, out, err, want):
    from pbc.models.progress import on_terminal

    monkeypatch.setattr(sys, "stdout", SimpleNamespace(isatty=lambda: out, write=lambda s: None))
    monkeypatch.setattr(sys, "stderr", SimpleNamespace(isatty=lambda: err, write=lambda s: None))
    assert on_terminal() is want


@pytest.mark.parametrize("seconds,text", [(7.4, "7s"), (95, "1m35s"), (3725, "1h02m")])
def test_duration(seconds, text):
    from pbc.models.progress import duration

    assert duration(seconds) == text


# ------------------------------------------------------------------------------------ image panel
def _panel_steps(tb_dir) -> list[int]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from pbc.models.module import panel_tag

    steps = []
    for f in sorted(tb_dir.rglob("events.out.tfevents.*")):
        acc = EventAccumulator(str(f), size_guidance={"images": 0})
        acc.Reload()
        if panel_tag(5.0) in acc.Tags()["images"]:
            steps += [im.step for im in acc.Images(panel_tag(5.0))]
    return steps


@pytest.mark.parametrize("every,want_epochs", [(5, [2]), (1, [1, 2])])
def test_image_panel_at_the_end_of_a_short_fit(tmp_path, every, want_epochs):
    """A 2-epoch run (trainer=smoke) is shorter than every_n_epochs=5: the panel still comes, at the end
    of fit; a run whose last validation epoch wrote it gets no second copy at the same step."""
    from lightning.pytorch.loggers import TensorBoardLogger

    from pbc.models.module import ImagePanel

    logger = TensorBoardLogger(tmp_path, name="tb", version="")
    trainer = fit([ImagePanel(every_n_epochs=every, num_poses=2, mesh_dir=str(tmp_path / "meshes"))], tmp_path,
                  logger=logger, enable_progress_bar=False, log_every_n_steps=1)
    logger.experiment.flush()
    steps_per_epoch = trainer.global_step // 2
    assert _panel_steps(tmp_path / "tb") == [e * steps_per_epoch for e in want_epochs]


# ------------------------------------------------------------------------------------ score table
LONG = "patch_vertex_error_cm_std_of_a_metric_name_longer_than_any_column_of_rich"


def test_metric_table_keeps_full_names():
    from pbc.models.progress import metric_table

    table = metric_table({"test": {LONG: 1.25, "loss": 0.5}, "train_final": {LONG: 2.0}})
    lines = table.splitlines()
    assert lines[0].split() == ["metric", "test", "train_final"]
    row = next(line for line in lines if line.startswith(LONG + " "))
    assert row.split() == [LONG, "1.25", "2"]
    loss = next(line for line in lines if line.startswith("loss "))
    assert loss.split() == ["loss", "0.5"]  # train_final has no loss: blank, not shifted
    assert len({len(line) for line in lines[:2]}) == 1  # the rule under the header spans it


def test_score_logs_the_plain_table_not_lightnings(caplog):
    """pbc.jobs.train.score asks Lightning for no table (verbose=False) and logs its own, every name in full."""
    from pbc.jobs.train import score

    calls = {}

    def test(module, dataloaders, ckpt_path, verbose=True):
        calls["verbose"] = verbose
        return [{f"test/{LONG}": 1.5, "test/loss": 0.25}, {f"train_final/{LONG}": 3.0}]

    trainer = SimpleNamespace(test=test, is_global_zero=True)
    # score logs on pbc.jobs.train's logger (the level of "pbc.train" only worked after a test had set pbc's)
    with caplog.at_level(logging.INFO, logger="pbc.jobs.train"):
        scores = score(trainer, None, SimpleNamespace(scoring_dataloaders=lambda: []), "best.ckpt")
    assert calls["verbose"] is False
    assert scores == {"test": {LONG: 1.5, "loss": 0.25}, "train_final": {LONG: 3.0}}
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "best.ckpt" in text and any(line.split() == [LONG, "1.5", "3"] for line in text.splitlines())


def test_silence_training_noise_drops_tips_and_named_warnings_only(caplog):
    import warnings

    from lightning.pytorch.utilities.warnings import PossibleUserWarning

    from pbc.models.progress import LIGHTNING_INFO_LOGGER, silence_training_noise

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        silence_training_noise()
        silence_training_noise()  # idempotent: one filter, not two
        warnings.warn("The 'train_dataloader' does not have many workers which may be a bottleneck.",
                      PossibleUserWarning, stacklevel=1)
        warnings.warn("`isinstance(treespec, LeafSpec)` is deprecated, use ...", FutureWarning, stacklevel=1)
        warnings.warn("The 'train_dataloader' is something else.", PossibleUserWarning, stacklevel=1)
    assert [str(w.message) for w in seen] == ["The 'train_dataloader' is something else."]
    info = logging.getLogger(LIGHTNING_INFO_LOGGER)
    assert len(info.filters) == len(set(map(id, info.filters)))
    with caplog.at_level(logging.INFO, logger=LIGHTNING_INFO_LOGGER):
        info.info("💡 Tip: For seamless cloud logging ...")
        info.info("GPU available: False, used: False")
    assert [r.getMessage() for r in caplog.records] == ["GPU available: False, used: False"]


# ------------------------------------------------------------------------------------ bf16 predictor
@pytest.mark.parametrize("flags,fast", [({"avx2", "avx512f"}, False), ({"avx512f", "avx512_bf16"}, True),
                                        ({"amx_bf16", "amx_tile"}, True)])
def test_bf16_on_the_cpu_only_with_native_units(monkeypatch, flags, fast):
    import warnings

    import pbc.inference.predictor as predict

    monkeypatch.setattr(predict, "cpu_flags", lambda: flags)
    assert predict.bf16_is_fast("cpu") is fast
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        used = predict.predictor_precision("bfloat16", "cpu")
        assert predict.predictor_precision("float32", "cpu") == "float32"
    assert used == ("bfloat16" if fast else "float32")
    assert len(seen) == (0 if fast else 1)
    if not fast:
        assert "float32" in str(seen[0].message) and "avx512_bf16" in str(seen[0].message)


@pytest.mark.parametrize("native", [True, False])
def test_bf16_on_cuda_asks_for_native_support(monkeypatch, native):
    import pbc.inference.predictor as predict

    asked = {}

    def supported(including_emulation=True):
        asked["emulation"] = including_emulation
        return native

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", supported)
    assert predict.bf16_is_fast("cuda:0") is native and asked["emulation"] is False
    assert predict.bf16_is_fast("meta") is False  # a device nobody measured: float32


def test_cpu_flags_without_proc_cpuinfo_asks_torch(monkeypatch):
    import builtins

    import pbc.inference.predictor as predict

    real_open = builtins.open

    def no_proc(path, *a, **k):
        if str(path) == "/proc/cpuinfo":
            raise FileNotFoundError(path)
        return real_open(path, *a, **k)

    monkeypatch.setattr(builtins, "open", no_proc)
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: True, raising=False)
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: False, raising=False)
    assert predict.cpu_flags() == {"avx512_bf16"}


@pytest.mark.parametrize("flags,used", [({"avx2"}, "float32"), ({"avx512_bf16"}, "bfloat16")])
def test_predictor_runs_the_precision_the_device_supports(monkeypatch, tmp_path, flags, used):
    import warnings

    from helpers.evaluate_world import IMAGE, ROOT, fake_dataset
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    import pbc.inference.predictor as predict

    monkeypatch.setattr(predict, "cpu_flags", lambda: flags)
    whole = OmegaConf.merge({"image": IMAGE}, {"n": OmegaConf.load(ROOT / "conf/model/whole.yaml").net})
    net = instantiate(OmegaConf.to_container(whole, resolve=True)["n"]).eval()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        pred = predict.ClothPredictor(fake_dataset(tmp_path / "fake"), IMAGE, net, [],
                                      OmegaConf.load(ROOT / "conf/stitch/average.yaml"), precision="bfloat16",
                                      cache_dir=tmp_path / "ops")
    assert pred.precision == used
    assert len([w for w in seen if "bfloat16" in str(w.message)]) == (used == "float32")
