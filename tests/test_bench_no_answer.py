"""``localize-bench`` where a method answers nothing: the README's Kampala dataset (real drone
tiles and OSM building footprints, one class), panoramas standing on unlabeled ground.

The paper method answers none of the views there. What a user checks: it gets no ROC AUC
(results.json ``null``, ``-`` in the printed table, "no answered view" on confidence.png)
rather than the 0.5 its tied stand-in confidences made; and nothing of matplotlib's (a warning
about an empty legend) reaches stderr. Skipped without ``../shared/data``.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import SHARED_DATA, shared_path, table_after
from test_readme_chain import BUILD_MARK, sh_blocks

from osmseg.output.plotting import figure

pytestmark = pytest.mark.shared_data


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
