"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from palpate.paths import YCB_DIR_ENV, ycb_dir


@pytest.fixture
def ycb() -> Path:
    """The YCB mesh folder, or skip the test with the reason."""
    path = ycb_dir()
    if path is None:
        pytest.skip(f"YCB meshes not found: set {YCB_DIR_ENV} or place them in ../shared/data/ycb")
    return path
