"""palpate: learning the shape of unknown objects by touch.

The runtime (bus, launcher, recorder, CLI) lives here; the nodes live in `palpate.nodes` and the
message schemas in `palpate.messages`.
"""

import os
from collections.abc import Callable

# One node, one core: multithreaded BLAS in several node processes on a small machine makes every
# solve slower (measured: GPIS surface 120 ms of CPU instead of 28 on 2 cores). Set before numpy loads;
# an explicit setting in the environment wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def _writable(path: str) -> bool:
    return os.access(path, os.W_OK)


def numba_cache_fallback(
    package_dir: str, home: str, temp: str, writable: Callable[[str], bool] = _writable
) -> str | None:
    """Where numba should cache compiled kernels, or None to leave it to numba: it caches them beside their
    modules, else under ~/.cache; where neither can be written (a read-only install run by a user without a
    writable home) it raised at import, even for ``palpate --help``. A directory of the temp folder then."""
    if writable(package_dir):
        return None
    cache = os.path.join(home, ".cache")
    existing = cache
    while not os.path.exists(existing) and os.path.dirname(existing) != existing:
        existing = os.path.dirname(existing)  # numba creates ~/.cache/numba if an ancestor lets it
    if writable(existing):
        return None
    return os.path.join(temp, f"palpate-numba-{getattr(os, 'getuid', lambda: 0)()}")


if "NUMBA_CACHE_DIR" not in os.environ:  # an explicit setting in the environment wins
    import tempfile

    _fallback = numba_cache_fallback(os.path.dirname(__file__), os.path.expanduser("~"), tempfile.gettempdir())
    if _fallback is not None:
        os.environ["NUMBA_CACHE_DIR"] = _fallback

__version__ = "0.1.0"
