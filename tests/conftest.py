"""Shared fixtures: one real tiny dataset per test session (coarse shirt, a few poses, the real drape),
the coarse mannequin, and the test tiers. Synthetic garments for fast tests live in tests/helpers/.

Tiers (markers registered in pyproject.toml, --strict-markers): a test that needs the real tiny dataset is
marked `slow` here automatically; `pytest -m "not slow"` is the quick tier, `make test` runs everything.
"""

from __future__ import annotations

from pathlib import Path

import pytest

# fixtures that drape real data: any test using them (directly or through another fixture) is `slow`
SLOW_FIXTURES = {"tiny_dataset", "draped", "foreign"}
# and tests that take tens of seconds on the 2-core CPU without such a fixture (measured with --durations):
# node-id prefixes, kept here so the tiers are one list
SLOW_TESTS = (
    "tests/test_drape.py::",                                         # the physics engine itself
    "tests/test_evaluate.py::test_evaluate_writes_all_outputs",      # every seam method on 28 crops
    "tests/test_evaluate.py::test_stacked_patch_net_matches_loop",
    "tests/test_stitch.py::test_ground_truth_crops_on_the_real_garment",
    "tests/test_train.py::test_every_config_composes_and_instantiates",  # builds every experiment's net
    "tests/test_sweeps.py::test_every_sweep_composes_for_every_value",
)
TINY_SAMPLES = 10  # poses requested; the distortion check discards some (see the manifest)


def tiny_overrides(data_dir: Path | str, *extra: str) -> list[str]:
    """Config overrides of the session's tiny dataset, rooted at `data_dir`."""
    return ["data=tshirt_tiny", f"paths.data_dir={data_dir}", f"data.num_samples={TINY_SAMPLES}", *extra]


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Directory of a finished `data=tshirt_tiny` dataset made by the real pipeline (generate + drape)."""
    from pbc.config import load_config
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
    from pbc.geometry.skeleton import skeleton_from_config

    return skeleton_from_config(body_cfg)


@pytest.fixture(scope="session")
def body(body_cfg):
    """The coarse mannequin (~1.5K vertices); treat as read-only."""
    from pbc.geometry.body import build_body

    return build_body(body_cfg)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())) or item.nodeid.startswith(SLOW_TESTS):
            item.add_marker(pytest.mark.slow)
