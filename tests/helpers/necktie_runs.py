"""Helpers shared by tests/unit/test_necktie.py and tests/integration/test_necktie_jobs.py."""

from __future__ import annotations

TIE_DATA = ["+experiment=necktie", "garment.grid_spacing=0.015", "data.num_samples=4", "data.workers=1",
            "body.mesh.voxel_size=0.03"]
