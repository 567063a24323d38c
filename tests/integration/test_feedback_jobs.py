"""What a researcher sees: progress bars and logs, `pbc.main`'s run dirs and --help, the TensorBoard image
panel, dataset preview figures and report figures. All synthetic and fast (no drape, no training)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------ progress and logs








# ------------------------------------------------------------------------------------------- pbc.main
def test_main_help_exits_zero_and_writes_nothing(tmp_path):
    env = dict(os.environ, PBC_ROOT=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "pbc.main", "--help"], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("usage: python -m pbc.main") and "pbc.train +experiment=whole" in r.stdout
    assert "Traceback" not in r.stderr and not (tmp_path / "runs").exists()


def test_main_names_the_failed_step_without_a_traceback(tmp_path):
    env = dict(os.environ, PBC_ROOT=str(tmp_path))
    r = subprocess.run([sys.executable, "-m", "pbc.main", "data=no_such_data"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode != 0
    assert "pbc.main: step 'make the dataset and its preview figures' failed" in r.stderr
    assert "CalledProcessError" not in r.stderr and "no_such_data" in r.stderr  # the step's own message
    assert len(list((tmp_path / "runs" / "main").glob("20*"))) == 1




# --------------------------------------------------------------------------------- TensorBoard panel
def _images(b=2, h=16, w=16):
    gen = torch.Generator().manual_seed(0)
    gt = 0.05 * torch.randn(b, 6, h, w, generator=gen)
    mask = torch.zeros(b, 1, h, w)
    mask[..., 2:-2, 3:-3] = 1
    return gt * mask, mask






# ------------------------------------------------------------------------------------- per-pose spread


# ------------------------------------------------------------------------------------ dataset preview


# ------------------------------------------------------------------------------------------- reports




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


def test_lightning_lines_print_once_and_reach_the_log_file(tmp_path):
    r = subprocess.run([sys.executable, "-c", LOGGING_SCRIPT, str(ROOT / "conf"), str(tmp_path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    console = r.stdout + r.stderr
    assert console.count("trainer line") == 1 and console.count("seed line") == 1, console
    log_file = (tmp_path / "job.log").read_text()
    assert "trainer line" in log_file and "seed line" in log_file
