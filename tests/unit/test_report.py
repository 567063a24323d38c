"""pbc.report on synthetic sweep dirs laid out exactly as pbc.train / pbc.evaluate leave them.

No training here: each run dir gets `.hydra/*.yaml`, a `metrics.json` written as pbc.train writes it
(`pbc.core.runs.RunRecord`) and a
TensorBoard events file, so the report's reading, tables, claims and failure handling are checked in
a second.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from helpers.cli import exit_code

from pbc.cli import report as report_cli
from pbc.core.runs import FAILED, INCOMPLETE, OK, RunRecord, load_runs
from pbc.jobs import report, sweeps


def make_run(
    root: Path,
    name: str,
    choices: dict,
    metrics: dict | None,
    curves: dict | None = None,
    job: str = "train",
    overrides: list[str] | None = None,
) -> Path:
    """One Hydra run dir. metrics=None leaves no metrics.json (a killed job)."""
    d = root / name
    (d / ".hydra").mkdir(parents=True)
    hydra_yaml = {"hydra": {"job": {"name": job}, "runtime": {"choices": {**choices, "hydra/launcher": "joblib"}}}}
    (d / ".hydra" / "hydra.yaml").write_text(yaml.safe_dump(hydra_yaml))
    ov = overrides if overrides is not None else [f"{k}={v}" for k, v in choices.items() if k != "experiment"]
    (d / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(ov))
    (d / ".hydra" / "config.yaml").write_text(
        yaml.safe_dump({"data": {"name": "tshirt_tiny", "num_samples": 16}, "trainer": {"max_epochs": 2}})
    )
    if metrics is not None:
        RunRecord.from_dict(metrics).write(d)  # validated as every record is
    if curves:
        from torch.utils.tensorboard import SummaryWriter

        w = SummaryWriter(str(d / "tensorboard"))
        for tag, values in curves.items():
            for step, v in enumerate(values):
                w.add_scalar(tag, v, step)
        w.close()
    return d


def ok_metrics(train_v, train_n, test_v, test_n) -> dict:
    # pbc.train's layout, plus the "train" block (best checkpoint over the training split).
    return {
        "status": "ok",
        "kind": "whole",
        "optimized_metric": "val/vertex_error_cm",
        "val_best": {"vertex_error_cm": test_v},
        "train": {"vertex_error_cm": train_v, "normal_distance": train_n},
        "test": {"vertex_error_cm": test_v, "normal_distance": test_n, "image_loss": 0.01},
        "epochs": 2,
        "seconds": 3.5,
        "config": {"seed": 0},
        "summary": {"lr": 0.001},
    }


def patch_metrics(patch_id, train_v, train_n, test_v, test_n) -> dict:
    """A patch run's record: its metrics over its patch's vertices, under their scoped names."""
    return {"status": "ok", "kind": "patch", "optimized_metric": "val/patch_vertex_error_cm",
            "val_best": {"patch_vertex_error_cm": test_v}, "identity": {"kind": "patch", "patch_id": patch_id},
            "train": {"patch_vertex_error_cm": train_v, "patch_normal_distance": train_n},
            "test": {"patch_vertex_error_cm": test_v, "patch_normal_distance": test_n, "image_loss": 0.01}}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sweep")
    curves = {"train/loss_step": [1.0, 0.5, 0.3], "val/vertex_error_cm": [3.0, 2.0]}
    make_run(root, "0_loss=l1", {"experiment": "whole", "loss": "l1"}, ok_metrics(0.30, 0.021, 0.41, 0.026), curves)
    make_run(root, "1_loss=l2", {"experiment": "whole", "loss": "l2"}, ok_metrics(0.36, 0.018, 0.48, 0.027), curves)
    make_run(
        root,
        "2_loss=l2_normal",
        {"experiment": "whole", "loss": "l2_normal"},
        {
            "status": "failed",
            "error": "FloatingPointError: non-finite train loss nan at global step 3",
            "traceback": "Traceback ...\nFloatingPointError: non-finite",
        },
    )
    # l1_normal: never run (missing). An FC pair in one space, and a killed FC job.
    make_run(
        root,
        "3_experiment=fc_direct_local",
        {"experiment": "fc_direct_local", "loss": "l1"},
        ok_metrics(0.70, 0.05, 0.75, 0.06),
    )
    make_run(
        root,
        "4_experiment=fc_pca_local",
        {"experiment": "fc_pca_local", "loss": "l1"},
        ok_metrics(0.52, 0.05, 0.57, 0.06),
    )
    make_run(root, "5_experiment=fc_pca_root", {"experiment": "fc_pca_root", "loss": "l1"}, None)
    for i, v in ((0, 0.2), (7, 0.25)):
        make_run(
            root,
            f"{6 + i}_experiment=patch_{i:02d}",
            {"experiment": f"patch_{i:02d}", "loss": "l1"},
            patch_metrics(i, v, 0.02, v + 0.1, 0.03) | {"test": {"patch_vertex_error_cm": v + 0.1,
                                                                  "patch_vertex_error_cm_std": 0.05}},
        )
    # pbc.evaluate's layout
    entries = {
        "whole": {"vertex_error_cm": 0.41, "normal_distance": 0.026, "seam_jump_cm": 0.01},
        "patches_average": {"vertex_error_cm": 0.45, "normal_distance": 0.03, "seam_jump_cm": 0.2},
        "patches_pca": {"vertex_error_cm": 0.38, "normal_distance": 0.027, "seam_jump_cm": 0.05},
        "gt_crops_pca": {"vertex_error_cm": 0.02, "normal_distance": 0.001, "seam_jump_cm": 0.001},
        "floor_256": {"vertex_error_cm": 0.01, "normal_distance": 0.001, "seam_jump_cm": 0.0},
    }
    make_run(
        root,
        "evaluate",
        {"stitch": "pca"},
        job="evaluate",
        overrides=[],
        metrics={"split": "test", "num_samples": 3, "entries": entries, "seconds": 2.0},
    )
    return root


def test_runs_read_with_status(sweep):
    runs = {r.name: r for r in load_runs(sweep)}
    assert runs["0_loss=l1"].status == OK
    assert runs["0_loss=l1"].get("experiment") == "whole" and runs["0_loss=l1"].get("loss") == "l1"
    assert runs["0_loss=l1"].metrics["test/vertex_error_cm"] == 0.41
    assert "config/seed" not in runs["0_loss=l1"].metrics  # config blocks are not metrics
    assert runs["0_loss=l1"].curves["train/loss_step"] == [(0, 1.0), (1, 0.5), (2, pytest.approx(0.3))]
    assert runs["2_loss=l2_normal"].status == FAILED
    assert "non-finite train loss" in runs["2_loss=l2_normal"].error
    assert runs["5_experiment=fc_pca_root"].status == INCOMPLETE


@pytest.fixture(scope="module")
def built(sweep, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    report.build_report(sweep, out)
    return out


def test_report_tables_equal_metrics_json(sweep, built):
    md_path = built / "report.md"
    data = json.loads((built / "report.json").read_text())
    t1 = {r["label"]: r for r in data["table1"]}
    for label, name in (("L1", "0_loss=l1"), ("L2", "1_loss=l2")):
        m = json.loads((sweep / name / "metrics.json").read_text())
        for split in ("train", "test"):
            for key in ("vertex_error_cm", "normal_distance"):
                assert t1[label]["values"][f"{split}/{key}"] == m[split][key]
    assert t1["L2 + N"]["status"] == FAILED and "non-finite" in t1["L2 + N"]["error"]
    assert t1["L1 + N"]["status"] == "missing"

    md = md_path.read_text()
    # The markdown cell shows our number with the paper's beside it.
    row = next(line for line in md.splitlines() if line.startswith("| L1 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "0.3 (0.33)" and cells[3] == "0.41 (0.44)" and cells[4] == "0.026 (0.027)"
    assert re.search(r"\| L2 \+ N \| failed", md)
    # Table 2 has its own columns (no normals: the FC baselines are compared on vertices) and figure
    assert "| model | train vertex | test vertex | runs |" in md
    assert "![Table 1](table1.png)" in md and "![Table 2](table2.png)" in md
    # Failed, killed and missing runs are listed with their reason, not dropped.
    assert "FloatingPointError: non-finite train loss nan" in md
    assert "no run with experiment=whole, loss=l1_normal" in md
    assert "no metrics.json" in md
    for png in ("table1.png", "table2.png", "hierarchy.png", "learning_curves.png"):
        assert (built / png).stat().st_size > 1000
    assert not list(built.glob(".*"))  # no temp files left behind


def test_claims_verdicts(built):
    claims = {c["text"]: c for c in json.loads((built / "report.json").read_text())["claims"]}
    assert claims["L1 < L2 on vertex error (train, test)"]["verdict"] == report.HELD
    assert claims["normal loss lowers normal error (L2+N < L2, train)"]["verdict"] == report.NOT_MEASURED
    # Only the local space was measured (root killed, position never run): not measured, with what is missing.
    pca = claims["PCA beats direct (FC, every space, train and test vertex error)"]
    assert pca["verdict"] == report.NOT_MEASURED and "Off. Root." in pca["ours"]
    assert claims["CNN beats FC (test vertex error)"]["verdict"] == report.HELD
    assert claims["patches beat whole (test vertex error)"]["verdict"] == report.HELD
    assert "stitched (pca)" in claims["patches beat whole (test vertex error)"]["ours"]


@pytest.mark.parametrize(
    ("l1", "l2", "verdict"),
    [((0.5, 0.6), (0.4, 0.5), report.NOT_HELD),  # L2 clearly better
     ((3.149, 3.263), (3.150, 3.264), report.TIE)],  # L1 better, but within 1%
)
def test_claim_verdict_from_l1_vs_l2(tmp_path, l1, l2, verdict):
    make_run(tmp_path, "0", {"experiment": "whole", "loss": "l1"}, ok_metrics(l1[0], 0.02, l1[1], 0.03))
    make_run(tmp_path, "1", {"experiment": "whole", "loss": "l2"}, ok_metrics(l2[0], 0.02, l2[1], 0.03))
    report.build_report(tmp_path, plots=False)
    claims = json.loads((tmp_path / "report.json").read_text())["claims"]
    assert claims[0]["verdict"] == verdict


def seeded(seed: int, *values) -> dict:
    m = ok_metrics(*values)
    m["config"] = {"seed": seed}
    return m


@pytest.mark.parametrize(
    ("l1", "l2", "verdict"),
    [(((0.50, 1.40), (0.52, 1.50)), ((0.40, 0.97), (0.41, 0.98)), report.NOT_HELD),  # apart by 4x L1's range
     (((0.50, 1.40), (0.52, 1.50)), ((0.49, 1.43), (0.51, 1.47)), report.WITHIN_NOISE),  # inside the range
     (((0.40, 0.90), (0.41, 0.91)), ((0.50, 1.40), (0.52, 1.50)), report.HELD)],
)
def test_seeds_give_each_row_a_range_and_the_claims_a_noise_level(tmp_path, l1, l2, verdict):
    """Two seeds a setting: the row is their mean with half their range beside it; an ordering whose gap is
    inside the larger range is within noise, a wider gap the wrong way round did not hold."""
    for seed in (0, 1):
        make_run(tmp_path, f"l1_s{seed}", {"experiment": "whole", "loss": "l1"}, seeded(seed, l1[seed][0], 0.02,
                                                                                       l1[seed][1], 0.03))
        make_run(tmp_path, f"l2_s{seed}", {"experiment": "whole", "loss": "l2"}, seeded(seed, l2[seed][0], 0.02,
                                                                                       l2[seed][1], 0.03))
    report.build_report(tmp_path, plots=False)
    data = json.loads((tmp_path / "report.json").read_text())
    row = next(r for r in data["table1"] if r["select"]["loss"] == "l1")
    assert row["values"]["test/vertex_error_cm"] == pytest.approx((l1[0][1] + l1[1][1]) / 2)
    assert row["spread"]["test/vertex_error_cm"] == pytest.approx(abs(l1[1][1] - l1[0][1]))
    assert data["claims"][0]["verdict"] == verdict
    assert "seeds' range" in data["claims"][0]["ours"]
    md = (tmp_path / "report.md").read_text()
    assert f"{report.fmt((l1[0][1] + l1[1][1]) / 2)} ±{report.fmt(abs(l1[1][1] - l1[0][1]) / 2)}" in md


def test_hierarchy_averages_one_evaluation_per_seed(tmp_path):
    """`pbc sweeps paper` evaluates the stitched patches once per seed (evaluate_s<seed>): the rows are the
    means over those evaluations, with their range."""
    for seed, (whole, stitched) in enumerate(((2.0, 1.8), (2.2, 1.9))):
        entries = {"whole": {"vertex_error_cm": whole}, "patches_pca": {"vertex_error_cm": stitched}}
        make_run(tmp_path / "hierarchy", f"evaluate_s{seed}", {"stitch": "pca"}, job="evaluate", overrides=[],
                 metrics={"split": "test", "num_samples": 3, "entries": entries, "seconds": 2.0})
    rows = {r.select["method"]: r for r in report.hierarchy_rows(load_runs(tmp_path, events=False))}
    assert rows["whole"].value("vertex_error_cm") == pytest.approx(2.1)
    assert rows["whole"].noise("vertex_error_cm") == pytest.approx(0.2)
    assert rows["patches_pca"].value("vertex_error_cm") == pytest.approx(1.85)
    assert len(rows["whole"].runs) == 2


def test_train_error_falls_back_to_tensorboard(tmp_path):
    m = ok_metrics(0, 0, 0.4, 0.03)
    del m["train"]
    make_run(
        tmp_path,
        "0",
        {"experiment": "whole", "loss": "l1"},
        m,
        {"train/vertex_error_cm_epoch": [0.9, 0.35], "train/vertex_error_cm_step": [1.0, 0.3]},
    )
    md = report.build_report(tmp_path, plots=False).read_text()
    row = next(line for line in md.splitlines() if line.startswith("| L1 |"))
    assert "0.35* (0.33)" in row and "from TensorBoard" in md


def test_cli_missing_dir(tmp_path, capsys):
    assert exit_code(report_cli.main, [str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_hierarchy_rows_and_evaluate_command(sweep, built):
    rows = {r["label"]: r for r in json.loads((built / "report.json").read_text())["hierarchy"]}
    assert list(rows)[:3] == ["whole", "stitched (average)", "stitched (pca)"]
    assert rows["stitched (pca)"]["values"]["vertex_error_cm"] == 0.38
    assert rows["stitcher on true crops (pca)"]["values"]["seam_jump_cm"] == 0.001
    md = (built / "report.md").read_text()
    hier_md = md.split("## Hierarchy")[1]
    header = next(line for line in hier_md.splitlines() if line.startswith("| model |"))
    # fixed column order, readable names
    assert header == "| model | vertex (cm) | normal (1 - cos) | seam jump (cm) | status |"
    assert "| stitched (pca) | 0.38 | 0.027 | 0.05 | ok |" in md
    patches = {r["label"]: r for r in json.loads((built / "report.json").read_text())["patches"]}
    assert patches["patch_07"]["values"]["test/patch_vertex_error_cm"] == pytest.approx(0.35)
    assert patches["patch_07"]["values"]["test/patch_vertex_error_cm_std"] == pytest.approx(0.05)
    # The runner's evaluation step: the newest whole run trained under the patches' loss (l1 here, though an
    # l2 whole run is newer) and every successful patch run, quoted.
    argv, why = sweeps.evaluate_command(sweep, python="py")
    assert why is None and argv[:3] == ["py", "-m", "pbc.evaluate"]
    assert argv[3] == f"whole_run='{sweep / '0_loss=l1'}'"
    assert argv[4].startswith("patch_runs=[") and argv[4].count("patch_0") == 2


def test_patch_metrics_say_their_scope(tmp_path):
    """A patch run's vertex metrics cover its patch only: recorded and read back as patch_*, shown so in the
    report, never as a whole-garment number; a whole run's keep their names."""
    from pbc.core.runs import monitor, scoped_name

    assert monitor("whole") == "val/vertex_error_cm" and monitor("patch") == "val/patch_vertex_error_cm"
    assert monitor("patches") == "val/vertex_error_cm"  # the stacked run's mean over its patches
    assert scoped_name("vertex_error_cm_std", "patch") == "patch_vertex_error_cm_std"
    assert scoped_name("image_loss", "patch") == "image_loss"
    assert scoped_name("normal_distance", "fc") == "normal_distance"
    make_run(tmp_path, "new", {"experiment": "patch_03"}, patch_metrics(3, 0.2, 0.02, 0.3, 0.03),
             {"val/patch_vertex_error_cm": [0.5, 0.3], "train/patch_vertex_error_cm_epoch": [0.9, 0.4]})
    make_run(tmp_path, "other", {"experiment": "patch_05"}, patch_metrics(5, 0.2, 0.02, 0.4, 0.03))
    make_run(tmp_path, "whole", {"experiment": "whole", "loss": "l1"}, ok_metrics(0.2, 0.02, 0.5, 0.03))
    runs = {r.name: r for r in load_runs(tmp_path)}
    for name, test_v in (("new", 0.3), ("other", 0.4)):
        r = runs[name]
        assert r.metrics["test/patch_vertex_error_cm"] == test_v and "test/vertex_error_cm" not in r.metrics
        assert r.metrics["val_best/patch_vertex_error_cm"] == test_v and "train/vertex_error_cm" not in r.metrics
        assert r.record.metric("test", "vertex_error_cm") == test_v  # the record looks up the scoped name
    assert runs["whole"].metrics["test/vertex_error_cm"] == 0.5
    assert "test/patch_vertex_error_cm" not in runs["whole"].metrics
    report.build_report(tmp_path, tmp_path / "out")
    md = (tmp_path / "out" / "report.md").read_text()
    assert "| patch_03 | 0.2 | 0.3 | 0.03 | ok |" in md and "| patch_05 | 0.2 | 0.4 | 0.03 | ok |" in md
    assert "| `new` | experiment=patch_03 | ok | 0.3 (patch) | 0.03 (patch) |" in md
    assert "| `whole` | experiment=whole | ok | 0.5 | 0.03 |" in md  # loss: only this run has the key


def test_labels_name_what_the_experiment_varies_even_beside_an_evaluate_job(tmp_path):
    # a hierarchy sweep: 3 patch runs + the whole run (experiment sets model) + the evaluate job, whose
    # config has none of the training choices; the curves' labels must read experiment=..., not every key
    common = {"body": "mannequin", "data": "tshirt_tiny", "loss": "l1"}
    for i in range(3):
        make_run(tmp_path, f"{i}_p", {**common, "experiment": f"patch_{i:02d}", "model": "patch"},
                 patch_metrics(i, 0.2, 0.02, 0.3, 0.03))
    make_run(tmp_path, "3_w", {**common, "experiment": "whole", "model": "whole"}, ok_metrics(0.2, 0.02, 0.3, 0.03))
    make_run(tmp_path, "evaluate", {"stitch": "pca"}, None, job="evaluate")
    runs = load_runs(tmp_path, events=False)
    labels = {r.name: report.label_of(r, runs) for r in runs}
    assert labels["0_p"] == "experiment=patch_00" and labels["3_w"] == "experiment=whole"
