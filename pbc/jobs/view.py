"""The browser viewer's library: a `ClothPredictor` shown live in a viser scene (the command is `pbc view`,
pbc/cli/view.py). Nothing here starts a server at import.

The scene: the posed body and the predicted garment; a slider per joint axis (Euler angles x, y, z in
degrees, the body's own limits, the convention of `pbc.sim.poses.euler_xzy_to_matrix`); a dropdown of the
dataset's poses, which also shows the simulated garment beside the prediction and colours the prediction by
its per-vertex error; the model (whole / stitched patches) and the seam method as toggles; play/pause and a
timeline over a loaded sequence (.npy of rotations, or a .bvh clip through pbc.motion).

`view_meshes(predictor, pose, ...)` is the update function (pose -> the meshes drawn); `ClothViewer` holds
the scene and pushes them. GUI callbacks never queue up work: a change while an update runs marks the state
dirty and the running update goes round once more with the newest pose (`ClothViewer.schedule`), so a
dragged slider shows its latest value rather than replaying every intermediate one.
"""

from __future__ import annotations

import contextlib
import faulthandler
import ipaddress
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import torch
import trimesh
import viser
from omegaconf import OmegaConf
from scipy.spatial.transform import Rotation
from torch import Tensor

from pbc.core.paths import CONF_DIR
from pbc.geometry.body.base import pose_body
from pbc.inference.poses import read_motion, read_poses
from pbc.inference.predictor import ClothPredictor, fit_training_pca, stitch_config
from pbc.motion.retarget import Motion
from pbc.sim.poses import euler_xzy_to_matrix
from pbc.stitch.seams import METHODS, NEEDS_WHOLE

AXES = ("x", "y", "z")
NO_POSE = "(sliders)"  # the dropdown entry of "no dataset pose": the sliders' own pose
MODEL_LABELS = {"whole": "whole", "patches": "stitched patches"}
MAX_PORT = 65535


def view_config():
    """conf/view.yaml: the viewer's settings (one source for the command, the library and the tests)."""
    return OmegaConf.load(CONF_DIR / "view.yaml")


# ----------------------------------------------------------------------------- poses <-> slider angles


def angles_to_pose(angles_deg) -> Tensor:
    """Slider angles (J, 3) in degrees, per axis (x, y, z) -> rotations (J, 3, 3) float32."""
    return euler_xzy_to_matrix(torch.as_tensor(np.asarray(angles_deg, dtype=np.float64))).float()


def pose_to_angles(pose) -> np.ndarray:
    """Rotations (J, 3, 3) -> angles (J, 3) in degrees per axis (x, y, z), the inverse of `angles_to_pose`.

    R = Rx(x) Rz(z) Ry(y) is scipy's intrinsic "XZY" sequence; it returns (x, z, y), reordered here."""
    r = np.asarray(pose, dtype=np.float64).reshape(-1, 3, 3)
    xzy = Rotation.from_matrix(r).as_euler("XZY", degrees=True)
    return xzy[:, [0, 2, 1]]


def clamp_to_limits(angles_deg, limits_deg) -> np.ndarray:
    """Angles (J, 3) clipped into the limits (J, 3, 2): what the sliders can show of a pose outside them."""
    lim = np.asarray(limits_deg, dtype=np.float64)
    return np.clip(np.asarray(angles_deg, dtype=np.float64), lim[..., 0], lim[..., 1])


# ----------------------------------------------------------------------------- the update function


@dataclass
class ViewMeshes:
    """What one update draws: vertices in metres, float32 numpy."""

    garment: np.ndarray  # (V, 3) the prediction
    body: np.ndarray  # (Vb, 3) the posed body
    error_cm: np.ndarray | None = None  # (V,) |prediction - simulation| per vertex, with a simulated garment


