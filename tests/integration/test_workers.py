"""The drape workers hand back each result as it completes: progress and resume see every finished
drape while slower ones still run (a wait for all of them showed `0/200` for the whole generation)."""

from __future__ import annotations

from helpers.workers import wait_for_flag

from pbc.data.generate import map_in_workers


def test_results_come_back_while_other_jobs_still_run(tmp_path):
    flag = tmp_path / "release"
    results = map_in_workers(wait_for_flag, [("slow", str(flag)), ("fast", None)], workers=2)
    first = next(results)  # must not wait for the slow job, which waits for this test
    assert first == "fast"
    flag.touch()
    assert list(results) == ["slow"]  # released by the flag, not by its 60 s timeout
