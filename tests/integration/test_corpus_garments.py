"""Every garment of the real-world corpus (../shared/corpus/garments: MakeHuman outfits piece by piece, DiffAvatar's
meshes, a hospital gown, exactly as their tools wrote them) is placed right on Anny or refused in one line naming
the problem and a fix: the placement part of bench/corpus_garments.py, which also drapes and fits them.

Right: an OBJ placed in the unit the corpus's README states for it (any unit where the README does not know it),
its cloth round the torso and near the body; a MakeHuman piece fitted by its own binding, round the body too.
Refused: one line naming the file. Never: a garment made for no body (the gown, laid flat, Z up) placed on one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from pbc.core.config import load_config
from pbc.geometry.garment.mhclo import mhclo_mesh
from pbc.geometry.garment.outfit import name_pieces
from pbc.geometry.garment.placement import _landmarks, _sdf, placed_mesh, torso_cover_deg

# the corpus README's unit for each OBJ (None: unknown there), or "not on a body" for one made for no body, whose
# refusal says it does not go round the torso (the file bench/corpus_garments.py reads too)
STATED = yaml.safe_load((Path(__file__).resolve().parents[1] / "data" / "corpus_garments.yaml").read_text())
MADE_FOR_NO_BODY = {k: "round the body's torso" for k, v in STATED.items() if v == "not on a body"}
NEAR = 0.08  # m: the median distance of placed cloth to the rest body (the placement refuses past 0.15)


def corpus_objs(corpus):
    return sorted(p for p in (corpus / "garments").rglob("*.obj") if not p.with_suffix(".mhclo").is_file())


def test_the_corpus_garments_are_all_known_here(corpus):
    names = {str(p.relative_to(corpus / "garments")) for p in corpus_objs(corpus)}
    assert names == set(STATED), names
    assert len(sorted((corpus / "garments").rglob("*.mhclo"))) >= 7


def _cfg(overrides):
    return load_config(["body=anny", *overrides]).garment


def test_every_corpus_obj_is_placed_right_or_refused_in_one_line(corpus, anny_body):
    lm = _landmarks(anny_body)
    limit = float(_cfg(["garment=obj", "garment.obj=x"]).placement.min_torso_cover_deg)
    wrong = []
    for path in corpus_objs(corpus):
        name = str(path.relative_to(corpus / "garments"))
        gcfg = _cfg(["garment=obj", f"garment.obj={path}"])
        try:
            mesh, placement = placed_mesh(path, gcfg, anny_body)
        except ValueError as err:
            text = str(err)
            assert "\n" not in text and str(path) in text, (name, text)
            if name in MADE_FOR_NO_BODY:
                assert MADE_FOR_NO_BODY[name] in text, (name, text)
            continue
        if name in MADE_FOR_NO_BODY:
            wrong.append(f"{name}: placed ({placement.lines()[0]}), but it was made for no body")
            continue
        if STATED[name] is not None and placement.unit_name != STATED[name]:
            wrong.append(f"{name}: unit {placement.unit_name}, the corpus says {STATED[name]}")
        cover = torso_cover_deg(mesh.vertices, mesh.faces, anny_body, lm)
        median = float(np.median(np.abs(_sdf(anny_body, mesh.vertices))))
        if not (cover >= limit and median < NEAR):
            wrong.append(f"{name}: {cover:.0f} degrees round the torso, median {median:.3f} m from the body")
    assert not wrong, wrong


@pytest.mark.parametrize("outfit", ["female_casualsuit01", "male_casualsuit02", "male_worksuit01"])
def test_makehuman_pieces_are_fitted_round_the_body(corpus, anny_body, outfit):
    path = corpus / "garments" / "makehuman" / outfit / f"{outfit}.mhclo"
    lm = _landmarks(anny_body)
    whole, _ = mhclo_mesh(_cfg(["garment=mhclo", f"garment.path={path}", "garment.piece=all"]), anny_body)
    _, names = name_pieces(whole.vertices, whole.faces)
    places = sorted({n.split("_")[0] for n in names})
    assert "top" in places or "bottom" in places, names
    for place in places:
        if place not in ("top", "bottom"):
            continue
        mesh, _ = mhclo_mesh(_cfg(["garment=mhclo", f"garment.path={path}", f"garment.piece={place}"]), anny_body)
        median = float(np.median(np.abs(_sdf(anny_body, mesh.vertices))))
        assert median < NEAR, (outfit, place, median)
        if place == "top":
            assert torso_cover_deg(mesh.vertices, mesh.faces, anny_body, lm) >= 300, (outfit, place)


def test_a_makehuman_outfit_with_a_folded_uv_island_imports_unwrapped_as_its_refusal_says(corpus, anny_body):
    from pbc.geometry.garment.mhclo import mhclo_garment

    path = corpus / "garments" / "makehuman" / "male_worksuit01" / "male_worksuit01.mhclo"
    node = ["garment=mhclo", f"garment.path={path}", "garment.piece=all"]
    with pytest.raises(ValueError, match=r"is folded over .* garment.uvs=unwrap") as err:
        mhclo_garment(_cfg(node), anny_body)
    assert "\n" not in str(err.value)
    garment, names, _, _ = mhclo_garment(_cfg([*node, "garment.uvs=unwrap"]), anny_body)
    assert names and all(n.startswith(("front", "back")) for n in names)
    assert set(garment.face_side.unique().tolist()) == {0, 1}
