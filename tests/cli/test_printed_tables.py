"""Every table a command prints has one label over each column (issue 31).

The commands run for real: ``localize-bench`` on the demo's dataset, ``localize-pairs`` on
annotated pairs, ``eval`` (its summary and its metrics.txt) on a tiny trained model. Each table
is read as a person reads it (:func:`conftest.table_rows`): cells apart by two spaces or more,
as many values as labels in every row, each label over its value; and the value under a label
is the number results.json or metrics.json holds for it. (``osmseg localize``'s top-k and a
region search's answers are read the same way in tests/localize/test_loc_match.py and
tests/localize/test_loc_georender.py.)
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TEST_DATA, table_after, table_rows
from test_loc_pairs import write_pairs

from osmseg.cli.main import cli
from osmseg.units import column, metres, number


@pytest.fixture(scope="module")
def demo_dataset(demo_run: Path) -> Path:
    """The dataset ``osmseg demo`` builds (conftest's ``demo_run``, made once for the session)."""
    return demo_run / "demo" / "dataset"


def check_method_tables(printed: str, results: dict, unit: str) -> None:
    """The two tables of the methods side by side: errors, then confidence, a row per method."""
    methods = results["methods"]
    radii = sorted(next(iter(methods.values()))["recall_at"], key=float)  # results.json sorts its keys as text
    errors = table_after(printed, ["method", "answered"], len(methods))
    assert list(errors[0]) == ["method", "answered", f"median {unit}", f"mean {unit}", *(f"@{r} {unit}" for r in radii),
                               "heading error °", "s/view"]
    confidence = table_after(printed, ["method", "match/other AUC"], len(methods))
    assert list(confidence[0]) == ["method", "match/other AUC", "right/wrong AUC", "threshold", "accepted",
                                   "of them wrong"]
    per_view = column([m["localize_mean_s"] for m in methods.values()], "s")
    assert len({len(row["s/view"].split(".")[-1]) for row in errors}) == 1, errors  # one precision in the column
    for (name, m), row, conf, seconds in zip(methods.items(), errors, confidence, per_view):
        assert row["method"] == conf["method"] == name
        assert row["answered"] == f"{m['answered']}/{m['n']}"
        assert row[f"median {unit}"] == number(m["median_error"], unit)
        assert row[f"mean {unit}"] == number(m["mean_error"], unit)
        assert [row[f"@{r} {unit}"] for r in radii] == [number(m["recall_at"][r], "ratio") for r in radii]
        assert row["s/view"] == seconds and float(seconds) == pytest.approx(m["localize_mean_s"], rel=0.01)
        assert conf["match/other AUC"] == number(m["roc_auc"], "ratio")
        assert conf["right/wrong AUC"] == number(m.get("right_wrong_auc"), "ratio")
        assert conf["accepted"] == number(m.get("accepted"), "ratio")
        assert conf["of them wrong"] == number(m.get("false_accept"), "ratio")


def test_localize_bench_prints_the_methods_one_label_per_column(demo_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["localize-bench", str(demo_dataset), "--viewpoints", "3", "--methods",
                                      "paper,profile", "--no-plots", "--out", str(out)])
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == {"paper", "profile"}
    check_method_tables(result.stderr, results, "m")
    profile = results["methods"]["profile"]
    assert table_after(result.stderr, ["method", "threshold"], 2)[1]["threshold"] == f"{profile['threshold']:g}"


def test_localize_bench_says_its_counts_and_the_candidate_baseline_in_words(demo_dataset: Path, tmp_path: Path) -> None:
    """One view is '1 rendered panorama', the one subset of 4 classes '(1 subset)' (they said '1
    rendered panoramas', '1 subsets'); the paper method's random-candidate baseline says what it is
    beside the method's own median (it said 'paper method, a random candidate: median ...')."""
    out = tmp_path / "bench"
    result = CliRunner().invoke(cli, ["--no-progress", "localize-bench", str(demo_dataset), "--viewpoints", "1", "--methods",
                                      "paper,profile", "--no-plots", "--out", str(out)])
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    lines = result.stderr.splitlines()
    assert lines[0].startswith("1 rendered panorama, classes ")
    assert any(line.strip().startswith("4 classes (1 subset): ") for line in lines), lines
    assert any(line.strip().startswith("2 classes (6 subsets): ") for line in lines), lines
    baseline = results["baselines"]["random_candidate_median"]
    assert baseline is not None
    assert (f"baseline of the paper method, one of its own candidates taken at random: median error "
            f"{metres(baseline)} (the method's answers: {metres(results['methods']['paper']['median_error'])})") in lines


def test_localize_pairs_without_truth_makes_up_no_centre_baseline(tmp_path: Path) -> None:
    """Without truth.csv a pair's truth is its aerial image's centre: guessing the centre is no
    baseline there (it would score 0), so the summary leaves it out and says why."""
    for truth, out in ((False, tmp_path / "guessed"), (True, tmp_path / "known")):
        folder = write_pairs(tmp_path / f"pairs-{truth}", truth=truth)
        result = CliRunner().invoke(cli, ["localize-pairs", str(folder), "--methods", "paper", "--no-plots",
                                          "--out", str(out)])
        assert result.exit_code == 0, result.output
        results = json.loads((out / "results.json").read_text())
        check_method_tables(result.stderr, results, "px")
        guesses = next(line for line in result.stderr.splitlines() if "blind guesses" in line)
        if truth:
            centre = results["baselines"]["centre_guess_mean"]
            assert centre > 100 and f"image centre {number(centre, 'px')} px" in guesses
        else:
            assert results["baselines"]["centre_guess_mean"] is None
            assert "image centre 0" not in guesses and "without truth.csv" in guesses, guesses
        # and errors.png draws the centre's guess only where it is one
        from localization.bench.plots import draw_errors
        from osmseg.output.plotting import figure

        with figure(6.5, 4.8) as fig:
            draw_errors(fig, results)
            legend = [t.get_text() for legend in fig.legends for t in legend.get_texts()]  # under the axes
        assert ("guess the image centre" in legend) == truth, legend


def test_eval_prints_and_writes_one_label_per_column(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    data = TEST_DATA / "tinyseg"
    trained = CliRunner().invoke(cli, ["-q", "train", str(data), "--out", str(tmp_path / "run"), "--config",
                                       str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"])
    assert trained.exit_code == 0, trained.output
    result = CliRunner().invoke(cli, ["eval", str(tmp_path / "run" / "best.pt"), str(data), "--out",
                                      str(tmp_path / "eval")])
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    by_id = sorted(metrics["per_class"].items(), key=lambda kv: kv[1]["id"])  # metrics.json sorts its keys as text
    scored = {name: c for name, c in by_id if not c.get("ignored")}
    ignored = [name for name, _ in by_id if name not in scored]
    assert ignored == ["unlabeled"]  # tinyseg's gaps: named under the table, not a row without values
    for printed in (result.stderr, (tmp_path / "eval" / "metrics.txt").read_text()):
        lines = printed.splitlines()
        head = next(i for i, line in enumerate(lines) if line.startswith("class "))
        assert set(lines[head + 1]) == {"-"}, "a rule under the labels"
        rows = table_rows([lines[head], *lines[head + 2:head + 2 + len(scored)]])
        assert set(lines[head + 2 + len(scored)]) == {"-"}, "a rule under the rows"
        assert list(rows[0]) == ["class", "IoU", "precision", "recall", "F1", "support"]
        for row, (name, c) in zip(rows, scored.items()):
            assert row["class"] == name and row["support"] == f"{c['support']:,}"
            assert [row[k] for k in ("IoU", "precision", "recall", "F1")] == [
                number(c[k], "ratio") for k in ("iou", "precision", "recall", "f1")]
        assert "not scored: unlabeled" in lines[head + 3 + len(scored)]
