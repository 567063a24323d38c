"""The wrong-body study's phenotype trials (pbc.robustness): names, parsing, and the refusal on a body that has
no phenotype. The Anny bodies themselves are built in tests/integration/test_anny.py."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from pbc.robustness import load_settings, phenotype_of, phenotype_trials, trial_body, trial_names


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
