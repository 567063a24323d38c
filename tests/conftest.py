"""Shared fixtures: one real tiny dataset per test session (coarse shirt, a few poses, the real drape),
the coarse mannequin, and the test tiers. Synthetic garments for fast tests live in tests/helpers/.

Tiers are folders: tests/unit (synthetic data, no drape, no subprocess; `make test-fast`), tests/integration
(drapes real data, runs whole jobs), tests/gpu (needs CUDA; skipped elsewhere). The fixture
`unit_tier_rules` here refuses a unit test that drapes or starts a process, so the quick tier stays quick.
"""

from __future__ import annotations

import multiprocessing.context
import subprocess
from pathlib import Path

import pytest

import pbc.sim.batched
import pbc.sim.drape

# session fixtures that drape real cloth: a unit test may not use them
DRAPE_FIXTURES = frozenset({"tiny_dataset", "draped", "foreign"})
UNIT_DIR = Path(__file__).resolve().parent / "unit"
MOVE = "belongs in tests/integration: the unit tier drapes no cloth and starts no process"
TINY_SAMPLES = 10  # poses requested; the distortion check discards some (see the manifest)


def tiny_overrides(data_dir: Path | str, *extra: str) -> list[str]:
    """Config overrides of the session's tiny dataset, rooted at `data_dir`."""
    return ["data=tshirt_tiny", f"paths.data_dir={data_dir}", f"data.num_samples={TINY_SAMPLES}", *extra]


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Directory of a finished `data=tshirt_tiny` dataset made by the real pipeline (generate + drape)."""
    from pbc.core.config import load_config
    from pbc.data.generate import generate

    return generate(load_config(tiny_overrides(tmp_path_factory.mktemp("tiny_data"))))


@pytest.fixture(scope="session")
def foreign(tmp_path_factory):
    """A garment pbc did not make (tests/helpers/tube_top.py), made into a dataset once per session:
    (root, its config overrides, the dataset dir)."""
    from helpers.tube_top import tube_top_dataset

    return tube_top_dataset(tmp_path_factory.mktemp("foreign"))


# --- body and skeleton (conf/body/mannequin.yaml), meshed coarsely so the session pays well under a second
BODY_CONFIG = Path(__file__).resolve().parents[1] / "conf" / "body" / "mannequin.yaml"
COARSE_VOXEL = 0.03  # m; the default mesh is ~0.014


@pytest.fixture(scope="session")
def body_cfg():
    """The mannequin config with a coarse marching-cubes voxel; shared, so copy it before changing it."""
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(BODY_CONFIG)
    cfg.mesh.voxel_size = COARSE_VOXEL
    return cfg


@pytest.fixture(scope="session")
def skeleton(body_cfg):
    from pbc.geometry.body.skeleton import skeleton_from_config

    return skeleton_from_config(body_cfg)


@pytest.fixture(scope="session")
def body(body_cfg):
    """The coarse mannequin (~1.5K vertices); treat as read-only."""
    from pbc.geometry.body.mannequin import build_mannequin

    return build_mannequin(body_cfg)


def pytest_collection_modifyitems(config, items):
    """The folder is the tier; the marker lets `-m "not integration"` select the same set."""
    for item in items:
        tier = Path(str(item.path)).relative_to(Path(__file__).parent).parts[0]
        if tier in ("integration", "gpu"):
            item.add_marker(getattr(pytest.mark, tier))


def _refuse(what: str):
    def refuse(*args, **kwargs):
        raise RuntimeError(f"this test {what}: it {MOVE}")

    return refuse


@pytest.fixture(autouse=True)
def unit_tier_rules(request, monkeypatch):
    """The quick tier's rule, enforced: a test in tests/unit drapes no cloth and starts no process; one that
    needs either fails here with the advice to move it, instead of making the quick tier slow."""
    if UNIT_DIR not in Path(str(request.node.path)).resolve().parents:
        return
    used = DRAPE_FIXTURES & set(request.fixturenames)
    if used:
        pytest.fail(f"{request.node.nodeid} uses {sorted(used)} (real drapes): it {MOVE}", pytrace=False)
    monkeypatch.setattr(subprocess.Popen, "__init__", _refuse("starts a subprocess"))
    monkeypatch.setattr(multiprocessing.context.BaseContext, "Pool", _refuse("starts a process pool"))
    monkeypatch.setattr(pbc.sim.drape, "build_drape_sim", _refuse("drapes cloth"))
    monkeypatch.setattr(pbc.sim.batched.BatchedDrape, "__init__", _refuse("drapes cloth"))


# --- the Anny body (conf/body/anny.yaml): built once per session. On a machine without Anny's asset cache
# ($PBC_CACHE_DIR/anny, else ~/.cache/pbc/anny) the first build takes 1.5-3 min and 790 MB on 2 cores; CI
# keeps that folder between runs. Later sessions load it in about 6 s.
@pytest.fixture(scope="session")
def anny_cfg():
    """The Anny body config; shared, so copy it before changing it."""
    from pbc.core.config import load_config

    return load_config(["body=anny"]).body


@pytest.fixture(scope="session")
def anny_body(anny_cfg):
    """The Anny body (13,718 vertices, 20 posable joints); treat as read-only."""
    from pbc.geometry.body import body_from_config

    return body_from_config(anny_cfg)


@pytest.fixture
def stop_at_data(monkeypatch):
    """pbc.jobs.train.train stops with helpers.train_runs.ReachedTheData where it would open the dataset."""
    from helpers.train_runs import stop_training_at_data

    stop_training_at_data(monkeypatch)
