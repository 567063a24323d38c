"""pbc installed as a user installs it: a wheel (not editable) in a fresh venv, run from a folder outside
the repository. Every console script answers --help, the Hydra jobs compose their config from the conf/
shipped in the wheel (`--cfg job`), and the users' own `python -m pbc.train +experiment=patch_07` works.

The fresh venv borrows the test interpreter's installed dependencies through a .pth line (torch and
newton are gigabytes; the point is pbc's own install), so only pbc comes from the wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"])


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path]:
    """(the venv's bin dir, an empty working folder outside the repository)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"  # build from a copy: the checkout stays untouched (no build/ folder left in it)
    for name in ("pbc", "conf", "patches"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", str(src),
                    "-w", str(tmp / "dist")], check=True, capture_output=True)
    wheel = next((tmp / "dist").glob("pbc-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    site = next(venv.glob("lib/python*/site-packages"))
    (site / "_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([venv / "bin" / "python", "-m", "pip", "install", "-q", "--no-deps", str(wheel)], check=True,
                   capture_output=True)
    work = tmp / "user"
    work.mkdir()
    return venv / "bin", work


def run(cmd: list, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=300,
                          env={"PATH": "/usr/bin:/bin", "HOME": str(cwd)})


def test_the_wheel_ships_pbc_and_its_configs_not_the_checkout(installed):
    bin_dir, work = installed
    r = run([bin_dir / "python", "-c", "import pbc, pbc.core.paths as p; print(pbc.__file__); print(p.CONF_DIR); "
             "print(p.PATCHES_DIR)"], work)
    assert r.returncode == 0, r.stderr
    pkg, conf, patches = r.stdout.split()
    assert str(ROOT) not in pkg and Path(conf) == Path(pkg).parent / "conf" and Path(patches).name == "patches"
    assert (Path(conf) / "experiment" / "patch_07.yaml").is_file() and (Path(patches) / "tshirt.json").is_file()


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_console_script_answers_help(installed, script):
    bin_dir, work = installed
    r = run([bin_dir / script, "--help"], work)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() and "Traceback" not in r.stderr


def test_the_jobs_compose_from_the_shipped_configs(installed):
    bin_dir, work = installed
    for cmd in (["pbc-train", "--cfg", "job", "+experiment=patch_07"], ["pbc", "generate", "--cfg", "job"],
                ["pbc-evaluate", "--cfg", "job", "patch_runs=null", "whole_run=x"]):
        r = run([bin_dir / cmd[0], *cmd[1:]], work)
        assert r.returncode == 0, (cmd, r.stderr)
        assert "data:" in r.stdout or "whole_run" in r.stdout, cmd
    # the users' own command, and the dispatcher as a module
    r = run([bin_dir / "python", "-m", "pbc.train", "--cfg", "job", "+experiment=patch_07"], work)
    assert r.returncode == 0 and "patch_id: 7" in r.stdout, r.stderr
    r = run([bin_dir / "python", "-m", "pbc", "--help"], work)
    assert r.returncode == 0 and "train" in r.stdout
    # the committed cage is found inside the wheel
    r = run([bin_dir / "pbc", "cage", "garment=tshirt_coarse", "--out", work / "auto.json"], work)
    assert r.returncode == 0 and "patches/tshirt_coarse.json: {'patches': 28" in r.stdout, r.stderr


def test_user_errors_outside_a_project_are_one_line(installed):
    bin_dir, work = installed
    r = run([bin_dir / "pbc", "nope"], work)
    assert r.returncode == 2 and "unknown command 'nope'" in r.stderr and "generate" in r.stderr
    r = run([bin_dir / "pbc", "preview", "data/tshirt_small_seed0"], work)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "pbc generate" in r.stderr and str(work / "data") in r.stderr


def test_the_shipped_model_predicts_from_the_wheel(installed):
    """pbc/pretrained ships in the wheel: `--pretrained tshirt` (the starter, a fully connected model) and
    `--pretrained tshirt_mannequin` (an image CNN) predict outside any project, and write nothing into the
    installed package (the CNN's image operators go to the user cache)."""
    bin_dir, work = installed
    for name in ("tshirt", "tshirt_mannequin"):
        r = run([bin_dir / "pbc", "predict", "--pretrained", name, "--poses", "test", "--max", "2", "--sheet", "0",
                 "--out", work / f"pred_{name}"], work)
        assert r.returncode == 0, r.stderr
        assert "2 poses" in r.stdout and "vertex error vs simulation" in r.stdout
    r = run([bin_dir / "python", "-c", "import pbc.pretrained as p; print(p.SHIPPED_DIR)"], work)
    shipped = Path(r.stdout.strip())
    assert str(ROOT) not in str(shipped)
    assert not any((shipped / name / "data" / "operators").exists() for name in ("tshirt", "tshirt_mannequin"))
    assert list((work / ".cache" / "pbc" / "operators").glob("*.npz"))
