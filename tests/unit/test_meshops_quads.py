"""Triangle pairs read back into their quads (pbc.geometry.meshops.paired_quads): Anny cuts a square quad along
either diagonal by the last bit of one CPU's rounding, and two such meshes are the same quads."""

from __future__ import annotations

import numpy as np
import pytest

from pbc.geometry.meshops import paired_quads


def cut(quads: np.ndarray, along_ac: np.ndarray) -> np.ndarray:
    a, b, c, d = np.asarray(quads).T
    first = np.where(along_ac[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    second = np.where(along_ac[:, None], np.stack([c, d, a], 1), np.stack([d, b, c], 1))
    return np.stack([first, second], 1).reshape(-1, 3)


def test_quads_cut_along_either_diagonal_read_back_alike():
    rng = np.random.default_rng(0)
    quads = np.array([rng.permutation(40)[:4] for _ in range(30)])
    one, other = cut(quads, rng.random(30) < 0.5), cut(quads, rng.random(30) < 0.5)
    assert not np.array_equal(one, other)
    assert np.array_equal(paired_quads(one), quads)
    assert np.array_equal(paired_quads(other), quads)


def test_triangles_that_are_not_quads_are_refused():
    with pytest.raises(ValueError, match="not pairs"):
        paired_quads([[0, 1, 2]])
    with pytest.raises(ValueError, match="triangles 2 and the next are not one quad"):
        paired_quads(np.r_[cut([[0, 1, 2, 3]], np.array([True])), [[4, 5, 6], [7, 8, 9]]])
