"""Where numba caches palpate's compiled kernels when neither the install nor the home can be written."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from palpate import numba_cache_fallback


def test_numba_gets_a_temp_cache_only_where_neither_the_install_nor_the_home_is_writable(tmp_path: Path) -> None:
    """An outside walkthrough: a read-only install run by a user whose home was read-only crashed every
    command, --help too, with numba's "cannot cache function ...: no locator available"."""
    install, home = str(tmp_path / "site"), str(tmp_path / "home")
    os.makedirs(install)
    os.makedirs(home)
    temp = str(tmp_path / "tmp")

    def only(*paths: str) -> Callable[[str], bool]:  # the directories that may be written
        return lambda path: path in paths

    assert numba_cache_fallback(install, home, temp, only(install)) is None  # numba caches beside the modules
    assert numba_cache_fallback(install, home, temp, only(home)) is None  # it creates ~/.cache/numba
    fallback = numba_cache_fallback(install, home, temp, only())
    assert fallback is not None and fallback.startswith(os.path.join(temp, "palpate-numba-"))
    os.makedirs(os.path.join(home, ".cache"))
    assert numba_cache_fallback(install, home, temp, only(os.path.join(home, ".cache"))) is None
