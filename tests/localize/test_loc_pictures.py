"""The localization pictures as a person reads them (issue 31): whole titles, class-table colours,
axes in plain degrees, each method's legend in its own terms, unanswered queries shown as such.

Most checks look at the demo's own run (``osmseg demo --no-train``: four Helsinki samples, twelve
rendered panoramas localized by both methods, the pictures a new user opens first): its PNGs,
its results.json, and the same answers drawn again on a figure whose artists can be read.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.figure import Figure
from PIL import Image

from localization.bench.render import render_view
from localization.common.inputs import SideOptions
from localization.common.landmarks import load_landmark_classes
from localization.paper.graph import adjacency
from localization.pipeline import LocalizeConfig, LocalizeFiles, localize_files
from localization.region.search import Answer, RegionConfig, RegionResult
from osmseg.classes import load_class_table
from osmseg.output.plotting import figure, save_png

TABLE = load_class_table("classes13.toml")
AERIAL13 = load_landmark_classes("aerial13")
WHITE = 250  # lighter than this, in every channel, is the page


@pytest.fixture(scope="module")
def demo(demo_run: Path) -> Path:
    """The output folder of ``osmseg demo --no-train`` (dataset/ and localize/; conftest's
    ``demo_run``, made once for the session)."""
    return demo_run / "demo"


def _pixels(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _ink_on_the_edges(pixels: np.ndarray, frame: int = 2) -> int:
    """Pixels that are not page white in the outermost ``frame`` rows and columns: whatever was
    drawn there runs into the picture's edge, and is cut off by it."""
    ink = (pixels < WHITE).any(axis=2)
    edge = np.zeros_like(ink)
    edge[:frame], edge[-frame:], edge[:, :frame], edge[:, -frame:] = True, True, True, True
    return int((ink & edge).sum())


def _results(demo: Path) -> dict[str, Any]:
    return json.loads((demo / "localize" / "results.json").read_text())


# ------------------------------------------------------------------------------------------ whole titles
def test_no_picture_of_the_demo_runs_off_its_edges(demo: Path) -> None:
    """errors.png's two-line title ran past its right edge, and a map's title over the top of the
    picture (an equal-aspect map under constrained layout): every picture now has a white frame."""
    loc = demo / "localize"
    pictures = [loc / "errors.png", loc / "confidence.png", loc / "classes.png", *sorted((loc / "views").glob("*.png"))]
    assert len(pictures) == 7
    for path in pictures:
        assert _ink_on_the_edges(_pixels(path)) == 0, path.name


def test_the_errors_title_is_wrapped_within_its_axes(demo: Path) -> None:
    from localization.bench.plots import draw_errors, errors_title
    from osmseg.output.plotting import wrap_titles

    results = _results(demo)
    with figure(6.5, 4.0) as fig:
        draw_errors(fig, results)
        wrap_titles(fig)
        fig.canvas.draw()
        ax = fig.axes[0]
        title = ax.title
        assert title.get_window_extent().width <= ax.get_window_extent().width
        assert fig.bbox.contains(*title.get_window_extent().p0) and fig.bbox.contains(*title.get_window_extent().p1)
        assert title.get_text().count("\n") >= 2  # the title's second line was too long for the axes
        assert title.get_text().split() == errors_title(results).split()  # the same words, only on more lines


def test_a_title_wider_than_the_picture_is_wrapped_and_saved_whole(tmp_path: Path) -> None:
    """The helper every picture is saved through: a long title on several lines, the PNG as wide
    as the figure (not widened by the title), nothing at its edges."""
    long = "; ".join(f"clause {i} of a long title" for i in range(12))
    with figure(4.0, 3.0) as fig:
        ax = fig.add_subplot()
        ax.plot([0, 1], [0, 1])
        ax.set_title(long)
        path = save_png(fig, tmp_path / "long.png")
        lines = ax.title.get_text().split("\n")
        assert len(lines) >= 4 and " ".join(lines) == long
        assert all(line.endswith(";") for line in lines[:-1])  # broken after its clauses
    pixels = _pixels(path)
    assert pixels.shape[1] <= 4.0 * 100 + 2 * 8 and _ink_on_the_edges(pixels) == 0


