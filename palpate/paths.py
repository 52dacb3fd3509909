"""Path settings. Data locations come from the environment, with repository-relative defaults."""

from __future__ import annotations

import os
from pathlib import Path

import palpate.launch_files as _launch_files

REPO_ROOT = Path(__file__).resolve().parent.parent
#: The launch files shipped with palpate: launch/ of the repository, installed as `palpate.launch_files`
#: (so `palpate demo` and the evaluations find them in a wheel too).
LAUNCH_DIR = Path(_launch_files.__file__).resolve().parent

#: Environment variable that points at the YCB mesh folder (binary STL files in metres).
YCB_DIR_ENV = "PALPATE_YCB_DIR"
#: Environment variable for the on-disk cache (convex decompositions, ...).
CACHE_DIR_ENV = "PALPATE_CACHE_DIR"
#: Mesh files an evaluation or benchmark takes from a folder (the simulator reads any format trimesh does).
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")


def ycb_dir() -> Path | None:
    """The YCB mesh folder: ``$PALPATE_YCB_DIR``, else ``../shared/data/ycb`` beside the repository.

    Returns None when the folder does not exist, so that callers can skip with a reason.
    """
    candidate = ycb_dir_looked_at()
    return candidate if candidate.is_dir() else None


def ycb_dir_looked_at() -> Path:
    """Where ``ycb_dir`` looks (to name it when nothing is there)."""
    configured = os.environ.get(YCB_DIR_ENV)
    return Path(configured) if configured else REPO_ROOT.parent / "shared" / "data" / "ycb"


def cache_dir() -> Path:
    """Directory for derived data that is expensive to compute: ``$PALPATE_CACHE_DIR`` or ~/.cache/palpate."""
    configured = os.environ.get(CACHE_DIR_ENV)
    path = Path(configured) if configured else Path.home() / ".cache" / "palpate"
    path.mkdir(parents=True, exist_ok=True)
    return path


def why_not(exc: BaseException) -> str:
    """What stopped a file operation, for a message: the OS's reason, else the exception's type
    (pathlib's mkdir of a path of thousands of parts raises RecursionError)."""
    return exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__


def read_start(path: str | Path, size: int) -> bytes:
    """At most the first `size` bytes of the file at `path` (a caller that asks for one byte more than it
    takes tells a file too large without reading it to the end: /dev/zero would fill the memory)."""
    with Path(path).open("rb") as stream:
        return stream.read(size)


def output_path_problem(path: Path, example: str) -> str:
    """Why a file could not be written at `path` (its folder is made as needed), '' when it could;
    `example`: a file name to suggest when `path` is a folder."""
    if path.is_dir():
        return f"{path} is a directory; give a file name, such as {path / example}"
    existing = next(p for p in (path.parent, *path.parent.parents) if p.exists())
    if not existing.is_dir():
        return f"{path}: {existing} is not a folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"{path}: the folder {existing} is not writable"
    return ""


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether `a` and `b` name one file: the same path once resolved (symlinks too), or hard links."""
    a, b = Path(a), Path(b)
    return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
