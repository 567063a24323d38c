"""Bad input to the Anny body is one clear error before Anny builds anything (no asset cache needed here),
and `pbc body show|export` on the mannequin. The Anny body itself: tests/integration/test_anny.py."""

from __future__ import annotations

import sys

import pytest
import torch
import trimesh
from omegaconf import OmegaConf

from pbc.cli import body as body_cli
from pbc.core.config import load_config
from pbc.geometry.body import anny as anny_body
from pbc.geometry.body.anny import check_phenotype, check_topology, joint_table, merge_weights

RANGES = {"age": [0.5, 1.0], "height": [0.1, 0.9]}


def test_unknown_phenotype_key_lists_keys_and_ranges():
    with pytest.raises(ValueError, match=r"unknown keys \['agee'\].*age in \[0.5, 1\], height in \[0.1, 0.9\]"):
        check_phenotype({"agee": 0.7}, RANGES)


@pytest.mark.parametrize("value", [0.2, 1.5, "tall", float("nan")])
def test_phenotype_out_of_range(value):
    with pytest.raises(ValueError, match=r"body.phenotype.age=.* is out of range \[0.5, 1\]"):
        check_phenotype({"age": value}, RANGES)


def test_phenotype_in_range_is_kept():
    assert check_phenotype({"age": 0.5, "height": "0.9"}, RANGES) == {"age": 0.5, "height": 0.9}


@pytest.mark.parametrize("topology", ["smplx", "smpl"])
def test_licensed_topology_refused(topology):
    with pytest.raises(ValueError, match="licensed .*never fetches"):
        check_topology(topology, ["smpl", "smplx"])
    check_topology("anny", ["smpl", "smplx"])  # the default passes


def _rig_cfg(**joint):
    return OmegaConf.create({"rig": "toy", "root_bones": ["root"],
                             "joints": [{"name": "arm", "parent": "root", "bones": ["upper", "lower"], **joint}]})


def test_joint_table_merges_unlisted_bones_into_their_ancestor():
    labels, parents = ["root", "upper", "lower", "finger", "toe"], [-1, 0, 1, 2, 0]
    column, first = joint_table(_rig_cfg(), labels, parents)
    assert column == [0, 1, 1, 1, 0] and first == [1]
    w = merge_weights(torch.tensor([[0.25, 0.75], [0.5, 0.5]]), torch.tensor([[3, 4], [0, 1]]), column, 2)
    assert torch.equal(w, torch.tensor([[0.75, 0.25], [0.5, 0.5]]))


def test_joint_table_bone_missing_from_rig_names_it_and_the_rig():
    with pytest.raises(ValueError, match=r"bone 'lower', which rig 'toy' lacks; its bones are \['root', 'upper'\]"):
        joint_table(_rig_cfg(), ["root", "upper"], [-1, 0])


def test_joint_table_bones_of_one_joint_must_hang_together():
    with pytest.raises(ValueError, match="must be a child of one of the joint's bones"):
        joint_table(_rig_cfg(bones=["upper", "other"]), ["root", "upper", "other"], [-1, 0, 0])


def test_anny_missing_names_install_and_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setitem(sys.modules, "anny", None)  # import anny now raises ImportError
    anny_body.load_anny_model.cache_clear()
    cache = tmp_path / "cache" / "anny"
    with pytest.raises(ValueError, match=rf"pip install anny==.*asset cache will be built in {cache}"):
        anny_body.load_anny_model("anny", "anny")


def test_unwritable_cache_folder_is_one_error(monkeypatch, tmp_path):
    (tmp_path / "file").write_text("not a folder")
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path / "file" / "below"))
    anny_body.load_anny_model.cache_clear()
    with pytest.raises(PermissionError, match="cache folder .* is not writable: set PBC_CACHE_DIR"):
        anny_body.load_anny_model("anny", "anny")


@pytest.mark.parametrize("override, message", [
    ("body.topology=smplx", "licensed"),
    ("+body.phenotype.agee=0.5", "unknown keys ['agee']"),
    ("body.phenotype.height=1.0", "body.phenotype.height=1.0 is out of range [0.1, 0.9]"),
])
def test_cli_bad_anny_input_is_one_line_exit_2(override, message, capsys, tmp_path):
    out = tmp_path / "body.obj"
    with pytest.raises(SystemExit) as e:
        body_cli.main(["export", "body=anny", override, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and "\n" not in err and message in err and err.startswith("pbc body: error:")
    assert not out.exists()


def test_body_show_and_export_mannequin(body, body_cfg, capsys, tmp_path):
    text = body_cli.show(body_cfg, body)
    assert "l_arm" in text and "x [-45, 120]" in text and "chest" in text and "height" in text
    out = tmp_path / "m.obj"
    with pytest.raises(SystemExit) as e:
        body_cli.main(["export", "body.mesh.voxel_size=0.03", "--out", str(out)])
    assert e.value.code == 0
    mesh = trimesh.load(out, process=False)
    assert len(mesh.faces) == len(body.faces) and mesh.is_watertight
    head = load_config([]).body.primitives[6]  # the head ellipsoid: its top is the body's top
    assert abs(mesh.vertices[:, 1].max() - (head.centre[1] + head.radii[1])) < 0.02


def test_cache_trim_keeps_only_the_built_models(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("PBC_CACHE_DIR", str(tmp_path))
    v = tmp_path / "anny" / "v14"
    v.mkdir(parents=True)
    (v / "build_compact_model_data_abc.safetensors").write_bytes(b"m" * 10)
    (v / "build_model_data_def.safetensors").write_bytes(b"i" * 1000)
    (v / "load_data_123.safetensors").write_bytes(b"i" * 500)
    with pytest.raises(SystemExit) as e:
        body_cli.main(["cache", "--trim"])
    assert e.value.code == 0 and "removed 2 files" in capsys.readouterr().out
    assert [p.name for p in v.iterdir()] == ["build_compact_model_data_abc.safetensors"]
