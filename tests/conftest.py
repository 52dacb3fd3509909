"""Shared fixtures, and the Hypothesis profile of the suite."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from palpate.paths import YCB_DIR_ENV, ycb_dir

# The same examples on every run (a seed from each test's name), and no failure because a loaded
# machine drew them slowly. HYPOTHESIS_PROFILE=explore draws new examples each run.
settings.register_profile("palpate", derandomize=True, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("explore", suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "palpate"))


@pytest.fixture
def ycb() -> Path:
    """The YCB mesh folder, or skip the test with the reason."""
    path = ycb_dir()
    if path is None:
        pytest.skip(f"YCB meshes not found: set {YCB_DIR_ENV} or place them in ../shared/data/ycb")
    return path
