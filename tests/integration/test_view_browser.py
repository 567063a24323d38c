"""`pbc view` in a real browser: the viewer on localhost, opened in headless Chromium (Debian's package, driven
by playwright; playwright's own browsers are never downloaded), draws a non-empty 3D canvas; a slider moved
through the viewer's API changes the garment's vertices and the picture; the toggles, the dataset poses and
the timeline do what they say; the command on a port in use says so and takes the next free one.

    .venv/bin/python tests/integration/test_view_browser.py RUN [--patches SWEEP]   # docs/figures/viewer.png
"""

from __future__ import annotations

import io
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "unit"))
from helpers.evaluate_world import save_run  # noqa: E402
from test_view import tiny_predictor  # noqa: E402

from pbc.jobs.view import clamp_to_limits, pose_to_angles, start_viewer, url, view_meshes  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
# the brief's flags: no GPU (software WebGL), nothing fetched from outside, a fresh profile per launch
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
VIEWPORT = {"width": 1280, "height": 800}
WAIT_S = 60  # generous: software WebGL on 2 shared cores


def chromium() -> str:
    """Debian's Chromium: found, or installed with apt (as .ci/run does) where it is missing."""
    found = shutil.which("chromium") or (CHROMIUM if Path(CHROMIUM).exists() else None)
    if found is None and shutil.which("apt-get") and os.geteuid() == 0:
        subprocess.run("apt-get update -qq && apt-get install -y -qq chromium", shell=True, check=True)
        found = shutil.which("chromium")
    assert found, "Chromium is missing: apt-get install chromium (Debian's package; .ci/run installs it)"
    return found