def view_meshes(predictor: ClothPredictor, pose, model: str, method: str | None = None,
                truth=None) -> ViewMeshes:
    """One pose (J, 3, 3) -> the predicted garment (model "whole" or "patches", `method` the seam method),
    the posed body and, given the simulated garment `truth` (V, 3), the per-vertex error in cm."""
    pose = torch.as_tensor(np.asarray(pose, dtype=np.float32))
    garment = predictor(pose, model=model, method=method if model == "patches" else None).float().cpu()
    body = pose_body(predictor.dataset.body, pose[None].to(predictor.dataset.body.vertices.dtype))[0]
    err = None
    if truth is not None:
        err = ((garment - torch.from_numpy(np.array(truth, dtype=np.float32))).norm(dim=-1) * 100.0).numpy()
    return ViewMeshes(garment.numpy(), body.detach().cpu().float().numpy(), err)


def error_colors(error_cm: np.ndarray, max_cm: float, colormap: str) -> np.ndarray:
    """Per-vertex errors (V,) in cm -> RGBA (V, 4) uint8 over `colormap`, 0 to `max_cm` (saturating)."""
    cmap = matplotlib.colormaps[colormap]
    return (cmap(np.clip(np.asarray(error_cm) / float(max_cm), 0.0, 1.0)) * 255).astype(np.uint8)


# ----------------------------------------------------------------------------- sequences and ports


def load_sequence(path: str | Path, dataset, allow_rest: bool = False, rest_frame: int | None = None,
                  trust: bool = False) -> tuple[Tensor, float | None, Motion | None]:
    """A pose sequence for the timeline: an .npy of rotations ((N, J, 3, 3) or (N, J*9), checked by
    `pbc.inference.poses.read_poses`) or a .bvh clip (`pbc.inference.poses.read_motion`: joint map "auto", every
    frame; `allow_rest`: go on when the body's arms, legs or spine match no joint of the clip; `rest_frame`,
    `trust`: as pbc predict's) -> (poses (N, J, 3, 3) float32, the clip's frames a second, the clip's Motion;
    None and None for an .npy)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".bvh"):
        raise ValueError(f"sequence {path}: give an .npy of (N, {dataset.poses.shape[1]}, 3, 3) rotations or a .bvh "
                         "motion file")
    if not path.is_file():
        raise ValueError(f"sequence file {path} does not exist")
    if suffix == ".bvh":
        motion = read_motion(path, dataset, allow_rest=allow_rest, rest_frame=rest_frame, trust=trust)
        return torch.as_tensor(np.asarray(motion.poses), dtype=torch.float32), float(motion.fps), motion
    return read_poses(path, dataset)[0], None, None


def check_port(port) -> int:
    """A TCP port number 0-65535 (0: any free port the system picks); else one clear error."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= MAX_PORT:
        raise ValueError(f"port {port!r}: give a TCP port number from 1 to {MAX_PORT} (or 0 for any free one)")
    return port