def test_an_equal_aspect_map_keeps_its_title_inside(tmp_path: Path) -> None:
    """The case of the localize maps: a square image filling the width, a three-row legend below."""
    from matplotlib.patches import Rectangle

    with figure(9.0, 9.9) as fig:
        ax = fig.add_subplot()
        ax.imshow(np.zeros((64, 64, 3)))
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title("window 262 px, 613 candidates, 14 tied at the top; error 257.6 px (76.51 m)")
        fig.legend(handles=[Rectangle((0, 0), 1, 1, label=f"class {i}") for i in range(15)],
                   loc="outside lower center", ncols=5)
        path = save_png(fig, tmp_path / "map.png")
    pixels = _pixels(path)
    assert _ink_on_the_edges(pixels) == 0
    assert (pixels[:30] < WHITE).any()  # the title is in the picture, near its top


def test_no_legend_covers_the_curves_or_the_bars(demo: Path) -> None:
    """errors.png's legend sat in the lower right of its axes, over the lower parts of several
    CDFs, and confidence.png's in each panel, over its histograms: each is under the axes now,
    clear of every axes' data area."""
    from localization.bench.plots import draw_confidence, draw_errors

    results = _results(demo)
    for draw, size in ((draw_errors, (6.5, 4.8)), (draw_confidence, (8.8, 4.0))):
        with figure(*size) as fig:
            draw(fig, results)
            fig.canvas.draw()
            legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
            assert legends, draw.__name__
            for legend in legends:
                box = legend.get_window_extent()
                assert not [ax for ax in fig.axes if box.overlaps(ax.get_window_extent())], draw.__name__


# ------------------------------------------------------------------------------------------ unanswered
def test_unanswered_queries_are_counted_apart_never_drawn_at_a_likelihood(demo: Path) -> None:
    from localization.bench.plots import confidences, draw_confidence
    from localization.bench.scores import UNANSWERED_CONFIDENCE

    results = _results(demo)
    recs = results["viewpoints"]
    paper = [r["methods"]["paper"]["confidence"] for r in recs]
    missed = paper.count(UNANSWERED_CONFIDENCE)
    assert missed >= 1  # the demo's paper method leaves some panoramas unanswered (3 of 12)
    answered, unanswered = confidences(recs, "paper", "confidence")
    assert unanswered == missed and len(answered) == len(recs) - missed and min(answered) >= 0
    with figure(8.8, 3.6) as fig:
        assert draw_confidence(fig, results)
        fig.canvas.draw()
        apart = [ax for ax in fig.axes if [t.get_text() for t in ax.get_xticklabels()] == ["unanswered"]]
        assert len(apart) == 1  # the paper method's; the profile method answered every query
        numeric = [ax for ax in fig.axes if ax not in apart]
        paper_ax = next(ax for ax in numeric if "MAP likelihood" in ax.get_xlabel())
        bars = [p for p in paper_ax.patches if p.get_height() > 0]
        drawn = sum(p.get_height() for p in bars)
        n_answered = sum(len(confidences(recs, "paper", key)[0]) for key in ("confidence", "negative_confidence"))
        assert drawn == n_answered  # every answered value, and nothing else, in the histogram
        assert min(p.get_x() for p in bars) >= min(answered) - 1e-6 > UNANSWERED_CONFIDENCE
        assert paper_ax.get_xlim()[0] > UNANSWERED_CONFIDENCE  # the axis does not reach the stand-in value
        negatives_unanswered = confidences(recs, "paper", "negative_confidence")[1]
        assert [p.get_height() for p in apart[0].patches] == [missed, negatives_unanswered]


def test_a_region_with_no_answer_says_unanswered() -> None:
    from localization.common.figures import draw_region

    overview = np.full((60, 80), TABLE.by_name["building"].id, dtype=np.uint8)
    result = RegionResult(answers=(), alternative=None, blocks=9, config=RegionConfig(bbox=(24.9391, 60.1702,
                          24.9512, 60.1763)), overview=overview, overview_bounds=(24.9391, 60.1702, 24.9512, 60.1763))
    with figure(9.0, 8.0) as fig:
        ax = draw_region(fig, result, TABLE, truth=(24.9455, 60.1712))
        assert ax.get_title().startswith("unanswered")
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert "answers, ranked" not in labels and "truth" in labels and "building" in labels


# ------------------------------------------------------------------------------------------ degree axes
DEGREES = re.compile(r"^-?\d+(\.\d+)?°$")