def wait_for(check, what: str, timeout: float = WAIT_S, poll: float = 0.2):
    """Poll `check()` until it returns something other than None / False; fail naming `what` after `timeout` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = check()
        if got is not None and got is not False:
            return got
        time.sleep(poll)
    raise AssertionError(f"gave up waiting {timeout:.0f} s for {what}")


@contextmanager
def browser_page():
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as profile, sync_playwright() as p:
        # a persistent context on a fresh folder: playwright's form of --user-data-dir
        context = p.chromium.launch_persistent_context(profile, executable_path=chromium(), headless=True,
                                                       args=CHROMIUM_ARGS, viewport=VIEWPORT)
        try:
            yield context.pages[0] if context.pages else context.new_page()
        finally:
            context.close()


def canvas_pixels(page) -> np.ndarray:
    """RGB (H, W, 3) of the page's 3D canvas (the largest canvas), as drawn now."""
    from PIL import Image

    box = max((c.bounding_box() for c in page.locator("canvas").all()), key=lambda b: b["width"] * b["height"])
    png = page.screenshot(clip=box)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def garment_and_body_pixels(rgb: np.ndarray) -> tuple[int, int]:
    """Pixels of the (blue) garment and of the (skin) body: the scene's own colours, shaded."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return int(((b > r + 40) & (b > g + 10)).sum()), int(((r > b + 30) & (r > 90)).sum())


def open_viewer(page, viewer) -> None:
    page.goto(url(viewer))
    page.wait_for_selector("canvas", timeout=WAIT_S * 1000)
    wait_for(lambda: len(viewer.server.get_clients()) > 0, "the page to connect")
    close = page.locator(".mantine-Notification-root button")  # "software WebGL" notice over the scene
    if close.count():
        close.first.click()


def test_the_viewer_draws_in_chromium_and_a_slider_moves_the_garment(tmp_path):
    predictor = tiny_predictor(tmp_path / "fake")
    viewer = start_viewer(predictor, "127.0.0.1", 0)
    try:
        with browser_page() as page:
            open_viewer(page, viewer)
            # the first test pose is shown with its simulation: a garment and a body on the canvas
            first = wait_for(lambda: (lambda px: px if min(garment_and_body_pixels(px)) > 200 else None)(
                canvas_pixels(page)), "the canvas to show the garment and the body")
            garment_px, body_px = garment_and_body_pixels(first)
            assert garment_px > 200 and body_px > 200
            assert len(np.unique(first.reshape(-1, 3), axis=0)) > 50  # shaded 3D, not a flat fill
            before = viewer.garment_vertices()
            # bend the lower back forward through the viewer's API, as a user's drag would (the stand-in
            # body is skinned to the root and the lower back only)
            viewer.sliders[("lower_back", "x")].value = 40.0
            moved = wait_for(lambda: (lambda v: v if np.abs(v - before).max() > 0.01 else None)(
                viewer.garment_vertices()), "the garment's vertices to follow the slider")
            expect = predictor(viewer.pose, model="whole").numpy()
            assert np.allclose(moved, expect, atol=1e-5)
            assert viewer.pose_dropdown.value == "(sliders)"  # the moved pose is no longer the simulated one
            after = wait_for(lambda: (lambda px: px if np.abs(px - first).sum(-1).astype(bool).sum() > 500
                                      else None)(canvas_pixels(page)), "the picture to change")
            assert np.abs(after - first).max() > 0
            page.screenshot(path=str(tmp_path / "viewer.png"))
            assert (tmp_path / "viewer.png").stat().st_size > 10_000
    finally:
        viewer.close()
        viewer.server.stop()


def test_toggles_dataset_poses_and_the_timeline(tmp_path):
    predictor = tiny_predictor(tmp_path / "fake", patches=True)
    ds = predictor.dataset
    sequence = torch.from_numpy(np.array(ds.poses[:5]))
    viewer = start_viewer(predictor, "127.0.0.1", 0, sequence=sequence, log=lambda *_: None)
    try:
        # a sequence opens on its own first frame, not on a pose of the model's data
        assert torch.equal(viewer.pose, sequence[0]) and viewer.pose_dropdown.value == "(sliders)"
        assert int(viewer.timeline.value) == 0 and not viewer.truth_handle.visible
        # the first test pose: the simulated garment beside, the prediction coloured by its error
        viewer.pose_dropdown.value = "test 00008"
        wait_for(lambda: viewer.truth_handle.visible, "the test pose's simulation to show")
        assert viewer.truth_handle.visible and viewer.error_handle is not None
        assert np.allclose(viewer.truth_handle.vertices, ds.verts[8])
        err = np.linalg.norm(viewer.meshes.garment - np.asarray(ds.verts[8]), axis=1) * 100
        assert f"mean {err.mean():.2f} cm" in viewer.error_text.value
        assert np.allclose(viewer.angles(), clamp_to_limits(pose_to_angles(ds.poses[8]), viewer.limits), atol=0.3)
        # whole -> stitched patches, then each seam method: the drawn garment is the predictor's answer
        pose = viewer.pose
        viewer.model.value = "stitched patches"
        for method in ("average", "inpaint", "hierarchy", "pca"):
            viewer.method.value = method
            want = predictor(pose, model="patches", method=method).numpy()
            assert np.allclose(viewer.garment_vertices(), want, atol=1e-5), method
        assert not np.allclose(predictor(pose, model="whole").numpy(), want, atol=1e-4)
        # the timeline: frame k predicts the sequence's pose k; play advances it
        viewer.timeline.value = 3
        assert torch.equal(viewer.pose, sequence[3]) and viewer.pose_dropdown.value == "(sliders)"
        assert not viewer.truth_handle.visible and viewer.error_handle is None
        assert np.allclose(viewer.garment_vertices(), view_meshes(predictor, sequence[3], "patches", "pca").garment,
                           atol=1e-5)
        viewer.play.value = True
        wait_for(lambda: int(viewer.timeline.value) != 3, "play to advance the timeline")
        viewer.play.value = False
    finally:
        viewer.close()
        viewer.server.stop()


def test_the_command_on_a_port_in_use_says_so_and_takes_the_next_free_one(tiny_dataset, tmp_path):
    import json
    import socket

    manifest = json.loads((Path(tiny_dataset) / "manifest.json").read_text())
    run = save_run(tmp_path / "whole", Path(tiny_dataset), "whole", None, garment_hash=manifest["garment_hash"])
    with socket.socket() as busy:
        busy.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = busy.getsockname()[1]
        proc = subprocess.Popen([sys.executable, "-m", "pbc", "view", str(run), "--port", str(taken)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
        try:
            lines = []
            for line in proc.stdout:
                lines.append(line)
                if line.startswith("pbc view: http"):
                    break
            text = "".join(lines)
            assert f"port {taken} on 127.0.0.1 is in use; the viewer takes the next free one" in text, text
            port = int(lines[-1].split(":")[3].split("/")[0])
            assert port != taken
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
                assert r.status == 200 and b"<html" in r.read().lower()
            proc.send_signal(signal.SIGINT)
            out = proc.communicate(timeout=180)[0]  # the server stops in seconds; a loaded CI machine took >60
            assert proc.returncode == 0 and "pbc view: stopped" in out
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def write_figure(whole_run: str, patch_runs: list[str] | None, out: Path) -> Path:
    """The README's screenshot: the viewer on `whole_run` in headless Chromium, the first test pose."""
    from pbc.inference.predictor import ClothPredictor, stitch_config

    predictor = ClothPredictor.from_runs(whole_run, patch_runs, stitch_config("pca") if patch_runs else None)
    viewer = start_viewer(predictor, "127.0.0.1", 0)
    try:
        with browser_page() as page:
            open_viewer(page, viewer)
            wait_for(lambda: min(garment_and_body_pixels(canvas_pixels(page))) > 500, "the scene to draw")
            time.sleep(2)  # the error-coloured mesh arrives as a GLB, decoded after the first frames
            page.screenshot(path=str(out))
    finally:
        viewer.close()
        viewer.server.stop()
    return out


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="docs/figures/viewer.png from trained runs")
    ap.add_argument("whole_run")
    ap.add_argument("--patches", nargs="+")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "viewer.png"))
    a = ap.parse_args()
    print(write_figure(a.whole_run, a.patches, Path(a.out)))


def test_ctrl_c_ends_the_process_even_when_a_thread_holds_its_exit():
    """stop_within: a non-daemon thread that never ends would keep a viewer alive after Ctrl-C; the watchdog
    ends the process within the grace, status 0, with every thread's stack on stderr to say what held it."""
    script = (
        "import os, signal, threading, time\n"
        "from pbc.jobs.view import stop_within\n"
        "threading.Thread(target=lambda: time.sleep(3600), name='holds-the-exit').start()\n"
        "stop_within(1.0)\n"
        "print('ready', flush=True)\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(60)\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted', flush=True)\n"
    )
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["ready", "interrupted", "pbc view: stopped (forced 1 s after Ctrl-C)"]
    assert "still running 1 s after Ctrl-C" in proc.stderr and "holds-the-exit" not in proc.stdout
    assert "Thread 0x" in proc.stderr  # faulthandler's per-thread stacks
    assert time.monotonic() - t0 < 60
