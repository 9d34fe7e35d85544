"""Shared test fixtures: where the real data of others lives, and skipping when it is absent."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

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


def write_dataset_manifest(folder: Path, classes: Mapping[str, Any], samples: Sequence[Mapping[str, Any]]) -> Path:
    """A ``manifest.json`` that passes the dataset schema, for tests that make a dataset folder by
    hand (label masks only): ``samples`` give at least ``name`` and ``ground_resolution_m``."""
    rows = [{"center": {}, "bbox_wgs84": [], "bounds_3857": [], "zoom": 18, "tiles": [], "imagery": {}, "osm": {},
             "class_histogram": {}, "files": {f"labels/{s['name']}.png": "0" * 64}, **s} for s in samples]
    manifest = {"format": "osmseg-dataset", "format_version": 1, "tool": {}, "command": "", "seed": 0, "area": {},
                "zoom": 18, "grid_size": len(rows), "filters": {}, "imagery": {}, "osm": {}, "rejected": [],
                "summary": {}, "classes": dict(classes), "samples": rows}
    path = Path(folder) / "manifest.json"
    path.write_text(json.dumps(manifest), encoding="utf-8")
    return path


# tests/data/*/data.py are generator scripts (run by hand), not test modules
collect_ignore_glob = ["data/*"]
