"""Jobs for pbc.data.generate.map_in_workers tests (importable by spawned workers)."""

from __future__ import annotations

import time
from pathlib import Path


def wait_for_flag(job: tuple[str, str | None]) -> str:
    """(name, flag file or None): return at once, or when the flag file appears ('timeout' after 60 s)."""
    name, flag = job
    if flag is None:
        return name
    for _ in range(600):
        if Path(flag).exists():
            return name
        time.sleep(0.1)
    return "timeout"
