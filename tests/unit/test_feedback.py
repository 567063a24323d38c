"""What a researcher sees: progress bars and logs, `pbc.main`'s run dirs and --help, the TensorBoard image
panel, dataset preview figures and report figures. All synthetic and fast (no drape, no training)."""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------ progress and logs
def test_drape_bar_off_a_terminal_writes_short_log_lines(caplog):
    from pbc.data.generate import progress_bar

    with caplog.at_level(logging.INFO, logger="pbc.data.generate"):
        bar = progress_bar(5000, "drape (2 workers)", "sample", stream=io.StringIO(), log_every_s=3600)
        for i in range(5000):
            bar.update(1)
            bar.set_postfix(discarded=i // 100, refresh=False)
        bar.close()
    lines = [r.getMessage() for r in caplog.records]
    # a redraw per sample would be 5000 updates in one carriage-return line; here: the start and the end
    assert 1 <= len(lines) <= 3, lines
    assert all(len(line) < 160 and "\r" not in line and "\n" not in line for line in lines)
    assert "5000/5000" in lines[-1] and "discarded=49" in lines[-1]


def test_drape_bar_logs_at_its_interval(caplog):
    from pbc.data.generate import progress_bar

    with caplog.at_level(logging.INFO, logger="pbc.data.generate"):
        bar = progress_bar(10, "drape", "sample", stream=io.StringIO(), log_every_s=0)
        for _ in range(10):
            bar.update(1)
        bar.close()
    counts = [r.getMessage().split(": ", 1)[1].split(" ", 1)[0] for r in caplog.records]
    assert "5/10" in counts and counts[-1] == "10/10"


def test_training_bar_shows_loss_and_val_error():
    from pbc.models.module import on_progress_bar

    assert on_progress_bar("train", "loss") and on_progress_bar("val", "vertex_error_cm")
    assert on_progress_bar("val", "patch_vertex_error_cm")  # a scoped name (patch runs) too
    assert not on_progress_bar("train", "image_loss") and not on_progress_bar("val", "loss")
    assert not on_progress_bar("test", "vertex_error_cm")


def test_cpu_trainer_logs_within_an_epoch_of_the_default_data():
    """Lightning warns when an epoch has fewer batches than log_every_n_steps (tshirt_small: 5)."""
    from pbc.core.config import load_config
    from pbc.data.generate import split_sizes

    cfg = load_config(["trainer=cpu", "data=tshirt_small", "paths.output_dir=/tmp/x"])
    batches = -(-split_sizes(int(cfg.data.num_samples * 0.9))[0] // int(cfg.datamodule.batch_size))
    assert cfg.trainer.log_every_n_steps <= batches


# ------------------------------------------------------------------------------------------- pbc.main




def test_main_makes_a_fresh_run_dir_per_invocation(tmp_path):
    from pbc.jobs.main import fresh_run_dir

    a, b = fresh_run_dir(tmp_path / "main"), fresh_run_dir(tmp_path / "main")
    assert a != b and a.is_dir() and b.is_dir()
    assert (tmp_path / "main" / "latest").resolve() == b.resolve()


# --------------------------------------------------------------------------------- TensorBoard panel
def _images(b=2, h=16, w=16):
    gen = torch.Generator().manual_seed(0)
    gt = 0.05 * torch.randn(b, 6, h, w, generator=gen)
    mask = torch.zeros(b, 1, h, w)
    mask[..., 2:-2, 3:-3] = 1
    return gt * mask, mask


def test_panel_error_is_in_cm_and_not_normalised_per_pose():
    from pbc.models.module import panel_error_cm

    gt, mask = _images()
    pred = gt.clone()
    pred[0, 0] += 0.01 * mask[0, 0]  # pose 0: 1 cm off along du, front only
    pred[1, 3:6] += 0.02 * mask[1, 0]  # pose 1: (2, 2, 2) cm off on the back
    err = panel_error_cm(pred, gt, mask)
    assert err.shape == (2, 2, 16, 16)
    inside = mask[0, 0] > 0
    assert torch.allclose(err[0, 0][inside], torch.tensor(1.0), atol=1e-4)
    assert torch.allclose(err[1, 1][inside], torch.tensor(2.0 * 3**0.5), atol=1e-4)
    assert err[0, 1].abs().max() < 1e-4 and err[:, :, ~inside].abs().max() == 0  # off the charts: 0


def test_panel_tag_in_the_event_file(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from torch.utils.tensorboard import SummaryWriter

    from pbc.models.module import PANEL_COLUMNS, panel_figure, panel_tag

    gt, mask = _images()
    # the mask as a target serves it: one for the batch, per channel (1, 6, H, W)
    fig = panel_figure(gt + 0.005, gt, mask[:1].expand(1, 6, -1, -1), 2.0, 10.0)
    titles = [ax.get_title() for ax in fig.axes[:3]]
    assert titles[:2] == list(PANEL_COLUMNS[:2]) and titles[2].startswith("|error|") and "0-2 cm" in titles[2]
    w = SummaryWriter(str(tmp_path))
    w.add_figure(panel_tag(2.0), fig, global_step=3)
    w.close()
    acc = EventAccumulator(str(tmp_path))
    acc.Reload()
    assert panel_tag(2.0) == "val/panel_err_0-2cm" and "val/panel_err_0-2cm" in acc.Tags()["images"]
    img = acc.Images("val/panel_err_0-2cm")[0]
    assert img.step == 3 and img.height > img.width > 0  # 4 rows (2 poses x front/back), 3 columns


# ------------------------------------------------------------------------------------- per-pose spread
def test_per_pose_vertex_error_matches_the_mean():
    from pbc.models.metrics import vertex_error_cm, vertex_error_cm_per_pose

    gen = torch.Generator().manual_seed(1)
    gt = torch.randn(5, 40, 3, generator=gen)
    pred = gt + 0.01 * torch.arange(5.0).view(5, 1, 1)  # pose k off by k cm along every axis
    per = vertex_error_cm_per_pose(pred, gt)
    assert per.shape == (5,)
    assert torch.allclose(per, torch.arange(5.0) * 3**0.5, atol=1e-4)
    assert torch.allclose(per.mean(), vertex_error_cm(pred, gt))
    ids = torch.tensor([0, 3, 7])
    assert torch.allclose(vertex_error_cm_per_pose(pred, gt, ids).mean(), vertex_error_cm(pred, gt, ids))


# ------------------------------------------------------------------------------------ dataset preview
def test_sample_figure_holds_raised_arms(tmp_path, body):
    from pbc.data.preview import plot_samples, view_limits
    from pbc.geometry.body.base import pose_body

    poses = np.tile(np.eye(3, dtype=np.float32), (2, body.skeleton.num_joints, 1, 1))
    rest = pose_body(body, torch.from_numpy(poses[:1]))[0].numpy()
    # a "garment": a strip of triangles over the chest, then raised far above the head in sample 1
    top = rest[:, 1].max()
    strip = np.array([[x, y, 0.2] for y in (1.0, 1.1) for x in np.linspace(-0.2, 0.2, 5)], dtype=np.float32)
    faces = np.array([[i, i + 1, i + 5] for i in range(4)] + [[i + 1, i + 6, i + 5] for i in range(4)])
    raised = strip + np.array([0.9, top + 0.5, 0.0], dtype=np.float32)
    ds = SimpleNamespace(poses=poses, body=body, verts=np.stack([strip, raised]),
                         garment=SimpleNamespace(faces=torch.from_numpy(faces)))
    (x0, x1), (y0, y1) = view_limits(np.concatenate([rest, raised]))
    assert x0 <= -raised[:, 0].max() and x1 >= raised[:, 0].max() and y1 >= raised[:, 1].max()
    assert y0 <= rest[:, 1].min()
    path = plot_samples(ds, [0, 1], tmp_path / "samples.png")
    assert path.is_file() and path.stat().st_size > 1000


# ------------------------------------------------------------------------------------------- reports
def test_report_paths_are_relative(tmp_path):
    from test_report import make_run, patch_metrics

    from pbc.jobs import report

    sweep = tmp_path / "sweep"
    for i in range(6):
        make_run(sweep, f"{i}_experiment=patch_{i:02d}", {"experiment": f"patch_{i:02d}", "loss": "l1"},
                 patch_metrics(i, 0.2, 0.02, 0.3 + 0.01 * i, 0.03)
                 | {"test": {"patch_vertex_error_cm": 0.3 + 0.01 * i, "patch_vertex_error_cm_std": 0.05}},
                 {"train/loss_step": [1.0, 0.5], "val/vertex_error_cm": [3.0, 2.0]})
    make_run(sweep, "9_experiment=whole", {"experiment": "whole", "loss": "l2"},
             {"status": "failed", "error": f"FileNotFoundError: {sweep}/9_experiment=whole/x.ckpt and "
                                           f"{ROOT}/data/tshirt_small_seed0/manifest.json"})
    out = tmp_path / "report"
    md = report.build_report(sweep, out)
    for path in (md, out / "report.json"):
        text = path.read_text()
        assert str(tmp_path) not in text and str(ROOT) not in text, path
    text = md.read_text()
    assert "../sweep/9_experiment=whole/x.ckpt" in text and " data/tshirt_small_seed0/manifest.json" in text
    # the error bars the hierarchy figure promises exist in what it plots
    rows = json.loads((out / "report.json").read_text())["patches"]
    assert all(r["values"]["test/patch_vertex_error_cm_std"] == 0.05 for r in rows)  # a patch run: scoped
    # legends under the plots: a legend beside them would widen the saved PNG past the figure's width
    from PIL import Image

    assert Image.open(out / "learning_curves.png").size[0] <= 10 * 110 + 20
    assert Image.open(out / "hierarchy.png").size[0] <= 9 * 110 + 20


@pytest.mark.parametrize("inside", [True, False])
def test_relative_paths_leave_other_names_alone(tmp_path, inside):
    from pbc.jobs.report import relative_paths

    sweep = tmp_path / "s"
    out = sweep if inside else tmp_path / "r"
    text = f"{sweep}/a.ckpt {sweep}x/b {sweep}"
    rel = "." if inside else "../s"
    # the sweep dir's sibling "sx" is another directory: left as it was
    assert relative_paths(text, out, sweep) == f"{rel}/a.ckpt {sweep}x/b {rel}"


LOGGING_SCRIPT = """
import logging, logging.config, sys
import lightning  # noqa: F401  (gives its loggers handlers of their own, as in pbc.train)
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
with initialize_config_dir(config_dir=sys.argv[1], version_base="1.3"):
    cfg = compose("config", return_hydra_config=True, overrides=["hydra.runtime.output_dir=" + sys.argv[2]])
conf = OmegaConf.to_container(cfg.hydra.job_logging, resolve=False)
conf["handlers"]["file"]["filename"] = sys.argv[2] + "/job.log"
logging.config.dictConfig(conf)
logging.getLogger("lightning.pytorch.utilities.rank_zero").info("trainer line")
logging.getLogger("lightning.fabric.utilities.seed").info("seed line")
"""


