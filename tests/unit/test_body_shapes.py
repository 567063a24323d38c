"""Shape as data (`data.body_shape`, pbc.data.shapes): a dataset of several people. On a synthetic two-person
dataset (the evaluation tests' stand-in world, person k = the body scaled), each sample's targets equal the
single-body targets of its person's Body (the naive reference), reconstruction round-trips to its vertices,
the DataModule and its target cache serve the person, and the single-body path is unchanged. The config's
checks (ranges, bands, the mannequin) on composed configs; the Anny drapes are in
tests/integration/test_body_shapes_jobs.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from helpers.evaluate_world import IMAGE, fake_dataset

from pbc.core.config import load_config, load_garment_config
from pbc.data.datamodule import ClothDataModule
from pbc.data.generate import _cheap_fingerprint
from pbc.data.shapes import BodyShapes, load_shapes, person_body, sample_phenotypes, save_shapes
from pbc.geometry.garment.tshirt import make_tshirt
from pbc.pixels.reconstruct import Skinner
from pbc.pixels.target import make_target

SCALES = (0.9, 1.15)  # person k: the base body's rest vertices and joint heads scaled by SCALES[k]


def people_dataset(d):
    """The stand-in dataset with two people: sample i draped on person i % 2 (its anchors on that person plus
    the stand-in's smooth displacement)."""
    base = fake_dataset(d)
    s = torch.tensor(SCALES)[:, None, None]
    shapes = BodyShapes(("height",), np.array([[0.3], [0.7]]), base.body.vertices[None] * s,
                        base.body.skeleton.rest_heads[None] * s)
    person = np.arange(len(base)) % 2
    poses = torch.from_numpy(np.array(base.poses))
    skin = Skinner(base.body, base.garment, base.embedding)
    shift = torch.from_numpy(np.array(base.verts)) - skin(poses)[0]
    verts = torch.stack([Skinner(person_body(base.body, shapes, int(k)), base.garment, base.embedding)(
        poses[i:i + 1])[0][0] for i, k in enumerate(person)]) + shift
    return dataclasses.replace(base, verts=verts.numpy(), shapes=shapes, person=person)


def single(ds, k):
    """Person k's dataset as a single-body one: the naive reference."""
    return dataclasses.replace(ds, body=ds.person_body(k), shapes=None, person=None)


def batch_of(ds, rows, person=True):
    b = {"pose": torch.from_numpy(np.array(ds.poses[rows])).reshape(len(rows), -1),
         "verts": torch.from_numpy(np.array(ds.verts[rows]))}
    return dict(b, **ds.person_kw(rows)) if person else b


def test_each_sample_is_skinned_on_its_person(tmp_path):
    ds = people_dataset(tmp_path)
    rows = np.arange(len(ds))
    out = make_target(ds, IMAGE, "whole").render(batch_of(ds, rows))
    for k in range(2):
        mine = rows[ds.person == k]
        ref = make_target(single(ds, k), IMAGE, "whole").render(batch_of(ds, mine, person=False))
        for key in ("anchors", "frames", "offsets", "image"):
            assert torch.allclose(out[key][mine], ref[key], atol=1e-6), (k, key)
    # the base body's targets are another thing (the test can fail): centimetres apart
    base = make_target(single(ds, None), IMAGE, "whole").render(batch_of(ds, rows, person=False))
    assert (base["anchors"] - out["anchors"]).norm(dim=-1).max() > 0.02


def test_reconstruction_round_trips_to_the_samples_vertices(tmp_path):
    ds = people_dataset(tmp_path)
    rows = np.arange(len(ds))
    batch = batch_of(ds, rows)
    fc = make_target(ds, IMAGE, "fc")
    out = fc.render(batch)
    assert torch.allclose(fc.positions(out["offsets"], out), batch["verts"], atol=1e-5)
    # through the cloth image: the same positions as the person's own single-body target gives
    whole = make_target(ds, IMAGE, "whole")
    out = whole.render(batch)
    pos = whole.positions(out["image"], out)
    for k in range(2):
        mine = rows[ds.person == k]
        ref_t = make_target(single(ds, k), IMAGE, "whole")
        ref = ref_t.render(batch_of(ds, mine, person=False))
        assert torch.allclose(pos[mine], ref_t.positions(ref["image"], ref), atol=1e-6)
    assert (pos - batch["verts"]).norm(dim=-1).mean() < 2e-3  # the image's representation floor, m


def test_the_datamodule_and_its_cache_serve_the_person(tmp_path):
    ds = people_dataset(tmp_path)
    dm = ClothDataModule(str(tmp_path), IMAGE, target="whole", batch_size=4)
    dm.data, dm.splits = ds, {s: ds.split(s) for s in ("train", "val", "test")}
    dm.target = make_target(ds, IMAGE, "whole")
    batch = next(iter(dm.loader("train")))
    assert torch.equal(batch["person"], torch.from_numpy(ds.person[batch["index"].numpy()]))
    cached = dm.on_after_batch_transfer(dict(batch), 0)
    assert dm.target.cache is not None and dm.target.cache.covers(batch)
    fresh = dm.target.render(dict(batch))
    for key in ("anchors", "offsets", "image"):
        assert torch.allclose(cached[key], fresh[key], atol=1e-6), key
    k = int(batch["person"][0])
    ref = make_target(single(ds, k), IMAGE, "whole").render(
        {"pose": batch["pose"][:1], "verts": batch["verts"][:1]})
    assert torch.allclose(cached["offsets"][:1], ref["offsets"], atol=1e-6)


def test_the_single_body_path_is_unchanged(tmp_path):
    ds = people_dataset(tmp_path)
    pose = torch.from_numpy(np.array(ds.poses[:3]))
    one = Skinner(ds.body, ds.garment, ds.embedding)
    many = Skinner(ds.body, ds.garment, ds.embedding, shapes=ds.shapes)
    for a, b in zip(one(pose), many(pose), strict=True):  # no person: the base body, bit for bit
        assert torch.equal(a, b)
    assert one.num_people == 0 and many.num_people == 2
    with pytest.raises(ValueError, match="made without data.body_shape"):
        one(pose, person=torch.zeros(3, dtype=torch.long))
    with pytest.raises(ValueError, match=r"outside 0\.\.1"):
        many(pose, person=torch.tensor([0, 1, 2]))
    plain = single(ds, None)
    assert plain.person_kw([0, 1]) == {} and "person" not in batch_of(plain, [0, 1])
    with pytest.raises(ValueError, match="one body"):
        plain.person_body(0)


def test_shapes_file_round_trips_and_person_bodies(tmp_path):
    ds = people_dataset(tmp_path)
    save_shapes(ds.shapes, tmp_path / "shapes.npz")
    back = load_shapes(tmp_path / "shapes.npz")
    assert back.keys == ("height",) and np.array_equal(back.values, ds.shapes.values)
    assert torch.equal(back.vertices, ds.shapes.vertices) and torch.equal(back.heads, ds.shapes.heads)
    b1 = ds.person_body(1)
    assert torch.allclose(b1.vertices, ds.body.vertices * SCALES[1])
    assert torch.equal(b1.faces, ds.body.faces) and torch.equal(b1.weights, ds.body.weights)
    assert ds.person_body(None) is ds.body and back.phenotype(1) == {"height": 0.7}
    with pytest.raises(ValueError, match="person 2 is outside"):
        ds.person_body(2)


ANNY = ["body=anny_tpose", "garment=tshirt_coarse", "data=tshirt_small"]


def test_people_are_drawn_from_the_seed_in_the_ranges():
    cfg = load_config([*ANNY, "data.body_shape={height:[0.3,0.7],weight:[0.2,0.8]}", "data.body_shapes=5"])
    keys, values = sample_phenotypes(cfg)
    assert values.shape == (5, len(keys)) and set(keys) >= {"height", "weight", "age", "gender"}
    h, w, a = (values[:, keys.index(k)] for k in ("height", "weight", "age"))
    assert ((0.3 <= h) & (h <= 0.7)).all() and ((0.2 <= w) & (w <= 0.8)).all() and np.ptp(h) > 0.05
    assert (a == float(cfg.body.phenotype.age)).all()  # a key without a range keeps the body's value
    again = sample_phenotypes(load_config([*ANNY, "data.body_shape={height:[0.3,0.7],weight:[0.2,0.8]}",
                                           "data.body_shapes=5"]))[1]
    other = sample_phenotypes(load_config([*ANNY, "data.body_shape={height:[0.3,0.7],weight:[0.2,0.8]}",
                                           "data.body_shapes=5", "data.seed=1"]))[1]
    assert np.array_equal(values, again) and not np.array_equal(values, other)
    # the fingerprint names the people; a single-body config's fingerprint has no such key
    garment = make_tshirt(load_garment_config("conf/garment/tshirt_coarse.yaml"))[0]
    assert _cheap_fingerprint(cfg, garment)["body_shapes"]["values"] == values.tolist()
    assert "body_shapes" not in _cheap_fingerprint(load_config(ANNY), garment)


@pytest.mark.parametrize(("overrides", "message"), [
    (["data.body_shape={height:[0.3,0.7]}"], r"needs a body with phenotypes \(body=anny"),
    ([*ANNY, "data.body_shape={height:[0.0,0.7],size:[0,1]}"],
     r"height: \[0.0, 0.7\] leaves its band \[0.1, 0.9\]; unknown key 'size'; the body's phenotype keys"),
    ([*ANNY, "data.body_shape={weight:[0.8,0.2]}"], r"is not a range \[lo, hi\] with lo <= hi"),
    ([*ANNY, "data.body_shape={weight:[0.2,0.8]}", "data.body_shapes=0"], "data.body_shapes must be"),
])
def test_a_bad_shape_config_is_one_clear_error(overrides, message):
    with pytest.raises(ValueError, match=message):
        sample_phenotypes(load_config(["data=tshirt_small", *overrides]))
