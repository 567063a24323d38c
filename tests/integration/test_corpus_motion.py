"""Every motion clip of the real-world corpus (../shared/corpus/motion: CMU in three releases, Bandai Namco,
MakeHuman poses, exactly as their tools wrote them) is read right onto Anny or refused with its reason: its
unit one of a person's, its height a person's, its retargeted body standing upright with its feet under its
hips. Clips cut from those files make the refusals: a crouch in every frame, a trunk a joint map turns over."""

from __future__ import annotations

import numpy as np
import pytest

from pbc.motion.bvh import BvhError, read_bvh
from pbc.motion.inspect import describe
from pbc.motion.retarget import bvh_to_poses, choose_joint_map, load_joint_map, poses_from_clip

PERSON_UNITS = {"cm", "cmu", "dm"}  # Bandai Namco and CMU's Daz release in cm, CMU's others, MakeHuman


def corpus_clips(corpus):
    return sorted((corpus / "motion").rglob("*.bvh"))


def test_the_corpus_holds_every_release(corpus):
    names = [p.name for p in corpus_clips(corpus)]
    assert len(names) >= 50
    for prefix in ("bandai_", "cmu_01_01", "cmu_02_", "cmu_16_", "makehuman_"):
        assert any(n.startswith(prefix) for n in names), prefix


def test_every_corpus_clip_is_read_right_onto_anny(corpus, anny_body):
    skel = anny_body.skeleton
    wrong = []
    for path in corpus_clips(corpus):
        bvh = read_bvh(path)
        m = bvh_to_poses(bvh, skel, choose_joint_map(bvh), slice(None, None, max(1, bvh.num_frames // 12)))
        problems = []
        if m.units not in PERSON_UNITS:
            problems.append(f"units {m.units}")
        if not 1.2 <= m.height_m <= 2.0:
            problems.append(f"height {m.height_m:.2f} m")
        if m.sanity["problems"] or m.sanity.get("trunk_tilt_deg", 90) > 35 or m.sanity.get("feet_under_hips", 0) < 0.9:
            problems.append(f"sanity {m.sanity}")
        if set(m.missing) - {"spine", "neck1"}:
            problems.append(f"undriven {m.missing}")
        if problems:
            wrong.append(f"{path.name}: {', '.join(problems)}")
    assert not wrong, "\n".join(wrong)


def test_bandai_hips_offset_that_disagrees_with_its_channels(corpus, anny_body):
    # joint_Root lies on the floor and Hips' OFFSET is a world position 4.5 m away from where its channels put
    # it: the body's root frame is the pelvis (Hips), so neither reaches the units, the axes or the height
    path = corpus / "motion" / "bandai_dataset-1_walk_giant_001.bvh"
    bvh = read_bvh(path)
    hips = bvh.joints[bvh.names.index("Hips")]
    assert np.abs(hips.offset[2]) > 400  # the trap is still in the file
    m = poses_from_clip(path, anny_body.skeleton)
    assert m.units == "cm" and 1.2 < m.height_m < 1.8
    assert bvh.names[m.pelvis] == "Hips"
    assert m.mapped["lower_back"] == "Spine"  # the pelvis drives no joint: the lower back is the joint above it
    assert m.rest_frame is not None and "stands in for the clip's rest" in " ".join(m.notes)


def test_amc2bvh_clip_plays_at_the_capture_rate(corpus, anny_body):
    m = poses_from_clip(corpus / "motion" / "cmu" / "cmu_16_02_f0140-0259.bvh", anny_body.skeleton)
    assert m.table.name == "cmu_asf" and not m.missing
    assert m.fps == pytest.approx(120.0, rel=1e-3)
    assert any("converter default" in n for n in m.notes)
    assert m.times[-1] == pytest.approx((len(m.poses) - 1) / 120.0, rel=1e-3)
    # `pbc motion inspect` reports the rate it plays at, the header's in the note beside it
    bvh = read_bvh(corpus / "motion" / "cmu" / "cmu_16_02_f0140-0259.bvh")
    assert "120 frames at 120 fps (0.99 s)" in describe(bvh, m, anny_body.skeleton)[0]


def _cut(src, dst, frames):
    """A copy of clip src keeping only its frame lines `frames` (Frames: fixed)."""
    lines = src.read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.strip().upper().startswith("MOTION"))
    data = [ln for ln in lines[at + 3:] if ln.strip()]
    kept = [data[k] for k in frames]
    dst.write_text("\n".join(lines[:at + 1] + [f"Frames: {len(kept)}", lines[at + 2], *kept]) + "\n")
    return dst


def test_a_crouch_in_every_frame_is_refused_naming_rest_frame(corpus, anny_body, tmp_path):
    # the dash starts crouched (knees bent 126 degrees): its first frames alone hold no rest pose
    clip = _cut(corpus / "motion" / "bandai_dataset-1_dash_active_001.bvh", tmp_path / "crouch.bvh", range(3))
    with pytest.raises(BvhError, match=r"crouch\.bvh.*no frame stands as a rest.*knees bent.*--rest-frame"):
        poses_from_clip(clip, anny_body.skeleton)
    m = poses_from_clip(clip, anny_body.skeleton, rest_frame=0, trust=True)  # the user's own choice goes on
    assert m.rest_frame == 0
    with pytest.raises(ValueError, match="--rest-frame 7: .* has frames 0 to 2"):
        poses_from_clip(clip, anny_body.skeleton, rest_frame=7)


def test_the_whole_dash_takes_a_standing_frame_not_its_crouch(corpus, anny_body):
    m = poses_from_clip(corpus / "motion" / "bandai_dataset-1_dash_active_001.bvh", anny_body.skeleton)
    assert m.rest_frame not in (None, 0)
    assert "frame 0 does not stand as a rest: knees bent" in " ".join(m.notes)


def test_a_trunk_turned_upside_down_is_refused_by_the_sanity_check(corpus, anny_body, tmp_path):
    # a joint map driving the body's spine and neck with the clip's left leg: the trunk hangs below the pelvis
    # (its rest from frame 0, the T-pose: the OFFSETs read with this map lie flat, itself a refusal)
    table = load_joint_map("cmu_mb")
    crossed = tmp_path / "crossed.yaml"
    rows = {k: v for k, v in table.joints.items() if k not in ("neck1", "head")}
    rows.update(lower_back="LeftUpLeg", spine="LeftLeg", spine1="LeftFoot", neck="LeftToeBase")
    crossed.write_text("joints:\n" + "".join(f"  {k}: {v}\n" for k, v in rows.items())
                       + f"bones: [{', '.join(table.bones)}]\n")
    clip = corpus / "motion" / "cmu_01_01.bvh"
    with pytest.raises(BvhError, match=r"cmu_01_01\.bvh: .*does not stand as a person: the trunk leans \d+ degrees "
                                       r"from upright.*--trust-clip"):
        poses_from_clip(clip, anny_body.skeleton, crossed, frames="100:400:20", rest_frame=0)
    m = poses_from_clip(clip, anny_body.skeleton, crossed, frames="100:400:20", rest_frame=0, trust=True)
    assert m.sanity["problems"] and m.sanity["trunk_tilt_deg"] > 60
