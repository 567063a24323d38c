"""Safe file I/O for every stage: atomic writes, content hashes, and one clear error for a bad file.

Every writer in pbc goes through `atomic_path`: a temporary file in the target's directory, then
`os.replace`, so a crash or a SIGKILL leaves either the old file or the new one, never half of one.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import hashlib
import json
import os
import pickle
import shutil
import socket
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pbc.core.paths import CONF_DIR


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is renamed onto `path`, on error removed.

    `suffix` keeps the extension for writers that append one (np.save adds ".npy" when missing).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o644)  # mkstemp makes files private; what pbc writes is shared data
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, previous: str | os.PathLike | None = None) -> Iterator[Path]:
    """Yield an empty folder beside `path` to write into; on success it is renamed onto `path`, on error removed
    with everything in it, so `path` is either as before or whole. What `path` held is renamed to `previous`
    (kept) just before the new folder takes its place, or, with `previous` None, removed once it has."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o755)  # mkdtemp makes folders private; what pbc writes is shared data
        old = None
        if path.exists() or path.is_symlink():
            old = Path(previous) if previous is not None else tmp.with_name(tmp.name + ".replaced")
            os.rename(path, old)
        try:
            os.rename(tmp, path)
        except OSError:
            if old is not None:
                os.rename(old, path)  # the folder as it was
            raise
        if old is not None and previous is None and old.is_dir() and not old.is_symlink():
            shutil.rmtree(old)
        elif old is not None and previous is None:
            old.unlink()
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write `obj` as sorted, indented JSON, atomically (byte-identical for equal objects)."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib figure as PNG, atomically, and close it."""
    import matplotlib.pyplot as plt  # noqa: PLC0415 - the caller chose the backend and loaded pyplot; io needs none

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format="png")
    plt.close(fig)
    return Path(path)


def read_json(path: str | os.PathLike, what: str = "file") -> dict:
    """Read a JSON file, with one clear error when it is missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"{what} {path} is corrupt ({err}); delete it and re-run the command that makes it") from err


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    """`np.save`, atomically."""
    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, np.ascontiguousarray(array))


def load_npy(path: str | os.PathLike, mmap: bool = True, shape: tuple | None = None) -> np.ndarray:
    """Load (memory-map) an .npy file; a missing, truncated or wrongly shaped array gets one clear error.

    `shape` may hold None for dimensions that are free, e.g. (None, 10, 3, 3).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"array not found: {path}")
    try:
        arr = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise ValueError(f"array {path} is corrupt or truncated ({err}); regenerate the dataset") from err
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape, strict=False))
        if not ok:
            raise ValueError(f"array {path} has shape {arr.shape}, expected {shape}; regenerate the dataset")
    return arr


