"""The wrong-body study's phenotype trials (pbc.jobs.robustness): names, parsing, and the refusal on a body that has
no phenotype. The Anny bodies themselves are built in tests/integration/test_anny.py."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from pbc.jobs.robustness import load_settings, phenotype_of, phenotype_trials, trial_body, trial_names


def test_phenotype_trials_are_named_and_parsed_back():
    rob = load_settings()
    names = phenotype_trials(rob)
    assert len(names) == sum(len(v) for v in rob.phenotypes.values())
    assert "phenotype_height_-0.20" in names and "phenotype_weight_0.30" in names
    assert [phenotype_of(n) for n in names[:2]] == [("height", -0.2), ("height", 0.2)]
    assert phenotype_of("shape_1.0") is None
    assert not set(names) & set(trial_names(rob))  # the mannequin's default list holds none of them
    with pytest.raises(ValueError, match="phenotype_<key>_<delta>"):
        phenotype_of("phenotype_height_tall")


def test_phenotype_trial_needs_anny(body):
    rob = load_settings()
    with pytest.raises(ValueError, match="run the study on Anny"):
        trial_body(body, "phenotype_height_0.20", rob, OmegaConf.create({"kind": "mannequin"}))
    with pytest.raises(ValueError, match="run the study on Anny"):
        trial_body(body, "phenotype_height_0.20", rob)


def _row(trial, shape, test):
    return {"trial": trial, "shape": shape, "status": "ok", "train_cm": test + 0.5, "test_cm": test,
            "mean_baseline": {"test_cm": test + 0.1}}


def test_fig9_draws_the_phenotype_panel_and_drops_an_empty_sculpt_panel(tmp_path):
    from PIL import Image  # noqa: PLC0415 - only this test reads the image back

    from pbc.jobs.robustness import fig9  # noqa: PLC0415 - plotting helpers, only this test draws

    pheno = [_row("shape_0.0", 0.0, 3.0), _row("phenotype_height_0.20", None, 3.2)]
    both = pheno + [_row("shape_1.0", 1.0, 3.1), _row("paint_torso", None, 3.3)]
    w_pheno = Image.open(fig9(tmp_path / "a.png", pheno)).size[0]
    w_both = Image.open(fig9(tmp_path / "b.png", both)).size[0]
    w_shapes = Image.open(fig9(tmp_path / "c.png", both[2:] + pheno[:1])).size[0]
    assert w_both > 1.8 * w_pheno and abs(w_shapes - w_pheno) < 0.1 * w_pheno  # two panels vs one
