"""`pbc garment fit`'s pure helpers: where a fit goes without --out (an outfit's pieces apart), the overrides
that load a garment file, and what a fit stopped by --until says."""

from __future__ import annotations

from pathlib import Path

import pytest

from pbc.jobs.garment_fit import Fit, default_out, empty_splits, garment_overrides


def test_each_piece_of_an_outfit_gets_its_own_fit_dir(tmp_path):
    root = tmp_path / "root"
    suit = Path("assets/suit01.mhclo")
    assert default_out(suit, root) == root / "runs" / "fit" / "suit01"
    top = default_out(suit, root, ["garment.piece=top", "--samples"])
    bottom = default_out(suit, root, ["garment.piece=bottom"])
    assert (top.name, bottom.name) == ("suit01_top", "suit01_bottom")  # were both runs/fit/suit01: refused
    assert default_out(suit, root, ["garment.piece=top", "garment.piece=top_2"]).name == "suit01_top_2"  # last wins
    assert default_out(suit, root, ["garment.piece=all"]).name == "suit01"  # the whole outfit is the garment


def test_a_garment_file_is_loaded_by_its_suffix(tmp_path):
    obj, mh = tmp_path / "shirt.obj", tmp_path / "shirt.mhclo"
    assert garment_overrides(obj, []) == ["garment=obj", f"garment.obj={obj.resolve()}"]
    assert garment_overrides(mh, []) == ["garment=mhclo", f"garment.path={mh.resolve()}", "body=anny"]
    assert garment_overrides(mh, ["body=anny_tpose"])[-1] != "body=anny"  # the user's body is kept
    with pytest.raises(ValueError, match=r"an \.obj or a MakeHuman \.mhclo"):
        garment_overrides(tmp_path / "shirt.fbx", [])


def test_a_dataset_with_an_empty_split_stops_the_fit_naming_the_samples_to_ask_for(tmp_path):
    one = {"splits": {"train": [0], "val": [], "test": []},
           "counts": {"kept": 1, "requested": 6, "discarded": {"area_compressed": 5}}}
    msg = empty_splits(one, tmp_path / "data.log")
    assert msg.startswith("only 1 of 6 drapes were kept (area_compressed 5)") and "val, test empty" in msg
    assert "--samples 19" in msg and str(tmp_path / "data.log") in msg
    three = {"splits": {"train": [0], "val": [1], "test": [2]}, "counts": {"kept": 3, "requested": 6}}
    assert empty_splits(three, tmp_path / "data.log") is None


def test_a_fit_stopped_by_until_lists_only_what_its_steps_made(tmp_path):
    shirt = tmp_path / "shirt.obj"
    shirt.write_text("v 0 0 0\n")
    out = tmp_path / "fit"
    said = Fit(shirt, [], out, until="checks").stopped()
    assert "stopped after checks (--until)" in said and "without --until goes on" in said
    assert str(out / "cage.json") in said and str(out / "inspect") in said
    assert "the dataset" not in said and str(out / "logs") not in said  # no step process ran: no logs
    (out / "data").mkdir(parents=True)
    (out / "data" / "manifest.json").write_text('{"counts": {"kept": 5, "requested": 6}}')
    said = Fit(shirt, [], out, until="data").stopped()
    assert "the dataset: 5 drapes kept of 6" in said and str(out / "logs") in said and "whole-garment" not in said
    with pytest.raises(ValueError, match=r"--until inspect: one of checks, plan, data, models, preview"):
        Fit(shirt, [], out, until="inspect")
