"""Matching landmark graphs (localization.paper.match, .refine, .result), its pictures and the ``osmseg localize`` command.

Scenes are built here, small and seeded: hand-checkable cliques (the dissertation's Figure
3.1), and landmark layouts whose answer is known by construction (an isolated plaza, blocks
of distinct composition seen from a panorama, twin blocks told apart only by their
surroundings).
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import table_rows, write_dataset_manifest
from PIL import Image

from localization.cli.localize import localize_command
from localization.common.figures import CANDIDATE, TOP_K, TRUTH, _segments, graph_png, localization_png
from localization.common.landmarks import Landmarks
from localization.paper.config import PaperConfig
from localization.paper.edges import feature_edge_mask
from localization.paper.graph import cliques_fast
from localization.paper.match import (
    DEFAULT_P,
    aerial_graph,
    class_adjacency,
    extend_cliques,
    inverted_index,
    likelihood,
    localize,
    match_cliques,
    posteriors,
    rank,
    relevant_cliques,
)
from localization.paper.refine import inherit, localize_hierarchical
from osmseg.classes import load_class_table
from osmseg.errors import ConfigError

NAMES = ("building", "road", "vegetation", "footway")
B, R, V, F = range(4)

# --------------------------------------------------------------------------- Figure 3.1

# The dissertation's worked example: six landmarks, cliques C1 = {l1, l2, l4}, C2 = {l2, l3, l4},
# C3 = {l4, l5, l6}. Their union has 8 distinct edges: 12, 14, 24 (C1), 23, 34 (C2; 24 again),
# 45, 46, 56 (C3). The issue gives W[blue, green] = 2/8 = 0.25: exactly two of those edges
# join a blue and a green landmark. The figure's colours are not in the issue, so we take an
# assignment with three colours that gives exactly that count:
#   l1 blue, l2 green, l3 green, l4 red, l5 blue, l6 green
# blue-green edges: 12 and 56 (2 of 8); blue-red: 14, 45; green-red: 24, 34, 46; green-green: 23.
FIG_CLASSES = ("blue", "green", "red")
FIG_CLS = np.array([0, 1, 1, 2, 0, 1])
FIG_CLIQUES = np.array([[1, 1, 0, 1, 0, 0],
                        [0, 1, 1, 1, 0, 0],
                        [0, 0, 0, 1, 1, 1]], dtype=bool)


def figure_landmarks() -> Landmarks:
    xy = np.array([[10.0, 10], [20, 10], [30, 10], [20, 20], [30, 30], [40, 30]])
    return Landmarks(xy, FIG_CLS, FIG_CLASSES, 50, 50)


def test_figure_3_1_class_adjacency_of_the_whole_graph() -> None:
    w = class_adjacency(FIG_CLIQUES, figure_landmarks())
    assert w[0, 1] == w[1, 0] == pytest.approx(2 / 8)  # W_blue,green = 0.25
    expected = np.array([[0, 2, 2], [2, 1, 3], [2, 3, 0]]) / 8  # counts over i < j, mirrored
    np.testing.assert_allclose(w, expected)
    assert np.tril(w).sum() == pytest.approx(1.0)  # the lower triangle holds every edge once


def test_figure_3_1_extension_with_p_one_half() -> None:
    # |C1 ⊙ C2|0 / |C1|0 = 2/3 >= 0.5: C1 extends with C2; |C1 ⊙ C3|0 / |C1|0 = 1/3: C3 stays apart
    assert [e.tolist() for e in extend_cliques(FIG_CLIQUES, np.array([0, 1, 2]), 0.5)] == [[0, 1], [0, 1], [2]]
    # ">=" as in the authors' code: an overlap of exactly p still extends
    assert extend_cliques(FIG_CLIQUES, np.array([0]), 2 / 3)[0].tolist() == [0, 1]
    assert extend_cliques(FIG_CLIQUES, np.array([0]), 0.7)[0].tolist() == [0]


def test_figure_3_1_candidate_graph_is_the_union_of_its_cliques() -> None:
    # C1 extended with C2: edges 12, 14, 24, 23, 34. l1 and l3 share no clique, so no edge 13
    # (the complete graph on {l1..l4} would have 6 edges).
    w = class_adjacency(FIG_CLIQUES[[0, 1]], figure_landmarks())
    # blue-green 12, blue-red 14, green-red 24 and 34, green-green 23: five edges
    np.testing.assert_allclose(w, np.array([[0, 1, 1], [1, 1, 2], [1, 2, 0]]) / 5)


def test_figure_3_1_relevant_cliques_by_inverted_index() -> None:
    index = inverted_index(FIG_CLIQUES, FIG_CLS, 3)
    assert [ix.tolist() for ix in index] == [[0, 2], [0, 1, 2], [0, 1, 2]]
    assert relevant_cliques(index, [0, 2]).tolist() == [0, 2]  # blue and red: C1 and C3
    assert relevant_cliques(index, [0, 1, 2]).tolist() == [0, 2]


def test_class_adjacency_of_too_few_landmarks_is_zero() -> None:
    lm = figure_landmarks()
    one = np.zeros(6, dtype=bool)
    one[3] = True
    assert not class_adjacency(one, lm).any()


def test_feature_edge_removal_drops_edges_between_look_alike_landmarks() -> None:
    # l2 and l3 (both green, in C2) look alike: their edge goes, the other 7 stay
    features = np.array([[0.0, 9], [4, 0], [4, 0.2], [9, 9], [0, 0], [9, 0]])
    drop = feature_edge_mask(features, threshold=1.0)
    assert np.argwhere(np.triu(drop)).tolist() == [[1, 2]]
    w = class_adjacency(FIG_CLIQUES, figure_landmarks(), drop=drop)
    np.testing.assert_allclose(w, np.array([[0, 2, 2], [2, 0, 3], [2, 3, 0]]) / 7)
    # all principal components: a rotation, same distances; cosine looks at directions only
    assert (feature_edge_mask(features, 1.0, reduce="pca", components=2) == drop).all()
    cosine = feature_edge_mask(np.array([[1.0, 0], [10, 0.5], [0, 1]]), 0.01, metric="cosine")
    assert np.argwhere(np.triu(cosine)).tolist() == [[0, 1]]
    with pytest.raises(ConfigError):
        feature_edge_mask(features, 1.0, metric="manhattan")
    with pytest.raises(ConfigError):
        class_adjacency(FIG_CLIQUES, figure_landmarks(), drop=np.zeros((2, 2), bool))


def test_feature_edge_removal_reaches_the_localization() -> None:
    aerial, centres = blocks_scene()
    query = panorama(aerial, centres["park"], 60)
    rng = np.random.default_rng(0)
    same = np.zeros((len(aerial), 4))  # every aerial landmark looks the same: no edge is left
    gone = localize(aerial, query, PaperConfig(window=60), aerial_drop=feature_edge_mask(same, 0.5))
    assert gone.unanswered and "no candidate's graph has an edge" in gone.reason
    apart = rng.normal(size=(len(aerial), 4)) * 100  # all look different: nothing changes
    kept = localize(aerial, query, PaperConfig(window=60), aerial_drop=feature_edge_mask(apart, 0.5))
    np.testing.assert_allclose(kept.posteriors, localize(aerial, query, PaperConfig(window=60)).posteriors)


# --------------------------------------------------------------------------- likelihood and posterior


def test_likelihood_is_one_for_identical_and_lower_for_permuted_classes() -> None:
    w = class_adjacency(FIG_CLIQUES, figure_landmarks())
    assert likelihood(w, w) == pytest.approx(1.0)
    assert likelihood(w, 3 * w) == pytest.approx(1.0)  # normalised: scale does not matter
    perm = [2, 0, 1]
    permuted = w[np.ix_(perm, perm)]
    assert 0.0 < likelihood(w, permuted) < 1.0
    # eq. 3.3 by hand on the lower triangles (diagonal included)
    low = np.tril_indices(3)
    a, b = w[low], permuted[low]
    assert likelihood(w, permuted) == pytest.approx(a @ b / math.sqrt((a @ a) * (b @ b)))


def test_likelihood_degenerate_and_bad_shapes() -> None:
    w = class_adjacency(FIG_CLIQUES, figure_landmarks())
    assert likelihood(w, np.zeros((3, 3))) == 0.0
    assert likelihood(np.zeros((3, 3)), np.zeros((3, 3))) == 0.0
    with pytest.raises(ConfigError):
        likelihood(w, np.zeros((2, 2)))


def test_posteriors_against_hand_computed_values() -> None:
    lik = np.array([0.9, 0.5, 0.1])
    # P(L)=1/3; P(Z|¬L_k) = mean of the others: 0.3, 0.5, 0.7
    # k=0: 0.3 / (0.3 + 0.3*2/3) = 0.6;  k=1: (0.5/3) / (0.5/3 + 0.5*2/3) = 1/3;
    # k=2: (0.1/3) / (0.1/3 + 0.7*2/3) = 1/15
    np.testing.assert_allclose(posteriors(lik), [0.6, 1 / 3, 1 / 15])
    literal = []
    for k in range(3):  # eq. 3.6 written out
        others = np.mean(np.delete(lik, k))
        literal.append(lik[k] / 3 / (lik[k] / 3 + others * (2 / 3)))
    np.testing.assert_allclose(posteriors(lik), literal)
    assert posteriors(np.array([0.4])).tolist() == [1.0]
    assert posteriors(np.array([0.0, 0.0])).tolist() == [0.0, 0.0]


def test_rank_counts_ties_within_tolerance_and_breaks_them_deterministically() -> None:
    scores = np.array([0.2, 0.7, 0.7 * (1 + 1e-12), 0.7])
    centers = np.array([[0.0, 0], [50, 10], [40, 10], [10, 20]])
    order, ties = rank(scores, centers)
    assert ties == 3
    assert order.tolist() == [2, 1, 3, 0]  # tied: raster order (y, then x)
    order, _ = rank(scores, centers, second=np.array([0.0, 0.1, 0.1, 0.9]))
    assert order.tolist() == [3, 2, 1, 0]  # tied: the better own clique first


def test_inherit_takes_the_best_containing_coarse_window() -> None:
    fine = np.array([[10.0, 10], [30, 30], [200, 200]])
    coarse = np.array([[0.0, 0], [20, 20]])
    np.testing.assert_allclose(inherit(fine, coarse, np.array([0.9, 0.3]), 40), [0.9, 0.3, 0.0])


# --------------------------------------------------------------------------- scenes


def random_scene(seed: int, n: int = 80, size: int = 300) -> Landmarks:
    rng = np.random.default_rng(seed)
    return Landmarks(rng.uniform(0, size, (n, 2)), rng.integers(0, 4, n), NAMES, size, size)


def crop(lm: Landmarks, center: tuple[float, float], w: int) -> Landmarks:
    """The landmarks of the (w+1)-px square around ``center``, as the aerial crop seen there."""
    c = np.asarray(center, dtype=float)
    keep = np.all(np.abs(lm.xy - c) <= w / 2, axis=1)
    return Landmarks(lm.xy[keep] - c + w / 2, lm.cls[keep], lm.classes, w + 1, w + 1)


def panorama(lm: Landmarks, center: tuple[float, float], radius: float, width: int = 616,
             height: int = 112) -> Landmarks:
    """What a 360-degree camera at ``center`` sees within ``radius``: x = azimuth, y by class."""
    d = lm.xy - np.asarray(center, dtype=float)
    r = np.hypot(d[:, 0], d[:, 1])
    keep = (r <= radius) & (r > 0)
    azimuth = np.arctan2(d[keep, 1], d[keep, 0]) % (2 * np.pi)
    x = np.minimum(azimuth / (2 * np.pi) * width, width - 1e-6)
    y = np.where(lm.cls[keep] == B, height * 0.35, height * 0.7)
    return Landmarks(np.stack([x, y], axis=1), lm.cls[keep], lm.classes, width, height, panorama=True)


def plaza_scene(seed: int, center: tuple[int, int], w: int, isolated: bool) -> Landmarks:
    """Random landmarks plus a plaza at ``center``: footways exactly on the edges of the one
    w-window centred there (so that window's clique is produced by no other window), and a
    building, two roads and a tree inside. ``isolated`` keeps other landmarks more than w away."""
    rng = np.random.default_rng(seed)
    size = 400
    xy = rng.uniform(0, size, (120, 2))
    c = np.asarray(center, dtype=float)
    if isolated:
        xy = xy[np.max(np.abs(xy - c), axis=1) > 1.5 * w + 2]
    cls = rng.integers(0, 4, len(xy))
    d = w / 2
    plaza = c + np.array([[-d, 3], [d, -4], [5, -d], [-6, d], [-9, -7], [8, 6], [-5, 9], [10, -10]])
    plaza_cls = [F, F, F, F, B, R, R, V]
    return Landmarks(np.vstack([xy, plaza]), np.concatenate([cls, plaza_cls]), NAMES, size, size)


def test_isolated_plaza_is_found_exactly_and_its_ties_are_reported() -> None:
    w, p0 = 60, (250, 140)
    aerial = plaza_scene(1, p0, w, isolated=True)
    result = localize(aerial, crop(aerial, p0, w), PaperConfig(window=w, query_window=w))
    assert not result.unanswered
    assert result.map_xy == pytest.approx(p0)
    # every relevant sub-clique of the plaza extends to the whole plaza: all tie at likelihood 1,
    # and the tie is broken by how well the window's own clique matches (the full plaza: 1)
    assert result.ties > 1
    tied = result.order[:result.ties]
    np.testing.assert_allclose(result.likelihoods[tied], 1.0)
    assert result.clique_likelihoods[result.order[0]] == pytest.approx(1.0)
    assert np.all(np.max(np.abs(result.candidates[tied] - p0), axis=1) <= w)  # all in the plaza


def test_plaza_in_clutter_is_found_exactly_with_p_one() -> None:
    # With p = 1 a clique extends only with its supersets; the plaza window has none, so its
    # graph is exactly the query's.
    w, p0 = 60, (170, 220)
    aerial = plaza_scene(2, p0, w, isolated=False)
    result = localize(aerial, crop(aerial, p0, w), PaperConfig(window=w, query_window=w, p=1.0))
    assert result.map_xy == pytest.approx(p0)
    assert result.likelihoods[result.order[0]] == pytest.approx(1.0)
    assert len(result.candidates) > 20  # the clutter has candidates too, but they match worse


def blocks_scene() -> tuple[Landmarks, dict[str, tuple[int, int]]]:
    """Four isolated blocks of 3x3 landmarks (spacing 20 px), each with its own class mix."""
    mixes = {"offices": [B, B, R, B, R, B, F, B, V], "park": [V, V, F, V, V, F, B, V, R],
             "market": [F, F, B, F, R, F, V, F, B], "mixed": [B, R, V, F, R, V, B, F, R]}
    centres = {"offices": (80, 80), "park": (320, 90), "market": (90, 320), "mixed": (310, 300)}
    xy, cls = [], []
    for name, (cx, cy) in centres.items():
        for i, c in enumerate(mixes[name]):
            xy.append((cx + 20 * (i % 3 - 1), cy + 20 * (i // 3 - 1)))
            cls.append(c)
    return Landmarks(np.array(xy, float), np.array(cls), NAMES, 400, 400), centres


@pytest.mark.parametrize("name", ["offices", "park", "market", "mixed"])
def test_panorama_query_lands_in_the_right_block(name: str) -> None:
    aerial, centres = blocks_scene()
    truth = (centres[name][0] + 4, centres[name][1] - 3)  # off-centre viewpoint inside the block
    query = panorama(aerial, truth, radius=60)
    result = localize(aerial, query, PaperConfig(window=60))
    assert not result.unanswered
    error, _ = result.error(truth)
    assert error is not None and error <= 35  # inside the block (half-diagonal of a 60-px window: 42)
    assert len(result.candidates) > result.ties  # other blocks were candidates and lost


def twins_scene() -> Landmarks:
    """Two identical blocks; only their surroundings (a row of trees / of buildings 78 px below) differ."""
    block = [((-15, -15), F), ((15, -15), B), ((0, 0), R), ((-15, 15), V), ((15, 15), B), ((0, -15), R)]
    xy, cls = [], []
    for (cx, cy), around in (((120, 120), V), ((360, 360), B)):
        for (dx, dy), c in block:
            xy.append((cx + dx, cy + dy))
            cls.append(c)
        for dx in (-20, 0, 20):
            xy.append((cx + dx, cy + 78))
            cls.append(around)
    return Landmarks(np.array(xy, float), np.array(cls), NAMES, 480, 480)


def test_hierarchy_tells_twins_apart_by_their_surroundings() -> None:
    aerial, truth = twins_scene(), (360, 360)
    query = crop(aerial, truth, 160)  # sees the block and its row of buildings
    fine = localize(aerial, query, PaperConfig(window=60))
    assert fine.ties == 2  # the 60-px windows see identical blocks ...
    assert fine.error(truth)[0] > 200  # ... and raster order picks the wrong twin
    result = localize_hierarchical(aerial, query, PaperConfig(windows=(160, 60)))
    assert [lv.window for lv in result.levels] == [160, 60]
    assert result.window == 60 and result.ties == 1
    assert result.error(truth)[0] < 30
    # eq. 3.8: each fine candidate's score is its posterior times the best containing coarse one
    coarse, level = result.levels
    inherited = inherit(level.candidates, coarse.candidates, coarse.posteriors, coarse.window)
    np.testing.assert_allclose(result.posteriors, level.posteriors * inherited)


def test_vectorised_matching_equals_the_plain_formulas() -> None:
    aerial = random_scene(5)
    query = panorama(aerial, (150, 150), 70)
    w = 60
    cliques, qcliques = cliques_fast(aerial, w), cliques_fast(query, query.height)
    result = match_cliques(aerial, cliques, query, qcliques, PaperConfig(p=DEFAULT_P))
    query_w = class_adjacency(qcliques.members, query)
    extended = extend_cliques(cliques.members, result.relevant, DEFAULT_P)
    plain = [likelihood(query_w, class_adjacency(cliques.members[e], aerial)) for e in extended]
    np.testing.assert_allclose(result.likelihoods, plain, atol=1e-12)
    np.testing.assert_allclose(result.posteriors, posteriors(np.array(plain)), atol=1e-12)
    np.testing.assert_allclose(result.candidates, cliques.centers[result.relevant])


def test_a_graph_built_once_answers_many_queries_as_a_fresh_one_does() -> None:
    """An AerialGraph keeps each class set's candidates (a benchmark's views of one scene): every
    answer is the one a graph built for that query alone gives, to the bit."""
    aerial, centres = blocks_scene()
    config = PaperConfig(window=60)
    graph = aerial_graph(aerial, config)
    queries = [panorama(aerial, (cx + dx, cy), 60) for cx, cy in centres.values() for dx in (-4, 3)]
    queries += [queries[0].of_classes(("building", "road"))]  # another class set: its own entry
    for query in queries + queries[::-1]:  # the second time round, every class set is kept
        kept, fresh = localize(graph, query, config), localize(aerial_graph(aerial, config), query, config)
        assert kept.map_xy == fresh.map_xy and kept.ties == fresh.ties and kept.top_k == fresh.top_k
        assert np.array_equal(kept.posteriors, fresh.posteriors)
        assert np.array_equal(kept.likelihoods, fresh.likelihoods)
    assert len(graph.memo) == len({(tuple(sorted(set(q.cls.tolist()))), q.classes) for q in queries})


def test_reference_cliques_give_the_same_localization() -> None:
    aerial, centres = blocks_scene()
    query = panorama(aerial, centres["park"], 60)
    fast, slow = localize(aerial, query, PaperConfig(window=60)), localize(aerial, query, PaperConfig(window=60, fast=False))
    np.testing.assert_allclose(fast.posteriors, slow.posteriors)
    assert fast.top_k == slow.top_k


# --------------------------------------------------------------------------- unanswered and bad input


def test_unanswered_when_no_aerial_clique_holds_the_query_classes() -> None:
    aerial = random_scene(3)
    aerial = aerial.select(aerial.cls != F)
    query = crop(random_scene(3), (150, 150), 80)
    assert F in query.cls
    result = localize(aerial, query, PaperConfig(window=60))
    assert result.unanswered and "footway" in result.reason
    assert result.map_xy is None and result.ties == 0 and result.top_k == ()
    assert json.loads(json.dumps(result.to_dict()))["unanswered"] is True


def test_unanswered_for_empty_inputs_and_a_single_landmark() -> None:
    aerial = random_scene(4)
    empty = aerial.select(np.zeros(len(aerial), dtype=bool))
    assert localize(empty, aerial).unanswered
    assert "query has no landmarks" in localize(aerial, empty).reason
    one = aerial.select([0])
    assert "no edge" in localize(aerial, one, PaperConfig(window=50)).reason


def test_window_larger_than_the_image_gives_one_candidate() -> None:
    aerial = random_scene(6, size=200)
    result = localize(aerial, crop(aerial, (100, 100), 80), PaperConfig(window=500, query_window=80))
    assert len(result.candidates) == 1 and result.posteriors.tolist() == [1.0]


def test_bad_settings_are_config_errors() -> None:
    aerial = random_scene(7)
    for kwargs in ({"p": 0.0}, {"p": 1.5}, {"top_k": 0}, {"stride": 0}, {"window": 0}):
        with pytest.raises(ConfigError):
            localize(aerial, aerial, PaperConfig(**kwargs))
    with pytest.raises(ConfigError):
        localize_hierarchical(aerial, aerial, PaperConfig(windows=()))


def test_result_to_dict_is_json() -> None:
    aerial, centres = blocks_scene()
    result = localize_hierarchical(aerial, panorama(aerial, centres["market"], 60), PaperConfig(windows=(120, 60), top_k=3))
    data = json.loads(json.dumps(result.to_dict()))
    assert len(data["top_k"]) == 3 and data["top_k"][0]["rank"] == 1
    assert (data["map"]["x"], data["map"]["y"]) == result.map_xy
    assert len(data["candidates"]) == len(result.candidates) and len(data["levels"]) == 2


# --------------------------------------------------------------------------- pictures


def _colour_pixels(png: bytes, colour: str, tol: int = 40) -> int:
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    target = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(rgb - target).max(axis=2) <= tol).sum())


def test_localization_picture_shows_candidates_top_k_and_truth(tmp_path) -> None:
    aerial, centres = blocks_scene()
    truth = centres["park"]
    result = localize(aerial, panorama(aerial, truth, 60), PaperConfig(window=60))
    path = localization_png(tmp_path / "loc.png", result, aerial, truth=truth, resolution=0.5)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    for colour in (CANDIDATE, TOP_K, TRUTH):
        assert _colour_pixels(data, colour) > 20, colour
    again = localization_png(tmp_path / "again.png", result, aerial, truth=truth, resolution=0.5)
    assert again.read_bytes() == data  # deterministic
    assert not list(tmp_path.glob(".*.tmp"))
    with pytest.raises(ConfigError):
        localization_png(tmp_path / "bad.png", result, aerial, image=np.zeros((10, 10, 3), np.uint8))


def test_graph_picture_and_panorama_edges_across_the_seam(tmp_path) -> None:
    lm = Landmarks(np.array([[5.0, 50], [600.0, 50], [300.0, 60]]), np.array([B, V, R]), NAMES, 616, 112,
                   panorama=True)
    adj = np.array([[1, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=bool)
    segments = _segments(lm, adj)
    assert len(segments) == 2  # the 5 <-> 600 edge crosses the seam: drawn leaving right and entering left
    assert sorted(segments[:, :, 0].ravel().tolist()) == [-16.0, 5.0, 600.0, 621.0]  # 600 - 616, 5 + 616
    data = graph_png(tmp_path / "g.png", lm, adj).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert _colour_pixels(data, "#1f9e1f") > 10  # the vegetation landmark's colour


# --------------------------------------------------------------------------- command line


def write_landmarks(path, lm: Landmarks, labels: dict[int, str] | None = None) -> None:
    names = labels or dict(enumerate(lm.classes))
    path.write_text("".join(f"{x:.3f} {y:.3f} {names[c]}\n" for (x, y), c in zip(lm.xy, lm.cls)))


def run(*args: str):
    """``osmseg localize`` with the paper method (the default is the profile method)."""
    return CliRunner().invoke(localize_command, ["--method", "paper", *args])


def test_cli_with_landmark_files(tmp_path) -> None:
    aerial, centres = blocks_scene()
    truth = centres["offices"]
    write_landmarks(tmp_path / "aerial.txt", aerial)
    camvid = {B: "Building", R: "Road", V: "Tree", F: "Pavement"}  # the ground file in CamVid names
    write_landmarks(tmp_path / "ground.txt", panorama(aerial, truth, 60), camvid)
    out = tmp_path / "out"
    res = run("--aerial", str(tmp_path / "aerial.txt"), "--aerial-size", "400x400", "--aerial-landmarks",
              "landmarks-aerial13", "--ground", str(tmp_path / "ground.txt"), "--ground-size", "616x112",
              "--window", "60", "--truth", f"{truth[0]},{truth[1]}", "--aerial-resolution", "0.5", "--top-k", "3",
              "--json", "--out", str(out))
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert len(data["top_k"]) == 3
    assert data["truth"]["error_px"] <= 35 and data["truth"]["error_m"] == pytest.approx(data["truth"]["error_px"] / 2)
    for name in ("localization.png", "aerial_graph.png", "ground_graph.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    saved = json.loads((out / "result.json").read_text())
    assert saved["map"] == data["map"] and len(saved["candidates"]) == data["n_candidates"]
    table = run("--aerial", str(tmp_path / "aerial.txt"), "--aerial-size", "400x400",
                "--ground", str(tmp_path / "ground.txt"), "--ground-size", "616x112", "--window", "60")
    assert table.exit_code == 0
    rows = table_rows(table.stdout.splitlines())  # one label over each column
    assert list(rows[0]) == ["rank", "x", "y", "posterior", "likelihood"] and len(rows) == 5
    assert [r["rank"] for r in rows] == ["1", "2", "3", "4", "5"]


def _paint(mask: np.ndarray, lm: Landmarks, ids: dict[int, int], half: int = 4) -> None:
    for (x, y), c in zip(lm.xy.astype(int), lm.cls):
        mask[max(0, y - half):y + half + 1, max(0, x - half):x + half + 1] = ids[c]


def test_cli_with_masks_from_a_dataset_folder(tmp_path) -> None:
    aerial, centres = blocks_scene()
    truth = (centres["market"][0] + 3, centres["market"][1] + 7)  # no two landmarks at one azimuth
    table = load_class_table("classes13.toml")
    ids13 = {B: table.by_name["building"].id, R: table.by_name["highway"].id, V: table.by_name["tree"].id,
             F: table.by_name["footway"].id}
    mask = np.zeros((400, 400), np.uint8)
    _paint(mask, aerial, ids13)
    (tmp_path / "labels").mkdir()
    Image.fromarray(mask).save(tmp_path / "labels" / "s0.png")
    write_dataset_manifest(tmp_path, table.to_dict(), [{"name": "s0", "ground_resolution_m": 0.3}])
    camvid_ids = {B: 1, R: 3, F: 4, V: 5}  # CamVid label values (landmarks-camvid.toml mask_classes)
    pano = panorama(aerial, truth, 60)
    ground = np.zeros((pano.height, pano.width), np.uint8)  # 0 = Sky
    _paint(ground, pano, camvid_ids, half=3)
    Image.fromarray(ground).save(tmp_path / "ground.png")
    res = run("--aerial", str(tmp_path / "labels" / "s0.png"), "--ground", str(tmp_path / "ground.png"),
              "--min-size", "10", "--window", "60", "--truth", f"{truth[0]},{truth[1]}", "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["aerial_landmarks"] == len(aerial) and data["ground_landmarks"] == len(pano)
    assert data["truth"]["error_px"] <= 35
    assert data["truth"]["error_m"] == pytest.approx(0.3 * data["truth"]["error_px"])  # from the manifest


def test_cli_unanswered_is_a_normal_outcome(tmp_path) -> None:
    aerial, centres = blocks_scene()
    write_landmarks(tmp_path / "aerial.txt", aerial.select(aerial.cls != F))
    write_landmarks(tmp_path / "ground.txt", panorama(aerial, centres["market"], 60))
    res = run("--aerial", str(tmp_path / "aerial.txt"), "--aerial-size", "400x400", "--ground",
              str(tmp_path / "ground.txt"), "--ground-size", "616x112", "--window", "60")
    assert res.exit_code == 0
    assert res.stdout.startswith("unanswered: no aerial clique holds every class")


@pytest.mark.parametrize("case, code, words", [
    ("empty ground", 1, "no landmarks"),
    ("unreadable mask", 1, "cannot read the image"),
    ("rgb without checkpoint", 1, "not a label mask"),
    ("bad landmark line", 1, "expected 'x y Class'"),
    ("one class only", 1, "one class only"),
    ("window too large", 2, "--window 400 is not smaller than the aerial image"),
    ("truth outside", 2, "outside the aerial image"),
    ("bad size", 2, "WIDTHxHEIGHT"),
])
def test_cli_bad_input_is_one_line(tmp_path, case: str, code: int, words: str) -> None:
    aerial, centres = blocks_scene()
    write_landmarks(tmp_path / "aerial.txt", aerial)
    write_landmarks(tmp_path / "ground.txt", panorama(aerial, centres["park"], 60))
    args = {"--aerial": str(tmp_path / "aerial.txt"), "--aerial-size": "400x400",
            "--ground": str(tmp_path / "ground.txt"), "--ground-size": "616x112", "--window": "60"}
    if case == "empty ground":
        (tmp_path / "ground.txt").write_text("# nothing seen\n")
    elif case == "unreadable mask":
        (tmp_path / "ground.png").write_bytes(b"not a png at all")
        args["--ground"] = str(tmp_path / "ground.png")
    elif case == "rgb without checkpoint":
        Image.fromarray(np.zeros((40, 60, 3), np.uint8)).save(tmp_path / "photo.png")
        args["--aerial"] = str(tmp_path / "photo.png")
    elif case == "bad landmark line":
        (tmp_path / "ground.txt").write_text("10 20 Building\n30\n")
    elif case == "one class only":
        only = aerial.select(aerial.cls == B)
        write_landmarks(tmp_path / "aerial.txt", only)
        write_landmarks(tmp_path / "ground.txt", panorama(only, centres["offices"], 60))
    elif case == "window too large":
        args["--window"] = "400"
    elif case == "truth outside":
        args["--truth"] = "500,10"
    elif case == "bad size":
        args["--aerial-size"] = "400by400"
    res = run(*[v for kv in args.items() for v in kv])
    assert res.exit_code == code, res.output
    lines = res.stderr.strip().splitlines()
    assert words in lines[-1] and "Traceback" not in res.output
    assert len([line for line in lines if line.startswith("Error")]) == 1


def test_cli_segments_an_rgb_image_with_a_checkpoint(tmp_path) -> None:
    torch = pytest.importorskip("torch")
    from training.models.checkpoint import save_checkpoint
    from training.models.networks import build_model, model_spec

    spec = model_spec("airsegnet6", 0.0625, input_size=(64, 96))
    model = build_model(spec)
    with torch.no_grad():  # a model that calls every pixel "building", whatever it sees
        model.classifier.weight.zero_()
        model.classifier.bias.fill_(-5.0)
        model.classifier.bias[1] = 5.0
    save_checkpoint(tmp_path / "model.pt", {"spec": spec, "model": model.state_dict()})
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)).save(tmp_path / "aerial.png")
    (tmp_path / "ground.txt").write_text("10 50 Building\n60 60 Road\n")
    res = run("--aerial", str(tmp_path / "aerial.png"), "--aerial-checkpoint", str(tmp_path / "model.pt"),
              "--aerial-landmarks", "airsegnet6", "--ground", str(tmp_path / "ground.txt"), "--ground-size", "616x112",
              "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["aerial_landmarks"] == 1  # the whole image is one building component ...
    assert data["unanswered"] and "building, road" in data["reason"]  # ... and no road to match the ground's


def test_too_many_landmarks_is_a_clear_error_not_a_crash() -> None:
    """Landmarks of a noisy mask at --min-size 1 can number tens of thousands: refuse, with advice."""
    from localization.paper.edges import MAX_FEATURE_LANDMARKS
    from localization.paper.match import MAX_CLIQUE_PAIRS

    rng = np.random.default_rng(0)
    k = int((2 * MAX_CLIQUE_PAIRS) ** 0.5) + 2  # one window holding them all: k (k - 1) / 2 pairs, over the limit
    many = Landmarks(rng.uniform(0, 100, (k, 2)), rng.integers(0, 2, k), ("building", "road"), 100, 100)
    few = Landmarks(np.array([[10.0, 10], [20, 20]]), np.array([0, 1]), ("building", "road"), 100, 100)
    with pytest.raises(ConfigError, match="too many to match.*--min-size"):
        localize(many, few, PaperConfig(window=200))
    with pytest.raises(ConfigError, match="too many for feature edges"):
        feature_edge_mask(np.zeros((MAX_FEATURE_LANDMARKS + 1, 2)), 0.5)
