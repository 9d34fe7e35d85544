"""The figures README.md and docs/*.md quote from a command cannot drift from what it prints.

``docs/figures.py`` (``make docs-figures``) measures every figure between ``<!-- fig KEY -->``
markers again and writes it in. Here the cheap sets run again, as that script runs them (the
commands in a temporary folder, with this checkout's code), and every figure they give must be
what the docs say (timings masked); the expensive sets are only checked for their markers.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT

sys.path.insert(0, str(REPO_ROOT / "docs"))
import figure_sets
import figures


def test_every_marker_is_closed_and_names_a_set() -> None:
    seen = set()
    for path in figures.DOCUMENTS:
        for key, text in figures.markers(path.read_text(encoding="utf-8")):
            assert key.split(".")[0] in figures.SETS, f"{path.name}: {key} names no figure set"
            assert text.strip(), f"{path.name}: {key} is empty"
            seen.add(key.split(".")[0])
    assert seen == set(figures.SETS), f"sets whose figures no document shows: {set(figures.SETS) - seen}"


def test_the_headline_figures_of_the_issue_are_markers() -> None:
    """The figures issue 18 found typed by hand (116.4 m, 0.44 m, 0.80, 0.985) are measured ones now."""
    readme = (REPO_ROOT / "README.md").read_text(encoding="utf-8")
    for key in ("demo40.paper.median", "demo40.paper.answered", "demo40.profile.median", "demo40.profile.recall10",
                "demo40.profile.auc"):
        assert f"<!-- fig {key} -->" in readme, key


@pytest.mark.slow  # make test-slow: the demo build and a 40-view bench in subprocesses
def test_the_cheap_figures_are_what_the_docs_say(tmp_path: Path) -> None:
    cheap = [name for name, s in figures.SETS.items() if s.cost == "cheap"]
    measured = figures.measure(cheap, figures.Workspace(tmp_path), say=lambda line: None)
    assert {"zoom.span", "demo40.profile.median", "demo40.transcript"} <= set(measured)
    problems = figures.differences(measured)
    assert problems == [], "the docs differ from what the commands print now; run `make docs-figures`:\n" + \
        "\n".join(problems)


def test_a_figure_that_drifted_is_reported_and_rewritten(tmp_path: Path) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("median <!-- fig demo40.profile.median -->0.44 m<!-- /fig --> (was typed)\n"
                   "<!-- fig demo40.transcript -->\n```\nprofile 0.32 9.999\n```\n<!-- /fig -->\n", encoding="utf-8")
    measured = {"demo40.profile.median": figures.Figure("0.32 m"),
                "demo40.transcript": figures.Figure("\n```\nprofile 0.32 0.188\n```\n", figure_sets.TIMING_COLUMN)}
    problems = figures.differences(measured, [doc])
    assert len(problems) == 1 and "0.44 m" in problems[0] and "0.32 m" in problems[0]  # the timing is not a drift
    rewritten = figures.write_in(measured, [doc])[doc]
    assert "<!-- fig demo40.profile.median -->0.32 m<!-- /fig -->" in rewritten and "0.188" in rewritten
    doc.write_text(rewritten, encoding="utf-8")
    assert figures.differences(measured, [doc]) == []


def test_a_broken_marker_is_an_error() -> None:
    with pytest.raises(ValueError, match="not closed"):
        figures.markers("a <!-- fig demo40.profile.median -->0.32 m and no end")
