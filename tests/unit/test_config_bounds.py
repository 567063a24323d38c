"""Every sim, image and motion number held to its range in conf/bounds.yaml at the doors where it enters: a
value out of range or of another type is one line naming the key, the value and the range, in one
ValueError listing every problem, before anything is written. The shipped configs and the shipped models'
recorded configs pass."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
from omegaconf import OmegaConf

import pbc.core.validate as validate
from pbc.core.config import load_config
from pbc.core.paths import CONF_DIR
from pbc.core.validate import bounds_table, check_bounds, check_config, check_motion_settings
from pbc.motion import retarget
from pbc.motion.dialects import dialect_settings
from pbc.motion.retarget import check_motion_files

FPS_TEXT = "expected a number in [1, 240] (frames per simulated second)"
FPS_RANGE = re.escape(FPS_TEXT)
CLIP = Path(__file__).resolve().parents[1] / "data" / "bvh" / "cmu_mb_02_01_walk.bvh"
MODELS = sorted((Path(validate.__file__).resolve().parents[1] / "pretrained").glob("*/metrics.json"))


def _problems(err: pytest.ExceptionInfo) -> list[str]:
    """The problem lines of a refusal (after its heading line)."""
    head, *lines = str(err.value).splitlines()
    assert head.startswith("invalid "), head
    return [line.removeprefix("  - ") for line in lines]


# ============================================================================ the user battery's fps cases
@pytest.mark.parametrize("value, shown", [("-5", "-5 (int)"), ("0", "0 (int)"), ("1e9", "1000000000.0 (float)")])
def test_a_frame_rate_out_of_range_is_refused_at_generate_and_nothing_is_written(tmp_path, value, shown):
    """-5 made a 'ready' dataset of drapes 1.3-3.1 cm off, 0 a ZeroDivisionError, 1e9 discarded every drape."""
    from pbc.data.generate import generate

    data = tmp_path / "data"
    data.mkdir()
    with pytest.raises(ValueError) as err:
        generate(load_config(["data=tshirt_tiny", f"paths.data_dir={data}", f"sim.fps={value}"]))
    assert _problems(err) == [f"sim.fps={shown}: {FPS_TEXT}"]
    assert list(data.iterdir()) == []  # no dataset folder, no lock, no fingerprint to block the corrected retry


def test_training_refuses_a_frame_rate_out_of_range_before_its_run_dir_or_data(tmp_path):
    from pbc.jobs.train import train

    cfg = load_config(["data=tshirt_tiny", "+experiment=fc_direct_local", "trainer=smoke", "callbacks=minimal",
                       "logger=csv", f"paths.data_dir={tmp_path / 'data'}", f"paths.output_dir={tmp_path / 'run'}",
                       "sim.fps=0"])
    with pytest.raises(ValueError, match=rf"sim\.fps=0 \(int\): {FPS_RANGE}"):
        train(cfg)
    assert list(tmp_path.iterdir()) == []


def test_garment_fit_and_inspect_refuse_sim_overrides_out_of_range_before_their_folder(tmp_path):
    """A fit's record holds its overrides: one written for sim.fps=0 would refuse the corrected retry."""
    from pbc.cli.garment import run
    from pbc.jobs.garment_fit import Fit

    obj = tmp_path / "shirt.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=rf"sim\.fps=0 \(int\): {FPS_RANGE}"):
        Fit(obj, ["sim.fps=0"], tmp_path / "fit").run()
    with pytest.raises(ValueError, match=rf"sim\.fps=-5 \(int\): {FPS_RANGE}"):
        run(["inspect", str(obj), "sim.fps=-5", "--out", str(tmp_path / "inspect")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shirt.obj"]


# ============================================================================ one line each, every one at once
MISTYPED = [
    ("sim.fps=ten", "sim.fps='ten' (str): expected a number in [1, 240] (frames per simulated second)"),
    ("sim.max_frames=600.0", "sim.max_frames=600.0 (float): expected an integer in [1, 100000]"),
    ("sim.fps=true", "sim.fps=True (bool): expected a number in [1, 240] (frames per simulated second)"),
    ("sim.stretch_ke=[100,100]", "sim.stretch_ke=[100, 100] (list): expected a list of 3 numbers in (0, 1e6] "
                                 "(weft, warp, shear)"),
    ("sim.stretch_ke=[100,100,-40]", "sim.stretch_ke=[100, 100, -40] (list): expected a list of 3 numbers in "
                                     "(0, 1e6] (weft, warp, shear)"),
    ("sim.discard.max_area_compression=75", "sim.discard.max_area_compression=75 (int): expected a number in [0, 1] "
                                            "(fraction of the rest area)"),
    ("sim.batch_worlds=0", "sim.batch_worlds=0 (int): expected null or an integer >= 1"),
    ("sim.velocity_damping=1.0", "sim.velocity_damping=1.0 (float): expected a number in [0, 1) "
                                 "(fraction of the velocity removed each frame)"),
    ("image.whole_rows=[0.6,0.4]", "image.whole_rows=[0.6, 0.4] (list): expected [first, last] with first < last, "
                                   "numbers in [0, 1] (fractions of the image height)"),
    ("image.crop_size=600", "image.crop_size=600 is more than image.reference_resolution=512: expected "
                            "image.crop_size <= image.reference_resolution"),
]


@pytest.mark.parametrize("override, line", MISTYPED, ids=[row[0] for row in MISTYPED])
def test_a_mistyped_or_out_of_range_value_is_one_line_with_the_key_the_value_and_the_range(override, line):
    cfg = load_config([override])
    for check in (check_bounds, check_config):
        with pytest.raises(ValueError) as err:
            check(cfg)
        assert _problems(err) == [line]


def test_every_problem_is_listed_at_once():
    cfg = load_config(["sim.fps=0", "sim.thickness=5", "sim.friction=-1", "image.crop_size=0", "model.lr=0"])
    with pytest.raises(ValueError) as err:
        check_config(cfg)
    keys = [re.match(r"[\w.]+", line)[0] for line in _problems(err)]
    assert keys == ["model.lr", "sim.fps", "sim.thickness", "sim.friction", "image.crop_size"]
    assert "sim.thickness=5 (int): expected a number in (0, 0.05] (m)" in _problems(err)


def test_motion_settings_out_of_range_are_refused_naming_the_file_and_the_key():
    motion = OmegaConf.load(CONF_DIR / "motion" / "sequence.yaml")
    motion.max_frames, motion.known.quantile, motion.units.cm = 0, 1.5, -0.01
    motion.sanity.height_m = [2.4, 1.0]
    with pytest.raises(ValueError) as err:
        check_motion_settings("motion", motion, CONF_DIR / "motion" / "sequence.yaml")
    assert _problems(err) == [
        "conf/motion/sequence.yaml: units.cm=-0.01 (float): expected a number > 0 (metres per file unit)",
        "conf/motion/sequence.yaml: max_frames=0 (int): expected an integer >= 1 (poses one request may make)",
        "conf/motion/sequence.yaml: sanity.height_m=[2.4, 1.0] (list): expected [first, last] with first < last, "
        "numbers in (0, 10] (m)",
        "conf/motion/sequence.yaml: known.quantile=1.5 (float): expected a number in (0, 1] "
        "(quantile of the model's test poses)"]


def test_the_motion_doors_read_the_settings_first(tmp_path, monkeypatch):
    """pbc motion inspect and the clip reader of pbc predict / view refuse before the clip is read."""
    from pbc.cli.motion import run
    from pbc.inference.poses import read_motion

    bad = tmp_path / "sequence.yaml"
    shutil.copy(CONF_DIR / "motion" / "sequence.yaml", bad)
    bad.write_text(bad.read_text().replace("max_frames: 100000", "max_frames: -1"))
    monkeypatch.setattr(retarget, "SETTINGS_FILE", bad)
    needle = re.escape(f"{bad}: max_frames=-1 (int): expected an integer >= 1")
    with pytest.raises(ValueError, match=needle):
        run(["inspect", str(CLIP), "--no-figure"])
    with pytest.raises(ValueError, match=needle):
        read_motion(CLIP, dataset=None)


# ============================================================================ what ships passes
def _options(group: str, skip=re.compile(r"_|patch_\d\d$")) -> list[str]:
    """A group's presets; of the per-patch experiments only patch_00 (the rest differ by model.patch_id)."""
    return sorted(p.stem for p in (CONF_DIR / group.lstrip("+")).glob("*.yaml")
                  if not skip.match(p.stem) or p.stem == "patch_00")


@pytest.mark.parametrize("override", [f"{g}={o}" for g in ("data", "garment", "sim", "+experiment", "+scale")
                                      for o in _options(g)])
def test_every_shipped_preset_passes(override):
    check_bounds(load_config([override]))


def test_the_shipped_motion_settings_pass():
    dialect_settings.cache_clear()  # read again, not taken from an earlier test's load
    check_motion_files()


@pytest.mark.parametrize("metrics", MODELS, ids=lambda p: p.parent.name)
def test_every_shipped_models_recorded_config_passes(metrics):
    check_config(OmegaConf.create(json.loads(metrics.read_text())["config"]))


def _numbers(node: dict, prefix: str) -> list[str]:
    """The dotted keys of a settings file's numbers, booleans and lists of numbers (a mapping of names to
    numbers, sequence.yaml's units, is one key)."""
    out = []
    for k, v in node.items():
        key = f"{prefix}.{k}"
        if isinstance(v, dict) and k != "units":
            out += _numbers(v, key)
        elif (isinstance(v, bool | int | float) or (isinstance(v, list) and v and all(isinstance(x, int | float)
                                                                                      for x in v))
              or isinstance(v, dict)):
            out.append(key)
    return out


def test_every_number_of_the_sim_image_and_motion_files_has_a_row():
    files = [*(("sim", p) for p in (CONF_DIR / "sim").glob("*.yaml")),
             *(("image", p) for p in (CONF_DIR / "image").glob("*.yaml")),
             ("motion", CONF_DIR / "motion" / "sequence.yaml"), ("dialects", CONF_DIR / "motion" / "dialects.yaml")]
    table, _ = bounds_table()
    keys = [key for section, path in files
            for key in _numbers(OmegaConf.to_container(OmegaConf.load(path), resolve=False), section)]
    assert "sim.fps" in keys and "motion.units" in keys and "dialects.rest.frame.max_knee_bend_deg" in keys
    assert [key for key in keys if key not in table] == []
