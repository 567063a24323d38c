"""sim.self_collision_stiffness reaches Style3D's cloth-cloth terms; a mistyped term is one clear error."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from omegaconf import OmegaConf

from pbc.core.config import load_config
from pbc.sim.drape import configure_self_collision


def newton_collision():
    """What newton 1.8.0's Style3D `Collision` starts with."""
    return SimpleNamespace(radius=3e-3, stiff_vf=0.5, stiff_ee=0.1, stiff_ef=1.0)


def test_config_sets_the_three_terms_and_the_radius():
    sim = load_config([]).sim
    c = newton_collision()
    configure_self_collision(c, sim)
    assert c.radius == pytest.approx(float(sim.self_collision_radius))
    assert (c.stiff_vf, c.stiff_ee, c.stiff_ef) == (0.5, 0.1, 0.0)  # untangling off by default

    c = newton_collision()
    configure_self_collision(c, OmegaConf.create({"self_collision_stiffness": {"untangle": 0.3}}))
    assert (c.stiff_vf, c.stiff_ee, c.stiff_ef, c.radius) == (0.5, 0.1, 0.3, 3e-3)  # others keep newton's

    c = newton_collision()
    configure_self_collision(c, OmegaConf.create({"self_collision": False,
                                                  "self_collision_stiffness": {"untangle": 1}}))
    assert (c.stiff_vf, c.stiff_ee, c.stiff_ef) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(("terms", "words"), [({"untangel": 0.0}, ["untangel", "untangle", "style3d.yaml"]),
                                              ({"vertex_face": 0.2, "edge_edge": -1.0},
                                               ["edge_edge", ">= 0", "style3d.yaml"])])
def test_bad_terms_are_refused_by_name(terms, words):
    c = newton_collision()
    with pytest.raises(ValueError) as err:
        configure_self_collision(c, OmegaConf.create({"self_collision_stiffness": terms}))
    assert all(w in str(err.value) for w in words)
    assert (c.stiff_vf, c.stiff_ee, c.stiff_ef) == (0.5, 0.1, 1.0)  # nothing half-set