def _check_degree_ticks(axis: Any) -> None:
    """What a person reads on a degree axis: plain degrees, no offset, distinct labels at the ticks."""
    assert axis.get_offset_text().get_text() == ""
    ticks = [(t.get_loc(), t.label1.get_text()) for t in axis.get_major_ticks() if t.label1.get_visible()]
    lo, hi = sorted(axis.get_view_interval())
    shown = [(loc, text) for loc, text in ticks if lo <= loc <= hi]
    assert len(shown) >= 3
    for loc, text in shown:
        assert DEGREES.match(text), text  # no "e", no "+6.017e1", no bare 0.001
        assert float(text[:-1]) == pytest.approx(loc, abs=1e-9 + 0.5 * 10 ** -len(text.split(".")[-1][:-1]))
    assert len({text for _, text in shown}) == len(shown)


def test_region_axes_read_in_plain_degrees() -> None:
    """The reporter's region (Helsinki, 60.170-60.176 N), whose latitude axis read "+6.017e1"
    above ticks 0.001-0.006, and a whole-degree one."""
    from localization.common.figures import draw_region

    for bounds in ((24.9391, 60.1702, 24.9512, 60.1763), (26.93, 60.52, 26.97, 60.54), (10.0, 45.0, 14.0, 48.0)):
        overview = np.full((50, 50), TABLE.by_name["highway"].id, dtype=np.uint8)
        best = Answer(lon=(bounds[0] + bounds[2]) / 2, lat=(bounds[1] + bounds[3]) / 2, score=0.9, confidence=0.3,
                      heading_deg=0.0)
        result = RegionResult(answers=(best,), alternative=None, blocks=4, config=RegionConfig(bbox=bounds),
                              overview=overview, overview_bounds=bounds)
        with figure(9.0, 8.0) as fig:
            ax = draw_region(fig, result, TABLE)
            fig.canvas.draw()
            _check_degree_ticks(ax.xaxis)
            _check_degree_ticks(ax.yaxis)


def test_degree_axis_on_any_axes() -> None:
    from osmseg.output.plotting import degree_axis

    with figure(4.0, 3.0) as fig:
        ax = fig.add_subplot()
        ax.set_ylim(60.17015, 60.17635)
        ax.set_xlim(-0.0041, 0.0022)   # around the prime meridian: negative degrees
        degree_axis(ax.xaxis)
        degree_axis(ax.yaxis)
        fig.canvas.draw()
        _check_degree_ticks(ax.xaxis)
        _check_degree_ticks(ax.yaxis)


# ------------------------------------------------------------------------------------------ colours
def test_the_panorama_legend_shows_each_landmark_class_in_its_table_colour(demo: Path) -> None:
    """The bench's panorama picture: footway was purple there while purple is industrial in the
    map's legend. Under the picture, each landmark class's marker now has the colour the class
    table gives the mask class it comes from."""
    rec = _results(demo)["viewpoints"][0]
    pixels = _pixels(demo / "localize" / "views" / f"0000_{rec['scene']}_panorama.png")
    page = (pixels >= WHITE).all(axis=2).mean(axis=1) > 0.5  # rows that are mostly page: the title's, the legend's
    legend = pixels[_legend_top(page):]
    assert "footway" in rec["classes_seen"]
    for name in rec["classes_seen"]:
        source = next(mask_class for mask_class, landmark in AERIAL13.mapping.items() if landmark == name)
        colour = TABLE.by_name[source].color  # footway: classes13's footway, light blue
        found = int((legend == np.array(colour, dtype=np.uint8)).all(axis=2).sum())
        assert found >= 10, (name, colour)


def _legend_top(page: np.ndarray) -> int:
    """The first row under the picture's axes: after the last row that is mostly not page."""
    return int(np.flatnonzero(~page).max()) + 1


