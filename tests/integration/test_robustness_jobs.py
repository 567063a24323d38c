"""The wrong-body study (pbc.jobs.robustness) end to end as a sweep of the runner (pbc.sweeps) at scale=smoke on
the real tiny data: one model per body, the report and Figs. 9-10 from the run records."""

from __future__ import annotations

import json

import numpy as np


def test_study_is_a_sweep_of_the_runner(tiny_dataset, tmp_path):
    """`python -m pbc.sweeps robustness scale=smoke` on the session's real tiny data (two trials): the data
    step, the bodies, the Hydra multirun over robustness.trial (one run dir per trial, written through the
    run record) and the report (robustness.json/md, Figs. 9-10) read back from those records."""
    from conftest import TINY_SAMPLES

    from pbc.core.runs import OK, RunRecord
    from pbc.jobs.sweeps import run_sweep

    sweep = tmp_path / "sweep"
    trials = ["shape_0.0", "shape_2.0"]  # the artifact bodies go through the same code (unit tests)
    # a narrow decoder and one epoch: this tests the chain, the numbers come from `scale=smoke|cpu` runs
    sweep_dir, rc = run_sweep("robustness", [
        "scale=smoke", f"paths.data_dir={tiny_dataset.parent}", f"data.num_samples={TINY_SAMPLES}", "logger=csv",
        "model.net.start_channels=32", "trainer.max_epochs=1", "hydra.launcher.n_jobs=1",
        f"robustness.trial={','.join(trials)}"], sweep)
    rec = json.loads((sweep / "sweep.json").read_text())
    assert rc == 0, rec["steps"]
    assert [s["step"] for s in rec["steps"]] == ["data", "bodies", "train"]
    assert rec["steps"][1]["call"] == "pbc.jobs.robustness.prepare_bodies"
    for name in trials:  # one run dir per trial, beside its body; its record names the body it trained on
        record = RunRecord.read(sweep / name)
        assert record.status == OK and record.config["robustness"]["trial"] == name
        assert record.config["data"]["dir"] == str((sweep / "bodies" / name).resolve())
        # the cloth is the same in every trial, only body.npz differs
        assert (sweep / "bodies" / name / "verts.npy").resolve() == (tiny_dataset / "verts.npy").resolve()
    res = json.loads((sweep / "robustness.json").read_text())
    rows = {r["trial"]: r for r in res["rows"]}
    assert set(rows) == set(trials) and res["scale"] == "smoke"
    for name, r in rows.items():
        assert r["status"] == "ok" and np.isfinite(r["test_cm"]) and np.isfinite(r["train_cm"])
        assert r["test_cm"] == RunRecord.read(sweep / name).test["vertex_error_cm"]
    assert rows["shape_2.0"]["max_vertex_move_cm"] > 7.0 and rows["shape_0.0"]["max_vertex_move_cm"] == 0.0
    v = res["verdict"]
    assert v["trials_done"] == 2 and v["holds"] in (True, False)
    assert abs(v["ratios"]["shape_0.0"] - 1.0) < 1e-9
    # the too-thick body pokes through the simulated cloth: its offsets have dn < 0 somewhere
    assert res["penetration"]["shape_2.0"]["ground_truth"]["fraction"] > 0.0
    assert (sweep / "fig9_error_vs_shape.png").stat().st_size > 0
    assert (sweep / "fig10_wrong_body.png").stat().st_size > 0
    md = (sweep / "robustness.md").read_text()
    assert "Verdict" in md and "shape_2.0" in md
