"""Shared fixtures: paths to the real data in ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("PRINTABILITY_SHARED_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The ../shared/data folder; tests that need it are skipped loudly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data folder not found at {SHARED_DATA}")
    return SHARED_DATA


def _hypothesis_profiles() -> None:
    """CI replays the same examples every run (a red CI names a real regression, not a new
    random draw); local runs keep exploring. Select with HYPOTHESIS_PROFILE."""
    from hypothesis import settings

    settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
    settings.register_profile("dev", deadline=None, print_blob=True)
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI")
                                         else "dev"))


_hypothesis_profiles()


@pytest.fixture(autouse=True)
def _no_postprocess_server(monkeypatch):
    """A ``printability serve`` the developer left running must not answer the tests' plug-in
    runs (its code may be older than the tree's): the plug-in runs locally unless a test
    points PRINTABILITY_SERVER at its own server."""
    monkeypatch.setenv("PRINTABILITY_SERVER", "off")
