"""``localize-bench`` where a method answers nothing: the README's Kampala dataset (real drone
tiles and OSM building footprints, one class), panoramas standing on unlabeled ground.

The paper method answers none of the views there. What a user checks: it gets no ROC AUC
(results.json ``null``, ``-`` in the printed table, "no answered view" on confidence.png)
rather than the 0.5 its tied stand-in confidences made; nothing of matplotlib's (a warning
about an empty legend) reaches stderr; and the views' pictures name every colour they draw,
the map's black unlabeled ground and the panorama's sky among them. Skipped without
``../shared/data``.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import SHARED_DATA, shared_path, table_after
from PIL import Image
from test_readme_chain import BUILD_MARK, sh_blocks

from localization.common.landmarks import panorama_table
from osmseg.output.plotting import figure

pytestmark = pytest.mark.shared_data
WHITE = 250  # lighter than this, in every channel, is the page


def osmseg(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``osmseg ARGS`` as its own process, as a user runs it (stderr captured)."""
    env = {**os.environ, "OSMSEG_CACHE_DIR": str(cwd / "cache")}
    return subprocess.run([os.path.abspath(sys.executable), "-m", "osmseg", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The README's Kampala build, then ``localize-bench --stand-on unlabeled --viewpoints 4``
    with pictures of the first view: (its output folder, its stderr)."""
    shared_path("kampala-oam", "tiles")
    work = tmp_path_factory.mktemp("kampala")
    build = next(c for block in sh_blocks() for c in block if c.startswith("osmseg build") and BUILD_MARK in c)
    args = [a.replace("/data/", f"{SHARED_DATA}/") for a in shlex.split(build)][1:]
    built = osmseg(["-q", *args], work)
    assert built.returncode == 0, built.stderr
    done = osmseg(["localize-bench", "data/kampala", "--stand-on", "unlabeled", "--viewpoints", "4",
                   "--pictures", "1", "--out", "b/"], work)
    assert done.returncode == 0, done.stderr
    return work / "b", done.stderr


def test_a_method_that_answered_no_view_has_no_auc(bench: tuple[Path, str]) -> None:
    out, stderr = bench
    results = json.loads((out / "results.json").read_text())
    paper, profile = results["methods"]["paper"], results["methods"]["profile"]
    assert paper["answered"] == 0 and paper["n"] == 4  # the reporter's case: 0 of 4 views
    assert paper["roc_auc"] is None  # was 0.5: four ties of "unanswered" against four
    assert profile["answered"] > 0 and profile["roc_auc"] is not None
    rows = {row["method"]: row for row in table_after(stderr, ["method", "match/other AUC"], 2)}
    assert rows["paper"]["match/other AUC"] == "-"


def test_no_matplotlib_warning_reaches_stderr(bench: tuple[Path, str]) -> None:
    _, stderr = bench
    assert "Warning" not in stderr and "plots.py" not in stderr, stderr


def test_confidence_png_says_no_answered_view_and_draws_no_empty_legend(bench: tuple[Path, str]) -> None:
    from localization.bench.plots import PAIRS, draw_confidence

    out, _ = bench
    results: Any = json.loads((out / "results.json").read_text())
    assert (out / "confidence.png").is_file()
    with figure(8.8, 4.0) as fig:
        assert draw_confidence(fig, results)
        fig.canvas.draw()
        titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
        assert "landmark graphs (MAP): no answered view" in titles, titles
        assert not [t for t in titles if "MAP" in t and "AUC" in t], titles
        assert all(ax.get_legend() is None for ax in fig.axes)  # the empty legend box was the paper panel's
        # one legend, of what the profile method's histograms drew, under the panels
        assert [[t.get_text() for t in legend.get_texts()] for legend in fig.legends] == [[p[1] for p in PAIRS]]


def _legend(path: Path) -> np.ndarray:
    """The rows of a view picture under its axes: its legend."""
    with Image.open(path) as im:
        pixels = np.asarray(im.convert("RGB"))
    page = (pixels >= WHITE).all(axis=2).mean(axis=1) > 0.5  # rows that are mostly page
    return pixels[int(np.flatnonzero(~page).max()) + 1:]


def _swatches(region: np.ndarray, rgb: tuple[int, int, int], h: int = 6, w: int = 12) -> int:
    """Places where ``region`` holds an ``h`` x ``w`` block of colour ``rgb`` (a legend swatch;
    text, even black, is never that solid)."""
    same = (np.abs(region.astype(int) - np.array(rgb)).max(axis=2) <= 3).astype(int)
    sums = np.pad(same.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    blocks = sums[h:, w:] - sums[:-h, w:] - sums[h:, :-w] + sums[:-h, :-w]
    return int((blocks == h * w).sum())


def test_the_views_legends_name_unlabeled_ground_and_sky(bench: tuple[Path, str]) -> None:
    """The map drew the unlabeled ground black, the panorama its sky light blue (near footway's
    colour), and neither legend said what they were."""
    out, _ = bench
    views = out / "views"
    (map_png,) = views.glob("*_map.png")
    (panorama_png,) = views.glob("*_panorama.png")
    assert _swatches(_legend(map_png), (0, 0, 0)) > 0  # unlabeled: classes13's black
    panorama = _legend(panorama_png)
    assert _swatches(panorama, (0, 0, 0)) > 0  # the ground it stands on, unlabeled too
    assert _swatches(panorama, panorama_table("classes13.toml").by_name["sky"].color) > 0
