"""Files packed from meshes held in memory, kept in a cache directory under a name that is a hash
of what was packed, so that the next run (or another process) opens the file instead of packing
again: what :mod:`oavm.trimesh` and :mod:`oavm.open3d` do on first use.

The name hashes the float32 vertices and uint32 faces exactly as packed, the options and the
file format's version; a file there that does not open as a sound ``.oavm`` file (cut short by a
crash of an older version, another format) is packed again. Packing writes a temporary file and
renames it into place, so two processes packing the same mesh at once both end with a whole file.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from . import FORMAT_VERSION, FormatError, Scene, _native, pack
from . import open as open_scene

PathLike = Union[str, "os.PathLike[str]"]


def default_dir() -> Path:
    """``$OAVM_CACHE_DIR``, else ``$XDG_CACHE_HOME/oavm``, else ``~/.cache/oavm``."""
    if os.environ.get("OAVM_CACHE_DIR"):
        return Path(os.environ["OAVM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "oavm"


def key(vertices: np.ndarray, faces: np.ndarray, *extra: bytes) -> str:
    """The hex name of a packed mesh: blake2b over its arrays, their shapes and `extra`."""
    h = hashlib.blake2b(digest_size=20)
    h.update(f"oavm format {FORMAT_VERSION}; {vertices.shape} {faces.shape};".encode())
    h.update(np.ascontiguousarray(vertices, dtype=np.float32).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.uint32).tobytes())
    for e in extra:
        h.update(e)
    return h.hexdigest()


def opened(vertices: np.ndarray, faces: np.ndarray, cache_dir: Optional[PathLike],
           mem_budget=None, *extra: bytes, geometries: Optional[list] = None) -> Scene:
    """The scene of ``(vertices, faces)`` (float32 and uint32, as :func:`oavm.pack` takes
    them; with ``geometries``, several meshes, as ``_native.pack_arrays`` takes them), from the
    cache directory, packed there first if it is not."""
    where = Path(cache_dir) if cache_dir is not None else default_dir()
    where.mkdir(parents=True, exist_ok=True)
    if geometries:
        extra = extra + (repr(geometries).encode(),)
    path = where / f"{key(vertices, faces, *extra)}.oavm"
    if path.exists():
        try:
            return open_scene(path, mem_budget=mem_budget)
        except (FormatError, OSError):
            pass  # packed again below
    if geometries:
        # Atomically, as pack() writes (the geometries are those of native pack_arrays).
        _native.pack_arrays(vertices, faces, os.fspath(path), progress=False, geometries=geometries)
    else:
        pack((vertices, faces), path, progress=False)
    return open_scene(path, mem_budget=mem_budget)