def port_is_free(host: str, port: int) -> bool:
    """Whether `port` on `host` can be bound now (as the server binds it: SO_REUSEADDR set)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_port(host: str, port: int, tries: int = 100) -> int:
    """`port` when it is free, else the next free one above it (within `tries`); 0 stays 0 (the system picks)."""
    port = check_port(port)
    if port == 0:
        return 0
    for p in range(port, min(port + tries, MAX_PORT + 1)):
        if port_is_free(host, p):
            return p
    raise OSError(f"ports {port}-{min(port + tries, MAX_PORT + 1) - 1} on {host} are all in use: give another "
                  "--port")


# ----------------------------------------------------------------------------- the scene


class ClothViewer:
    """A viser scene of `predictor`: body, predicted garment, the GUI. Build it on a running server
    (`start_viewer` makes both). The public state for scripts and tests: `sliders[(joint, axis)]`,
    `model`, `method`, `pose_dropdown`, `timeline`, `play`, and `garment_vertices()` (what is drawn)."""

    def __init__(self, server: viser.ViserServer, predictor: ClothPredictor, cfg=None,
                 sequence: Tensor | None = None, log=print, sequence_fps: float | None = None):
        self.server, self.predictor = server, predictor
        self.cfg = cfg if cfg is not None else view_config()
        self.log = log
        ds = predictor.dataset
        self.skeleton = ds.body.skeleton
        self.limits = self.skeleton.limits_deg.double().numpy()  # (J, 3, 2)
        self.garment_faces = np.asarray(ds.garment.faces, dtype=np.uint32)
        self.body_faces = np.asarray(ds.body.faces, dtype=np.uint32)
        self.sequence = sequence
        self.sequence_fps = sequence_fps  # a BVH clip's own rate; else conf/view.yaml's fps
        # the pose predicted: the sliders' angles, or a dataset / sequence pose as given (its exact matrices)
        self.pose = angles_to_pose(np.zeros((self.skeleton.num_joints, 3)))
        self.truth: np.ndarray | None = None
        self.meshes: ViewMeshes | None = None
        self.updates = 0
        self._lock = threading.Lock()
        self._pending = self._busy = False
        self._quiet = False  # set while the code moves the sliders: those moves are not a new pose
        self._stop = threading.Event()
        self._player: threading.Thread | None = None
        self._pca_ready = predictor.stitcher is not None and getattr(predictor.stitcher, "pca", None) is not None
        self._dataset_index = self._dataset_poses()
        self._build_scene()
        self._build_gui()
        if self.sequence is not None:  # a sequence opens on its own first frame
            self._on_frame()
            return
        first = next((name for name in self._dataset_index if name.startswith("test")), NO_POSE)
        self.pose_dropdown.value = first  # the first test pose, with its simulation, else the rest pose
        if first == NO_POSE:
            self.schedule()

    # ---------------------------------------------------------------- building
    def _dataset_poses(self) -> dict[str, int]:
        """Dropdown label -> dataset index, the test split first (the poses no model trained on)."""
        out: dict[str, int] = {}
        splits = self.predictor.dataset.manifest.get("splits") or {}
        for split in ("test", "val", "train"):
            if split in splits:
                for i in self.predictor.dataset.split(split):
                    out[f"{split} {int(i):05d}"] = int(i)
        return out

    def _build_scene(self) -> None:
        c, scene = self.cfg, self.server.scene
        scene.set_up_direction("+y")
        self.server.initial_camera.position = tuple(float(v) for v in c.camera.position)
        self.server.initial_camera.look_at = tuple(float(v) for v in c.camera.look_at)
        ds = self.predictor.dataset
        rest_g = np.asarray(ds.garment.vertices, dtype=np.float32)
        rest_b = np.asarray(ds.body.vertices, dtype=np.float32)
        self.body_handle = scene.add_mesh_simple("/prediction/body", rest_b, self.body_faces,
                                                 color=tuple(c.colors.body))
        # both sides drawn: the shirt is an open surface, its inside shows at the neck and the sleeves
        self.garment_handle = scene.add_mesh_simple("/prediction/garment", rest_g, self.garment_faces,
                                                    color=tuple(c.colors.garment), side="double")
        self.error_handle = None  # the error-coloured garment (a GLB: viser's simple mesh has one colour)
        offset = (float(c.side_offset), 0.0, 0.0)
        self.truth_body_handle = scene.add_mesh_simple("/simulated/body", rest_b, self.body_faces,
                                                       color=tuple(c.colors.body), position=offset, visible=False)
        self.truth_handle = scene.add_mesh_simple("/simulated/garment", rest_g, self.garment_faces,
                                                  color=tuple(c.colors.simulated), side="double",
                                                  position=offset, visible=False)

    def _build_gui(self) -> None:
        gui, c = self.server.gui, self.cfg
        p = self.predictor
        models = [m for m in ("whole", "patches") if (p.whole_net if m == "whole" else p.patch_net) is not None]
        self.model = gui.add_dropdown("model", [MODEL_LABELS[m] for m in models],
                                      initial_value=MODEL_LABELS[models[0]])
        methods = [m for m in METHODS if p.whole_net is not None or m not in NEEDS_WHOLE]
        first = str(c.method) if str(c.method) in methods else methods[0]
        self.method = gui.add_dropdown("seam method", methods, initial_value=first,
                                       disabled=p.patch_net is None, hint="how the patch crops become one garment")
        self.model.on_update(lambda _: self.schedule())
        self.method.on_update(lambda _: self.schedule())
        self.pose_dropdown = gui.add_dropdown("dataset pose", [NO_POSE, *self._dataset_index], initial_value=NO_POSE,
                                              hint="a simulated pose: shown beside, the prediction coloured by error")
        self.pose_dropdown.on_update(lambda _: self._on_dataset_pose())
        self.error_text = gui.add_text("vertex error", "", disabled=True)
        self.show_error = gui.add_checkbox("colour by error", True)
        self.show_error.on_update(lambda _: self.schedule())
        self.timeline = self.play = None
        if self.sequence is not None:
            with gui.add_folder("sequence"):
                self.timeline = gui.add_slider("frame", 0, max(len(self.sequence) - 1, 1), 1, 0,
                                               disabled=len(self.sequence) < 2)
                self.play = gui.add_checkbox("play", False)
                self.fps = gui.add_number("fps", float(self.sequence_fps or c.fps), min=1.0, max=240.0, step=1.0)
            self.timeline.on_update(lambda _: self._on_frame())
            self.play.on_update(lambda _: self._on_play())
        self.sliders = {}
        step = float(c.slider_step_deg)
        for j, name in enumerate(self.skeleton.names):
            with gui.add_folder(name, expand_by_default=j in (0, 7)):
                for a, axis in enumerate(AXES):
                    lo, hi = (float(v) for v in self.limits[j, a])
                    s = gui.add_slider(f"{name} {axis}", lo, hi, step, float(np.clip(0.0, lo, hi)))
                    s.on_update(lambda _: self._on_slider())
                    self.sliders[(name, axis)] = s

    # ---------------------------------------------------------------- GUI events
    def angles(self) -> np.ndarray:
        """The sliders' angles (J, 3) in degrees."""
        return np.array([[self.sliders[(n, a)].value for a in AXES] for n in self.skeleton.names], dtype=np.float64)

    def _set_sliders(self, pose) -> None:
        """Show `pose` on the sliders (clipped to the limits) without making that a new pose."""
        angles = clamp_to_limits(pose_to_angles(pose), self.limits)
        self._quiet = True
        try:
            for j, n in enumerate(self.skeleton.names):
                for a, axis in enumerate(AXES):
                    self.sliders[(n, axis)].value = float(angles[j, a])
        finally:
            self._quiet = False

    def _on_slider(self) -> None:
        if self._quiet:
            return
        with self._lock:
            self.pose, self.truth = angles_to_pose(self.angles()), None
        if self.pose_dropdown.value != NO_POSE:
            self._quiet = True
            try:
                self.pose_dropdown.value = NO_POSE  # a moved slider leaves the simulated pose
            finally:
                self._quiet = False
        self.schedule()

    def _on_dataset_pose(self) -> None:
        if self._quiet:
            return
        label = self.pose_dropdown.value
        if label == NO_POSE:
            with self._lock:
                self.pose, self.truth = angles_to_pose(self.angles()), None
        else:
            i = self._dataset_index[label]
            ds = self.predictor.dataset
            with self._lock:
                self.pose = torch.from_numpy(np.array(ds.poses[i], dtype=np.float32))  # a copy: the arrays are mmaps
                self.truth = np.array(ds.verts[i], dtype=np.float32)
            self._set_sliders(self.pose)
        self.schedule()

    def _on_frame(self) -> None:
        if self._quiet or self.sequence is None:
            return
        k = int(self.timeline.value)
        with self._lock:
            self.pose, self.truth = self.sequence[k], None
        self._set_sliders(self.pose)
        if self.pose_dropdown.value != NO_POSE:
            self._quiet = True
            try:
                self.pose_dropdown.value = NO_POSE
            finally:
                self._quiet = False
        self.schedule()

    def _on_play(self) -> None:
        if self.play.value and (self._player is None or not self._player.is_alive()):
            self._player = threading.Thread(target=self._play_loop, name="pbc-view-play", daemon=True)
            self._player.start()

    def _play_loop(self) -> None:
        """Advance the timeline in real time at the fps box's rate; frames skip when an update is slower."""
        n = len(self.sequence)
        start, t0 = int(self.timeline.value), time.perf_counter()
        while self.play.value and not self._stop.is_set():
            k = (start + int((time.perf_counter() - t0) * float(self.fps.value))) % n
            if k != int(self.timeline.value):
                self.timeline.value = k
            time.sleep(0.5 / float(self.fps.value))

    # ---------------------------------------------------------------- updates
    def current_model(self) -> str:
        return {v: k for k, v in MODEL_LABELS.items()}[self.model.value]

    def schedule(self) -> None:
        """Update the scene to the newest state: now, or, when an update is running (another GUI event's
        thread), by that update going round once more when it ends."""
        with self._lock:
            self._pending = True
            if self._busy:
                return
            self._busy = True
        try:
            while True:
                with self._lock:
                    if not self._pending:
                        self._busy = False
                        return
                    self._pending = False
                    pose, truth = self.pose, self.truth
                self.refresh(pose, truth)
        except BaseException:
            with self._lock:
                self._busy = False
            raise

    def refresh(self, pose=None, truth=None) -> ViewMeshes:
        """Predict `pose` (default: the current one) and draw it; returns what was drawn."""
        if pose is None:
            pose, truth = self.pose, self.truth
        model, method = self.current_model(), str(self.method.value)
        if model == "patches" and method == "pca" and not self._pca_ready:
            self._fit_pca()
        m = view_meshes(self.predictor, pose, model, method, truth)
        self.meshes = m
        self.garment_handle.vertices = m.garment
        self.body_handle.vertices = m.body
        shown = m.error_cm is not None
        if shown:
            self.truth_handle.vertices = truth
            self.truth_body_handle.vertices = m.body
            self.error_text.value = f"mean {m.error_cm.mean():.2f} cm, max {m.error_cm.max():.2f} cm"
        else:
            self.error_text.value = ""
        self.truth_handle.visible = self.truth_body_handle.visible = shown
        coloured = shown and bool(self.show_error.value)
        if coloured:
            mesh = trimesh.Trimesh(m.garment, self.garment_faces, process=False,
                                   vertex_colors=error_colors(m.error_cm, float(self.cfg.error_max_cm),
                                                              str(self.cfg.error_colormap)))
            self.error_handle = self.server.scene.add_mesh_trimesh("/prediction/garment_error", mesh)
        elif self.error_handle is not None:
            self.error_handle.remove()
            self.error_handle = None
        self.garment_handle.visible = not coloured
        self.updates += 1
        return m

    def _fit_pca(self) -> None:
        """The PCA seam method's basis, fitted on the training split the first time it is chosen (seconds)."""
        self.log("fitting the PCA seam basis on the training split (once) ...")
        cfg = stitch_config("pca")
        self.predictor.stitcher.pca = fit_training_pca(self.predictor, int(cfg.pca_components),
                                                       int(self.cfg.pca_fit_max))
        self._pca_ready = True

    def garment_vertices(self) -> np.ndarray:
        """The predicted garment's vertices (V, 3) as the scene holds them now."""
        return np.asarray(self.garment_handle.vertices).copy()

    def close(self) -> None:
        """Stop playback (and wait for its thread, so nothing is sent after the server stops)."""
        self._stop.set()
        if self.play is not None:
            self.play.value = False
        if self._player is not None:
            self._player.join(timeout=10)


