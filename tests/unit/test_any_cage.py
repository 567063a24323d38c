"""The stitched path on a cage that is not the shirt's 28 patches: the tube top's automatic cage.

Fast: a stitcher built for the tube top's cage (import + automatic cage + operators, no drape) given the
exact crops of a known offset field returns that field. Slow: the tube top draped (the session's
`foreign` dataset), its whole model and its stacked all-patches job trained with `trainer=smoke`, then
`ClothPredictor.from_runs` under every seam method and `pbc.evaluate` on them.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.any_cage import SHIRT_PATCHES, _smooth_field, _stitch_cfg, _trained
from helpers.tube_top import CHARTS, tube_top_obj

ROOT = Path(__file__).resolve().parents[2]
# what the smoke jobs train at: small images keep the two jobs to seconds on the 2-core CPU


def test_a_stitcher_for_a_cage_of_another_patch_count_returns_the_field_of_exact_crops(tmp_path):
    """Crops rendered from a known offset field, assembled and sampled by a stitcher built for the tube
    top's automatic cage (not 28 patches): `average` gives the field back at every vertex, and crops of
    ones give ones, i.e. the blend weights sum to 1 at every vertex (a vertex no crop covers would read 0)."""
    from pbc.geometry.cage.auto import auto_cage
    from pbc.geometry.garment.obj_import import import_garment
    from pbc.pixels.operators import ImageOperators
    from pbc.stitch.seams import build_stitcher

    path = tmp_path / "top.obj"
    path.write_text(tube_top_obj())
    garment, names, chart = import_garment(path, charts=CHARTS, uv_unit="cm")
    res, crop, margin, pad = 512, 160, 16, 16
    cage = auto_cage(garment, res, crop, margin, chart_names=names, face_chart=chart)
    P = len(cage.patches)
    assert 1 < P != SHIRT_PATCHES
    ops = ImageOperators.for_garment(garment, res, pad)
    crops_ops = [ops.crop(p, crop, margin) for p in cage.patches]
    st = build_stitcher(ops, crops_ops, garment, cage, _stitch_cfg("average"))
    assert (st.vertex_patch >= 0).all()  # every vertex belongs to a patch
    field = _smooth_field(garment.vertices.float())
    crops = torch.stack([c.render(field) for c in crops_ops], 1)  # (B, P, 3, h, w)
    assert crops.shape[:2] == (2, P)
    out = st(crops, "average")
    assert out.shape == field.shape
    assert torch.allclose(out, field, atol=1e-5), float((out - field).abs().max())
    ones = st(torch.ones_like(crops), "average")
    assert torch.allclose(ones, torch.ones_like(ones), atol=1e-5)


@pytest.fixture(scope="module")
def trained(foreign):
    """The tube top's whole model and its stacked all-patches job (P single-patch runs exported under it)."""
    root, overrides, data_dir = foreign
    return root, _trained(root, overrides, data_dir, "whole"), _trained(root, overrides, data_dir, "patches")


