"""Shared fixtures: one real tiny dataset per test session (coarse shirt, a few poses, the real drape)."""

from __future__ import annotations

from pathlib import Path

import pytest

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