def is_loopback(host: str) -> bool:
    """Whether `host` is this machine only (127.0.0.0/8, ::1, localhost): nothing else can reach it."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name: what it resolves to
        try:
            return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
        except (OSError, ValueError):
            return False


def machine_address() -> str:
    """This machine's address as other machines on its network see it: the source address of the default
    route (a UDP socket is connected, nothing is sent), else the host name's address, else its name."""
    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("10.255.255.255", 1))
        addr = s.getsockname()[0]
        if not ipaddress.ip_address(addr).is_loopback and addr != "0.0.0.0":
            return addr
    with contextlib.suppress(OSError):
        addr = socket.gethostbyname(socket.gethostname())
        if not ipaddress.ip_address(addr).is_loopback:
            return addr
    return socket.gethostname()


def network_warning(host: str, port: int) -> str | None:
    """One line when the viewer serves more than this machine (it has no login), with the address to open."""
    if is_loopback(host):
        return None
    where = machine_address() if host in WILDCARD_HOSTS else host
    return (f"warning: the viewer on {host} is reachable from the network and has no login: anyone who can reach "
            f"this machine can use it (--host 127.0.0.1 keeps it to this machine); open http://{where}:{port}/")


WILDCARD_HOSTS = ("0.0.0.0", "::", "")  # every interface: no address to open as such


