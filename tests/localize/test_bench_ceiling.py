"""``benchmarks/bench_ceiling.py``: each view of a localize-bench run sorted into right, lost by the
search, a tie, or a look-alike that fits better, from scores it computes again (a constructed town)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from conftest import REPO_ROOT
from PIL import Image
from test_loc_render import RES, TABLE, town

from localization.bench.rendered import BenchConfig, Scene, run_bench
from localization.profile.search import ProfileConfig

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))


def test_every_view_is_sorted_by_its_own_scores_and_bad_folders_are_refused(tmp_path, capsys) -> None:
    import bench_ceiling

    mask = tmp_path / "town.png"
    Image.fromarray(town()).save(mask)
    scene = Scene("town", town(), TABLE, RES)
    # a coarse search that keeps one place per level: some answers are lost by it
    config = BenchConfig(viewpoints=6, seed=3, margin_m=10.0, save_panoramas=6, methods=("profile",),
                         negatives=False, heading="unknown",
                         profile=ProfileConfig(min_confidence=-1.0, min_kappa=-1.0, keep=1, coarse_m=12.0))
    results = run_bench([scene], config, tmp_path / "bench", plots=False)
    out = bench_ceiling.main([str(tmp_path / "bench"), str(mask), "--resolution", str(RES), "--right", "5"])
    assert out["views"] == 6 and sum(out["shares"].values()) == pytest.approx(1.0)
    errors = {v["index"]: v["error"] for v in results["viewpoints"]}
    for row in out["rows"]:   # the answer is the bench's own, and its kind follows its scores
        assert row["error_m"] == pytest.approx(errors[row["index"]], abs=0.01)
        if row["kind"] == "right":
            assert row["error_m"] <= 5
        elif row["kind"] == "lost by the search":
            assert row["best_near_truth"] > row["answer_score"]
        else:
            assert row["best_near_truth"] <= row["answer_score"] + 1e-4
    right = out["shares"]["right"]
    assert out["ceiling"] == pytest.approx(right + out["shares"]["lost by the search"])
    assert np.isclose(right, np.mean([e is not None and e <= 5 for e in errors.values()]))
    assert "ceiling (a perfect search)" in capsys.readouterr().out
    assert out["shares"]["lost by the search"] >= 0.5   # one place kept from a 12 m grid loses most views
    # the default search finds them: the ceiling is the scores', whatever the search
    default = BenchConfig(viewpoints=6, seed=3, margin_m=10.0, save_panoramas=6, methods=("profile",),
                          negatives=False, heading="unknown")
    run_bench([scene], default, tmp_path / "found", plots=False)
    found = bench_ceiling.main([str(tmp_path / "found"), str(mask), "--resolution", str(RES), "--right", "5"])
    assert found["shares"]["right"] > out["shares"]["right"] and found["ceiling"] == out["ceiling"]
    # a view that shows none of the landmark classes (here nothing at all) has no answer: it is counted
    # apart, in no other kind and not in the ceiling (it once stopped the whole run)
    blank = tmp_path / "found" / "panoramas" / "0000_town.png"
    Image.fromarray(np.zeros_like(np.asarray(Image.open(blank)))).save(blank)
    unread = bench_ceiling.main([str(tmp_path / "found"), str(mask), "--resolution", str(RES), "--right", "5"])
    kinds = {row["index"]: row["kind"] for row in unread["rows"]}
    before = {row["index"]: row["kind"] for row in found["rows"]}
    assert kinds[0] == "nothing to read" and unread["shares"]["nothing to read"] == pytest.approx(1 / 6, abs=1e-3)
    assert sum(unread["shares"].values()) == pytest.approx(1.0, abs=5e-3)   # each share rounded
    counted = before[0] in ("right", "lost by the search")
    assert unread["ceiling"] == pytest.approx(found["ceiling"] - counted / 6, abs=1e-3)
    assert all(kinds[i] == before[i] for i in kinds if i != 0)
    (tmp_path / "bench" / "panoramas" / "0005_town.png").unlink()
    with pytest.raises(SystemExit) as exit_:
        bench_ceiling.main([str(tmp_path / "bench"), str(mask), "--resolution", str(RES)])
    assert exit_.value.code == 2 and "--save-panoramas 6" in capsys.readouterr().err
