"""Helpers shared by tests/unit/test_autocage.py and tests/integration/test_autocage_jobs.py."""

from __future__ import annotations

from pbc.geometry.cage.auto import _components, _edges

IMAGE = (512, 160, 16)


def _check_patches_connected(garment, cage):
    edges = _edges(garment)
    for p in cage.patches:
        assert len(_components(p.vertices, edges, garment.num_vertices)) == 1, p.name