def start_viewer(predictor: ClothPredictor, host: str | None = None, port: int | None = None,
                 sequence: Tensor | None = None, cfg=None, log=print,
                 sequence_fps: float | None = None) -> ClothViewer:
    """Serve `predictor` on http://host:port (conf/view.yaml's by default). A port in use is said so (through
    `log`) and the next free one taken. Returns the viewer; `viewer.server.stop()` ends it."""
    cfg = cfg if cfg is not None else view_config()
    host = str(cfg.host if host is None else host)
    want = check_port(int(cfg.port) if port is None else port)
    got = free_port(host, want)
    if got != want:
        log(f"port {want} on {host} is in use; the viewer takes the next free one, {got}")
    server = viser.ViserServer(host=host, port=got, verbose=False)
    if got and server.get_port() != got:  # taken between the check and the bind: viser moved on by itself
        log(f"port {got} on {host} was taken meanwhile; the viewer is on {server.get_port()}")
    warning = network_warning(host, server.get_port())
    if warning:
        log(warning)
    try:
        return ClothViewer(server, predictor, cfg, sequence, log, sequence_fps)
    except BaseException:
        server.stop()
        raise


def url(viewer: ClothViewer) -> str:
    host = viewer.server.get_host()
    shown = "localhost" if is_loopback(host) else machine_address() if host in WILDCARD_HOSTS else host
    return f"http://{shown}:{viewer.server.get_port()}/"