def hash_arrays(*arrays: np.ndarray | Any) -> str:
    """A short, stable content hash of arrays (dtype, shape and bytes) and JSON-able values."""
    h = hashlib.sha256()
    for a in arrays:
        if isinstance(a, np.ndarray) or hasattr(a, "numpy"):
            a = np.ascontiguousarray(a.detach().cpu().numpy() if hasattr(a, "detach") else a)
            h.update(str(a.dtype).encode())
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(a, sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


# ----------------------------------------------------------------------------------------- reading
def load_npz(path: str | os.PathLike, keys: tuple[str, ...] | None = None, what: str = "file",
             fix: str = "delete it and re-run the command that makes it") -> dict[str, np.ndarray]:
    """Read every array (or `keys`) of an .npz into memory; a missing, truncated or incomplete file gets
    one ValueError/FileNotFoundError naming the file and `fix` (numpy raises a bare BadZipFile)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in (keys or ()) if k not in z.files]
            if missing:
                raise KeyError(f"missing arrays {missing}")
            return {k: z[k] for k in (keys or z.files)}
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, KeyError) as err:
        raise ValueError(f"{what} {path} is corrupt or truncated ({type(err).__name__}: {err}); {fix}") from err


def load_checkpoint(path: str | os.PathLike, map_location: str = "cpu", fix: str = "") -> dict:
    """`torch.load` of a Lightning checkpoint with one clear error naming the file when it is corrupt, and
    `fix` (default: resume from another checkpoint of the run, or train again)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        ck = torch.load(path, map_location=map_location, weights_only=False)
    except (RuntimeError, EOFError, OSError, ValueError, pickle.UnpicklingError, zipfile.BadZipFile) as err:
        raise ValueError(
            f"checkpoint {path} is corrupt or truncated ({type(err).__name__}: {err}); "
            + (fix or "delete it and resume from another checkpoint of the run (checkpoints/epoch_*.ckpt) or train "
               "again")
        ) from err
    if not isinstance(ck, dict) or "state_dict" not in ck:
        raise ValueError(f"{path} is not a Lightning checkpoint (no state_dict); pass a .ckpt written by pbc.train")
    return ck


# ----------------------------------------------------------------------------------------- places
def user_cache_dir(*parts: str) -> Path:
    """Per-user cache dir for derived files: $PBC_CACHE_DIR, else $XDG_CACHE_HOME/pbc, else ~/.cache/pbc."""
    base = os.environ.get("PBC_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pbc"
    return Path(base, *parts)


def is_writable_dir(path: str | os.PathLike) -> bool:
    """True when `path` exists as a writable dir or could be created (its nearest existing parent is writable)."""
    p = Path(path).absolute()
    while not p.exists():
        if p.parent == p:
            return False
        p = p.parent
    return p.is_dir() and os.access(p, os.W_OK | os.X_OK)


def out_dir_problem(path: str | os.PathLike) -> str | None:
    """Why new files cannot be written in folder `path`, or None when they can: it is a folder this user may
    write in, or it does not exist and the nearest existing folder above it is one (it can be created). Only
    looks: nothing is created."""
    p = Path(path).absolute()
    existing = p
    while not existing.exists() and existing.parent != existing:
        existing = existing.parent
    below = "" if existing == p else "it cannot be created: "
    if not existing.is_dir():
        return f"{below}{existing} is a file, not a folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"{below}{existing} is read-only to this user (chmod u+w {existing} to write there)"
    return None


def require_out_dir(path: str | os.PathLike, flag: str = "--out", holds_file: bool = False) -> Path:
    """Refuse up front, in one PermissionError naming the folder `path` and the fix, an output folder that does
    not exist and cannot be created, is a file, or is read-only (`out_dir_problem`): checked before any work,
    so no write fails later naming a temporary file. `flag` names the option the folder came from, a file
    inside it with `holds_file` (`--out body.obj`). Creates nothing."""
    problem = out_dir_problem(path)
    if problem is not None:
        where = f"the folder of {flag}" if holds_file else f"{flag} folder"
        want = "a file in a folder you can write to" if holds_file else "a folder you can write to"
        raise PermissionError(f"{where} {path}: {problem}; give {flag} {want}")
    return Path(path)


def require_writable_dir(path: str | os.PathLike, what: str = "output directory", fix: str = "") -> Path:
    """Create `path` if needed and return it; one PermissionError naming it when it cannot be written
    (a read-only runs dir otherwise surfaces as a misleading FileNotFoundError deep in a logger)."""
    p = Path(path)
    if not is_writable_dir(p):
        raise PermissionError(f"{what} {p} is not writable; {fix or 'choose a writable location'}")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise PermissionError(f"cannot create {what} {p} ({err}); {fix or 'choose a writable location'}") from err
    return p


# ----------------------------------------------------------------------------------------- full disks
class DiskFull(OSError):
    """A write failed for want of space (ENOSPC / EDQUOT), named: the path, the bytes needed when known, the fix.

    Raised with its one message (`DiskFull(message)`), so it pickles across worker processes as it is."""


_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


def out_of_space(err: BaseException | None) -> bool:
    """Whether ENOSPC / EDQUOT is `err` or anywhere in its chain (a full disk in np.save surfaces as the
    zip writer's or the file close's error, with the OSError two links down)."""
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, OSError) and err.errno in _NO_SPACE:
            return True
        err = err.__cause__ or err.__context__
    return False


def _human(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def human_bytes(n: int) -> str:
    """`n` bytes as people read them: 934.3 KiB, 1.2 GiB."""
    return _human(n)


def free_bytes(path: str | os.PathLike) -> int:
    """Bytes free to this user on the file system that holds `path` (or its nearest existing parent)."""
    p = Path(path).absolute()
    while not p.exists() and p.parent != p:
        p = p.parent
    return shutil.disk_usage(p).free


def _disk_full_message(path, what: str, fix: str, needed: int | None, free: int | None) -> str:
    amount = ""
    if needed is not None:
        amount = f": {_human(needed)} needed" + (f", {_human(free)} free" if free is not None else "")
    return f"no space left on the device holding {what} {path}{amount}; {fix or 'free space there'}"


IO_FILE = CONF_DIR / "io.yaml"  # free_space_margin_bytes


@functools.cache
def free_space_margin() -> int:
    """conf/io.yaml's free_space_margin_bytes: what a free-space check asks for beyond the files' own bytes (their
    blocks and folder entries); a whole number of bytes, at least 0 (its row in conf/bounds.yaml; checked here, as
    pbc.core.validate sits above this module)."""
    import yaml  # noqa: PLC0415 - only a free-space check reads the file

    margin = (yaml.safe_load(IO_FILE.read_text()) or {}).get("free_space_margin_bytes")
    if isinstance(margin, bool) or not isinstance(margin, int) or margin < 0:
        raise ValueError(f"{IO_FILE}: free_space_margin_bytes={margin!r}: expected a whole number of bytes, at least 0")
    return margin


def require_free_space(path: str | os.PathLike, needed: int, what: str = "output", fix: str = "") -> None:
    """Refuse up front (DiskFull naming `path`, the bytes asked for and the free bytes) when `needed` bytes of
    files and the margin of conf/io.yaml (`free_space_margin`) will not fit at `path`, so nothing is
    half-written; the message states the files' bytes and the margin, which add up to what it asks for."""
    free = free_bytes(path)
    margin = free_space_margin()
    if needed + margin > free:
        asked, left = _human(needed + margin), _human(free)
        if asked == left:  # equal when rounded: the bytes show which is more
            asked, left = f"{needed + margin:,} B", f"{free:,} B"
        amount = (f": {asked} needed ({_human(needed)} of files + a {_human(margin)} margin for the file system's "
                  f"blocks, conf/io.yaml), {left} free")
        raise DiskFull(f"no space left on the device holding {what} {path}{amount}; {fix or 'free space there'}")


@contextlib.contextmanager
def naming_full_disk(path: str | os.PathLike, what: str = "output", fix: str = "",
                     needed: int | None = None) -> Iterator[None]:
    """Turn an ENOSPC / EDQUOT `OSError` raised in the block (numpy, zipfile, json...: often chained two or
    three deep) into one DiskFull naming `path`, the bytes needed if known and `fix`. Writers inside should
    use `atomic_path`, which removes its temporary file, so nothing is left half-written."""
    try:
        yield
    except DiskFull:
        raise
    except Exception as err:
        if not out_of_space(err):
            raise
        free = None
        with contextlib.suppress(OSError):
            free = free_bytes(path)
        raise DiskFull(_disk_full_message(path, what, fix, needed, free)) from None


# ----------------------------------------------------------------------------------------- locks
class LockHeld(RuntimeError):
    """Another process holds a pbc lock file (see `dir_lock`)."""


@contextlib.contextmanager
def dir_lock(path: str | os.PathLike, what: str = "this directory", shared: bool = False,
             timeout: float = 0.0) -> Iterator[Path]:
    """Hold an advisory lock file `path` (flock) for the duration of the block.

    exclusive (default): no other holder at all; shared: other shared holders allowed, no exclusive one.
    `timeout` seconds to wait (0: refuse at once) before LockHeld names the holder (pid, host, start).
    The kernel drops the lock when its process dies, so a SIGKILLed holder leaves no stale lock. An
    exclusive holder removes the file on release (a waiter on the old file notices and retries), so a
    finished directory keeps no lock files.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise PermissionError(
            f"cannot create {path.parent} to lock {what} ({err}); choose a writable location"
        ) from err
    deadline = time.monotonic() + max(0.0, timeout)
    mode = fcntl.LOCK_SH if shared else fcntl.LOCK_EX
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise PermissionError(
                f"cannot write the lock file {path} ({err}); {what} is read-only: choose a writable location"
            ) from err
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = ""
            with contextlib.suppress(OSError, UnicodeDecodeError):
                holder = os.pread(fd, 4096, 0).decode().strip()
            os.close(fd)
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            raise LockHeld(
                f"{what} is in use by another process ({holder or 'holder unknown'}; lock file {path}); "
                "wait for it to finish and run again, or use another directory"
            ) from None
        # the file may have been removed by the previous exclusive holder after we opened it
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        if not shared:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}"
                          .encode(), 0)
        yield path
    finally:
        if not shared:
            with contextlib.suppress(OSError):
                path.unlink()
        os.close(fd)


def lock_holder(path: str | os.PathLike) -> str:
    """Who holds the lock file `path` as `dir_lock` wrote it ("pid N on HOST since TIME"), "" when unknown."""
    try:
        return Path(path).read_text().strip()
    except (OSError, UnicodeDecodeError):
        return ""
