"""Shared test fixtures: where the real data of others lives, and skipping when it is absent."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"
TEST_DATA = Path(__file__).resolve().parent / "data"

pytest_plugins = ["servers"]  # the http_server fixture: a scripted HTTP server on 127.0.0.1


def shared_path(*parts: str) -> Path:
    """Path inside ../shared/data, skipping the calling test when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not available: {path} (../shared/data is absent on this machine)")
    return path


@pytest.fixture
def shared_data() -> Path:
    """Root of ../shared/data (real imagery and OSM extracts made by others)."""
    if not SHARED_DATA.exists():
        pytest.skip("../shared/data is absent on this machine")
    return SHARED_DATA

# tests/data/*/data.py are generator scripts (run by hand), not test modules
collect_ignore_glob = ["data/*"]
