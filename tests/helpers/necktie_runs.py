"""Helpers shared by tests/unit/test_necktie.py and tests/integration/test_necktie_jobs.py."""

from __future__ import annotations

# judged where a drape first stops (the fold rule, sim.fold_frames, has its own tests; here it would only run a
# discarded drape 40 frames more)
TIE_DATA = ["+experiment=necktie", "garment.grid_spacing=0.015", "data.num_samples=4", "data.workers=1",
            "body.mesh.voxel_size=0.03", "sim.fold_frames=0"]
