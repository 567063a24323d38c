"""Procedural garments sized to the body (pbc.geometry.garment.sizing, `garment.size_to_body`): the reference is the
mannequin's own measurements, so sizing to it changes nothing; on a bigger body each rule follows its landmark."""

from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.geometry.garment import garment_from_config, garment_needs_body
from pbc.geometry.garment.sizing import landmarks, size_necktie, size_tshirt, sized_config


def _sized(overrides=()):
    gcfg = load_config(["garment.size_to_body.enabled=true", *overrides]).garment
    return gcfg, dict(gcfg.size_to_body.reference)


def test_reference_is_the_mannequins_own_measurements(body):
    # the committed reference was measured on the full mannequin; the coarse test mesh measures within 1 cm
    _, ref = _sized()
    got = landmarks(body)
    for key, value in ref.items():
        assert got[key] == pytest.approx(value, abs=0.01), key


@pytest.mark.parametrize("preset", ["tshirt", "necktie"])
def test_sizing_to_the_reference_changes_nothing(preset):
    gcfg, ref = _sized([f"garment={preset}"])
    rule = size_tshirt if preset == "tshirt" else size_necktie
    for key, value in rule(gcfg, ref).items():
        assert value == pytest.approx(float(gcfg[key]), abs=1e-12), key


def test_each_rule_follows_its_landmark():
    gcfg, ref = _sized()
    big = {k: 1.1 * v for k, v in ref.items()}  # every length 10% longer, every position 10% farther out
    sized = size_tshirt(gcfg, big)
    assert sized["chest_girth"] == pytest.approx(1.1 * gcfg.chest_girth)
    assert sized["torso_length"] == pytest.approx(1.1 * gcfg.torso_length)
    assert sized["shoulder_height"] == pytest.approx(gcfg.shoulder_height + 0.1 * ref["shoulder_height"])
    assert sized["center_z"] == pytest.approx(gcfg.center_z + 0.1 * ref["arm_z"])
    tie, tie_ref = _sized(["garment=necktie"])
    thick = dict(tie_ref, neck_radius=tie_ref["neck_radius"] + 0.01)
    sized = size_necktie(tie, thick)
    assert sized["neck_radius"] == pytest.approx(tie.neck_radius + 0.01)
    assert sized["neck_girth"] > tie.neck_girth


def test_sized_shirt_on_a_bigger_body_is_bigger(body):
    gcfg, _ = _sized()
    garment, cage = garment_from_config(gcfg, body)
    m = landmarks(body)
    bigger = {k: v * 1.15 for k, v in m.items()}
    sized = OmegaConf.merge(gcfg, size_tshirt(gcfg, bigger), {"cage": None, "size_to_body": {"enabled": False}})
    big, big_cage = garment_from_config(sized)
    assert big.num_vertices > garment.num_vertices  # a wider, longer pattern on the same grid spacing
    assert np.ptp(np.asarray(big.vertices)[:, 1]) > np.ptp(np.asarray(garment.vertices)[:, 1])
    assert len(big_cage.patches) == len(cage.patches)  # the same cage rule: the same patches


def test_the_sized_mannequin_shirt_is_the_shirt(body):
    gcfg, _ = _sized()
    plain, _ = garment_from_config(load_config([]).garment)
    sized, _ = garment_from_config(gcfg, body)
    assert garment_needs_body(gcfg) and not garment_needs_body(load_config([]).garment)
    if sized.num_vertices == plain.num_vertices:  # the coarse test body's chest may move the pattern a cell
        assert np.abs(np.asarray(sized.vertices) - np.asarray(plain.vertices)).max() < 0.02


def test_sizing_needs_the_body_and_a_procedural_garment():
    gcfg, _ = _sized()
    with pytest.raises(ValueError, match=r"garment_from_config\(gcfg, body\)"):
        garment_from_config(gcfg)
    obj = OmegaConf.merge(gcfg, {"kind": "obj"})
    with pytest.raises(ValueError, match="size_to_body.enabled=true sizes the procedural garments"):
        sized_config(obj, body=None)
