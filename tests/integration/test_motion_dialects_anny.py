"""Clips written as Mixamo, Bandai Namco, LAFAN1, Blender and Rokoko write them (tests/helpers/mocap.py) drive
the Anny body (body=anny: forearms, hands, legs): every arm and leg joint matched without a table, and each
bone's direction equal to the file's own forward kinematics to 1e-3 degrees (the unit tier checks the
mannequin, which has no forearms or legs)."""

from __future__ import annotations

import pytest
from helpers.mocap import DIALECTS, clip_text, expected_map, worst_direction_error

from pbc.motion.bvh import read_bvh
from pbc.motion.retarget import poses_from_clip


@pytest.mark.parametrize("dialect", sorted(DIALECTS))
def test_each_dialect_drives_annys_limbs(anny_body, tmp_path, dialect):
    skel = anny_body.skeleton
    path = tmp_path / f"{dialect}.bvh"
    path.write_text(clip_text(dialect, n_frames=6, seed=7))
    m = poses_from_clip(path, skel)
    want = expected_map(dialect)
    assert {j: m.mapped.get(j) for j in want} == want  # clavicles, arms, forearms, hands, thighs, shins, feet
    assert set(m.missing) <= {"spine", "neck1"}  # a clip with fewer spine or neck joints than the body
    assert worst_direction_error(skel, m, read_bvh(path)) < 1e-3