def test_landmark_files_are_drawn_in_their_dictionarys_class_table(tmp_path: Path) -> None:
    """Landmark files of CamVid classes, with no image: the graphs' dots and legend in camvid.toml's colours."""
    from osmseg.cli.main import cli

    aerial = [f"{x} {y} {'Building' if (x + y) % 100 else 'Road'}" for x in range(25, 400, 50) for y in range(25, 400, 50)]
    aerial += ["300 100 Tree", "312 110 Pavement", "295 112 Tree"]
    ground = ["100 60 Building", "140 80 Road", "300 70 Building", "330 90 Road", "480 50 Tree", "500 70 Pavement"]
    (tmp_path / "a.txt").write_text("\n".join(aerial) + "\n")
    (tmp_path / "g.txt").write_text("\n".join(ground) + "\n")
    res = CliRunner().invoke(cli, ["localize", "--method", "paper", "--aerial", str(tmp_path / "a.txt"), "--aerial-size",
                                   "400x400", "--aerial-landmarks", "camvid", "--ground", str(tmp_path / "g.txt"),
                                   "--ground-size", "616x112", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    camvid = load_class_table("camvid.toml")  # the dictionary's table: the names and ids its mask_classes give
    assert load_landmark_classes("camvid").mask_ids() == {c.id: c.name for c in (camvid.unlabeled, *camvid.classes)}
    pixels = _pixels(tmp_path / "out" / "ground_graph.png")
    for name in ("Building", "Road", "Tree", "Pavement"):
        rgb = np.array(camvid.by_name[name].color, dtype=np.uint8)
        assert int((pixels == rgb).all(axis=2).sum()) >= 20, name


# ------------------------------------------------------------------------------------------ legend terms
def _legend_texts(fig: Figure) -> list[str]:
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()]


def test_each_method_draws_its_answer_in_its_own_terms(demo: Path, tmp_path: Path) -> None:
    """``osmseg localize`` on a demo mask and a panorama rendered in it, both methods: the profile
    method scores positions of a grid (no windows, no MAP), the paper method ranks windows."""
    from localization.bench.rendered import load_dataset_scenes
    from localization.common.figures import TERMS, draw_graph, draw_localization
    from localization.common.landmarks import landmark_colours

    scene = load_dataset_scenes(demo / "dataset")[1]
    truth = tuple(_results(demo)["viewpoints"][1]["truth"])
    view = render_view(scene.mask, scene.table, scene.resolution_m, truth, AERIAL13)
    Image.fromarray(view.panorama.labels.astype(np.uint8)).save(tmp_path / "pano.png")

    def side(name: str, table: str | None, panorama: bool) -> SideOptions:
        return SideOptions(name, "aerial13", table, None, None, panorama, "centroid", 50, 50)

    request = LocalizeFiles(aerial=demo / "dataset" / "labels" / f"{scene.name}.png", ground=tmp_path / "pano.png",
                            aerial_options=side("aerial", None, False),
                            ground_options=side("ground", "classes13.toml", True), truth=truth)
    for method in ("profile", "paper"):
        report = localize_files(request, LocalizeConfig(method=method))
        assert report.result.top_k and report.result.map_xy is not None
        with figure(9.0, 9.9) as fig:
            draw_localization(fig, report.result, report.aerial.landmarks, truth=truth)
            texts = _legend_texts(fig)
        k = len(report.result.top_k)
        terms = TERMS[method]
        assert terms["top"].format(k=k) in texts and terms["best"] in texts, texts
        if method == "profile":
            assert not [t for t in texts if re.search(r"window|MAP|candidate", t)], texts
            assert f"top-{k} positions" in texts and "best position" in texts
            assert any(t.startswith("best distinct alternative") for t in texts)
        else:
            assert f"top-{k} windows" in texts and "best (MAP)" in texts
        # the ground side's landmark graph: each dot in its class-table colour
        ground = report.ground
        assert ground.colours == landmark_colours(AERIAL13, TABLE)
        graph = adjacency(LocalizeConfig(method="paper").paper.cliques(ground.landmarks, ground.landmarks.height))
        with figure(9.0, 2.3) as fig:
            ax = draw_graph(fig, ground.landmarks, graph, image=ground.picture(), colours=ground.colours)
            faces = np.round(ax.collections[-1].get_facecolors()[:, :3] * 255).astype(int)
        expected = [ground.colours[ground.landmarks.classes[c]] for c in ground.landmarks.cls]
        assert faces.tolist() == [list(c) for c in expected]


def test_confidence_of_queries_all_alike_reads_without_an_offset() -> None:
    """Three identical pairs: every confidence the same. The histogram's axis read "1e-9+6.705e-1"
    (bins a billionth wide); it reads plain values around the one value."""
    from localization.bench.plots import draw_confidence

    row = {"confidence": 0.6705, "negative_confidence": 0.6705}
    results: Any = {"queries": "annotated pairs", "methods": {"profile": {"roc_auc": 0.5}, "paper": {"roc_auc": 0.5}},
                    "viewpoints": [{"methods": {"profile": dict(row), "paper": dict(row)}} for _ in range(3)]}
    with figure(8.8, 3.6) as fig:
        assert draw_confidence(fig, results)
        fig.canvas.draw()
        for ax in fig.axes:
            assert ax.xaxis.get_offset_text().get_text() == ""
            labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
            assert labels and not [t for t in labels if "e" in t.lower()], labels
            lo, hi = ax.get_xlim()
            assert lo < 0.6705 < hi and hi - lo > 0.05
