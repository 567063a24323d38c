"""Shared fixtures: one real tiny dataset per test session (coarse shirt, a few poses, the real drape),
the coarse mannequin, and the test tiers. Synthetic garments for fast tests live in tests/helpers/.

Tiers are folders: tests/unit (synthetic data, no drape, no subprocess; `make test-fast`), tests/integration
(drapes real data, runs whole jobs), tests/gpu (needs CUDA; skipped elsewhere). The fixture
`unit_tier_rules` here refuses a unit test that drapes or starts a process, so the quick tier stays quick.
"""

from __future__ import annotations

import json
import multiprocessing.context
import os
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


ROOT = Path(__file__).resolve().parents[1]
# Parallel runs (`make test`: pytest-xdist, TEST_WORKERS processes): the name of this worker, None in a plain run
XDIST_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
# Every drape of the session, here and in the jobs the tests start (they inherit the variable), shares one warp
# kernel cache: the checkout's .cache/warp, conf/sim/style3d.yaml's default for a run from the repository. A job
# run under another PBC_ROOT (a tmp folder) would otherwise compile every kernel again, about a minute of CPU.
# Warp writes each kernel in a folder of its own process and renames it into place: parallel workers are safe.
os.environ.setdefault("PBC_WARP_CACHE", str(ROOT / ".cache" / "warp"))


@pytest.fixture(autouse=True)
def no_hydra_config_left():
    """Each test starts outside any Hydra app: an entry point run in-process leaves Hydra's global HydraConfig set
    (a command-line run is one process per command), which would make later library calls (pbc.jobs.train's
    output_dir) read a finished app's config."""
    from hydra.core.hydra_config import HydraConfig

    yield
    HydraConfig.instance().cfg = None


@pytest.fixture(scope="session", autouse=True)
def no_user_models(tmp_path_factory):
    """The user's models folder ($PBC_MODELS, pbc.pretrained.user_models_dir) is an empty folder of the session
    for every test and every job it starts: `--pretrained tshirt` is the shipped model whatever the machine's
    user packed (a test of user models points the variable at its own folder)."""
    saved = os.environ.get("PBC_MODELS")
    os.environ["PBC_MODELS"] = str(tmp_path_factory.mktemp("user_models"))
    yield
    if saved is None:
        os.environ.pop("PBC_MODELS", None)
    else:
        os.environ["PBC_MODELS"] = saved


def once_per_run(tmp_path_factory, name: str, build, encode=str, decode=Path):
    """`build(folder)` for a session fixture, once per test run. A plain run builds in its tmp folder. In a
    parallel run the first worker that asks builds in the run's tmp folder shared by the workers, under a file
    lock, and writes `encode(result)` beside it (JSON); the others wait for the lock and read it (`decode`).
    The result is shared as sequential runs share it between test files: tests read it, and what jobs write
    beside it (operator caches) is written atomically."""
    if not XDIST_WORKER:
        return build(tmp_path_factory.mktemp(name))
    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp().parent  # pytest-N/, above each worker's pytest-N/popen-gwK/
    record = shared / f"{name}.json"
    with FileLock(str(shared / f"{name}.lock")):
        if not record.is_file():
            folder = shared / name
            folder.mkdir()
            record.write_text(json.dumps(encode(build(folder))))
    return decode(json.loads(record.read_text()))


def tiny_overrides(data_dir: Path | str, *extra: str) -> list[str]:
    """Config overrides of the session's tiny dataset, rooted at `data_dir`."""
    return ["data=tshirt_tiny", f"paths.data_dir={data_dir}", f"data.num_samples={TINY_SAMPLES}", *extra]


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Directory of a finished `data=tshirt_tiny` dataset made by the real pipeline (generate + drape)."""
    from pbc.core.config import load_config
    from pbc.data.generate import generate

    return once_per_run(tmp_path_factory, "tiny_data", lambda d: generate(load_config(tiny_overrides(d))))


@pytest.fixture(scope="session")
def foreign(tmp_path_factory):
    """A garment pbc did not make (tests/helpers/tube_top.py), made into a dataset once per session:
    (root, its config overrides, the dataset dir)."""
    from helpers.tube_top import tube_top_dataset

    return once_per_run(tmp_path_factory, "foreign", tube_top_dataset,
                        encode=lambda r: [str(r[0]), list(r[1]), str(r[2])],
                        decode=lambda r: (Path(r[0]), r[1], Path(r[2])))


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


# --- parallel runs (`make test`: pytest-xdist). Each worker has its own tmp folders; the real tiny datasets are
# made once per run (once_per_run); warp's kernel cache is safe as is (above); Anny's asset cache, written in
# place and not atomically, is built under a lock (anny_cache_built_once). The Makefile hands the workers whole
# files (--dist loadfile: a module fixture is built once), in collection order (--no-loadscope-reorder: the long
# integration files first, the short unit files last, so both workers finish together).
def pytest_configure(config):
    """In an xdist worker, torch computes on one thread, and so do the jobs the tests start (OMP_NUM_THREADS,
    inherited): two workers on two cores, each with a thread per core, would fight over them."""
    if XDIST_WORKER:
        import torch

        os.environ["OMP_NUM_THREADS"] = "1"
        torch.set_num_threads(1)


@pytest.fixture(scope="session", autouse=True)
def anny_cache_built_once():
    """Parallel workers share Anny's asset cache, which Anny writes in place: the first worker loads (so builds,
    on a machine without it) the tests' two Anny topologies under a file lock; the other waits, then reads it.
    With a built cache this costs a worker about 2 s, and the loaded models are reused (lru_cache)."""
    if not XDIST_WORKER:
        yield
        return
    from filelock import FileLock

    from pbc.core.config import load_config
    from pbc.geometry.body.anny import MAKEHUMAN_TOPOLOGY, anny_cache_dir, load_anny_model

    cfg = load_config(["body=anny"]).body
    cache = anny_cache_dir()
    cache.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(cache) + ".lock"):
        for topology in (str(cfg.topology), MAKEHUMAN_TOPOLOGY):
            load_anny_model(str(cfg.rig), topology)
    yield


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


CORPUS = Path(__file__).resolve().parents[1].parent / "shared" / "corpus"  # ../shared/corpus from the repo root


@pytest.fixture(scope="session")
def corpus() -> Path:
    """The real-world corpus (files as other tools wrote them, ../shared/corpus/README.md). Missing is a failure,
    never a skip: it is every door's yardstick."""
    if not (CORPUS / "README.md").is_file():
        pytest.fail(f"the corpus is missing at {CORPUS}: the tests read real clips and garments from "
                    "../shared/corpus (beside the repository); put it there")
    return CORPUS
