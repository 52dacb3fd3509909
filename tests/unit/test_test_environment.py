"""The test set-up installs the optional extras, so the viewer and Foxglove tests run instead of skipping."""

from __future__ import annotations

import importlib

import pytest


@pytest.mark.parametrize("module", ["rerun", "foxglove", "google.protobuf", "mcap"])
def test_the_optional_packages_the_tests_need_are_installed(module: str) -> None:
    importlib.import_module(module)