def stop_within(grace_s: float, say=lambda text: print(text, flush=True)) -> None:
    """Make Ctrl-C end this process whatever its threads do: SIGINT raises KeyboardInterrupt as Python's own
    handler does, and arms a watchdog that, if the process is still alive `grace_s` seconds later (a thread
    of the web server or a library holding the exit), writes every thread's stack to stderr, says the viewer
    stopped, and exits with status 0: the user asked it to stop, and a second Ctrl-C should not be needed."""
    def force_exit() -> None:
        sys.stderr.write(f"pbc view: still running {grace_s:g} s after Ctrl-C; every thread's stack:\n")
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        say(f"pbc view: stopped (forced {grace_s:g} s after Ctrl-C)")
        os._exit(0)

    def on_interrupt(signum, frame) -> None:
        watchdog = threading.Timer(grace_s, force_exit)
        watchdog.daemon = True
        watchdog.start()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_interrupt)


def wait_forever(viewer: ClothViewer, poll_s: float = 1.0) -> None:
    """Block until Ctrl-C (KeyboardInterrupt, which the entry floor reports); the server stops either way."""
    try:
        while True:
            time.sleep(poll_s)
    finally:
        viewer.close()
        viewer.server.stop()
        sys.stdout.flush()


__all__: Sequence[str] = ("ClothViewer", "ViewMeshes", "angles_to_pose", "clamp_to_limits", "error_colors",
                          "free_port", "load_sequence", "pose_to_angles", "start_viewer", "view_config",
                          "view_meshes")
