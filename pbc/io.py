"""Safe file I/O for every stage: atomic writes, content hashes, and one clear error for a bad file.

Every writer in pbc goes through `atomic_path`: a temporary file in the target's directory, then
`os.replace`, so a crash or a SIGKILL leaves either the old file or the new one, never half of one.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


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


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write `obj` as sorted, indented JSON, atomically (byte-identical for equal objects)."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib figure as PNG, atomically, and close it."""
    import matplotlib.pyplot as plt

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
