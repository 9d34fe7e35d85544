"""``region.html``: the region search's map, opened as a user opens it, in headless Chromium.

* A view of the town found there: the page, with no network, shows the region as drawn, one
  circle per answer, the alternative and the truth, and says "here"; a view of a park town
  searched in the same town says "not found here" in the same box.
* The page is self-contained: no script or style sheet comes from elsewhere (read with the
  standard library's HTML parser); the basemap's tiles are its only outside addresses.
* The same search writes the same bytes.

Skipped, with how to install it, where no Chromium is installed (``.ci/run`` installs Debian's).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from test_loc_georender import lonlat
from test_region_null import region, towns, view  # noqa: F401  (towns: the fixture)

from localization.common.marks import TOP_K
from osmseg.cli.main import cli


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if (path := shutil.which(name)) is not None:
            return path
    pytest.skip("headless Chromium is not installed (Debian: apt-get install chromium)")


def browse(page: Path, profile: Path, *what: str) -> str:
    """Open ``page`` in headless Chromium with no network (its flags as this machine's own probe
    runs it), let its scripts run, and return what it printed (``--dump-dom``: the page's DOM)."""
    args = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}", "--virtual-time-budget=3000", *what, page.as_uri()]
    done = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


class Elements(HTMLParser):
    """Every start tag of a page, with its attributes."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, {k: v or "" for k, v in attrs}))

    def with_class(self, name: str) -> list[dict[str, str]]:
        return [a for _, a in self.tags if name in a.get("class", "").split()]


def search(query: np.ndarray, osm: Path, out: Path, truth: tuple[float, float] | None = None) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(query.astype(np.uint8)).save(out / "query.png")
    w, s, e, n = region().bbox
    args = ["localize-region", "--ground", str(out / "query.png"), "--ground-landmarks", "aerial13",
            "--ground-table", "classes13.toml", "--osm", str(osm), "--bbox", f"{w},{s},{e},{n}", "--heading", "0",
            "--out", str(out), "--cache-dir", str(out.parent / "cache")]
    if truth is not None:
        args += ["--truth", f"{truth[0]},{truth[1]}"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "region.html" in result.stderr.splitlines()[-1]  # "written: region.geojson, region.png, region.html in"
    return json.loads((out / "region.geojson").read_text())


def test_the_map_opens_offline_with_every_answer_and_says_here_or_not_found_here(
        towns: tuple[Path, Path], tmp_path: Path) -> None:
    here, park = towns
    truth = lonlat(10.0, -25.0)
    doc = search(view(here, (10.0, -25.0)), here, tmp_path / "found", truth)
    page = tmp_path / "found" / "region.html"
    text = page.read_text()
    parsed = Elements(text)
    assert not [a for t, a in parsed.tags if t == "script" and a.get("src")], "a script is linked, not written in"
    assert not [a for t, a in parsed.tags if t == "link" and a.get("href")], "a style sheet is linked, not written in"
    dom = Elements(browse(page, tmp_path / "profile", "--dump-dom"))  # after Leaflet ran
    circles = dom.with_class("leaflet-interactive")
    assert len(circles) == len(doc["features"]) + 1  # the answers, the alternative and the truth
    assert len(dom.with_class("leaflet-image-layer")) == 1  # the region as drawn
    verdict = [a for t, a in dom.tags if a.get("id") == "osmseg-verdict"]
    assert [a["data-verdict"] for a in verdict] == [doc["properties"]["verdict"]] == ["here"]
    shot = tmp_path / "found.png"
    browse(page, tmp_path / "profile", f"--screenshot={shot}", "--window-size=900,700")
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    green = np.array([int(TOP_K[i:i + 2], 16) for i in (1, 3, 5)])
    assert (np.abs(pixels - green).max(axis=1) <= 8).sum() >= 20  # the answers' circles are drawn
    assert len(np.unique(pixels, axis=0)) > 50  # the region's classes, the controls, the legend: not a blank page
    # a view of the park town searched here: the same box says so
    elsewhere = search(view(park, (0.0, -60.0)), here, tmp_path / "park")
    other = Elements(browse(tmp_path / "park" / "region.html", tmp_path / "profile", "--dump-dom"))
    said = [a["data-verdict"] for t, a in other.tags if a.get("id") == "osmseg-verdict"]
    assert said == [elsewhere["properties"]["verdict"]] == ["not found here"]
    # the same search, the same bytes
    search(view(here, (10.0, -25.0)), here, tmp_path / "found", truth)
    assert page.read_text() == text
