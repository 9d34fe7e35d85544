"""The figure sets of ``docs/figures.py`` that need what osmseg does not ship, or take minutes:
the authors' annotated pairs, the benchmarks' timings, and the real data of ``../shared/data``.
(The sets on the demo's own masks are in :mod:`figure_sets`, with the helpers both use; the
trainer on real held-out imagery in :mod:`figure_sets_heldout`.)
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any, cast

from figure_sets import MASK_THRESHOLD, TIMING_COLUMN, F, by_classes, of, px_stats, span, table
from figures import REPO_ROOT, Figure, Workspace, figure_set, transcript

from osmseg.units import count, degrees, factor, metres, number, pixels, ratio, seconds

# --------------------------------------------------------------------------- the authors' annotated pairs

SIZES = ("--aerial-size", "750x750", "--ground-size", "1232x224")


def pairs_run(ws: Workspace, out: str, *extra: str) -> tuple[tuple[str, ...], str, dict[str, Any]]:
    args = ("localize-pairs", ws.pairs_folder(), "--out", out, *SIZES, *extra)
    printed, r = ws.bench(*args[1:], command="localize-pairs")
    return args, printed, r


@figure_set("pairs", "expensive", needs="pairs")
def pairs(ws: Workspace) -> dict[str, Figure]:
    """localize-pairs on the authors' 15 annotated CVUSA pairs: both methods, heading known and unknown, their conventions"""
    paper_args, printed, paper = pairs_run(ws, "pairs/", "--methods", "paper")
    _, _, known = pairs_run(ws, "pairs-known/", "--aerial-resolution", "0.25", "--methods", "paper,profile")
    _, _, unknown = pairs_run(ws, "pairs-unknown/", "--aerial-resolution", "0.25", "--methods", "paper,profile",
                              "--view-heading", "unknown")
    _, _, authors = pairs_run(ws, "pairs-authors/", "--methods", "paper", "--conventions", "authors")
    n = len(paper["viewpoints"])
    s, b = paper["summary"], paper["baselines"]
    rows = []
    for heading, r, name in (("known", known, "paper"), ("known", known, "profile"), ("unknown", unknown, "profile")):
        st = px_stats(r["viewpoints"], name)
        rows.append([heading, name, pixels(st["mean"]), pixels(st["median"]),
                     *(ratio(st["recall"][k]) for k in (25, 50, 100)), ratio(r["methods"][name]["roc_auc"])])
    rows_k = [v["methods"]["profile"] for v in known["viewpoints"]]
    kappa = [v["kappa"] for v in rows_k]
    other = [v["negative_kappa"] for v in rows_k if v["negative_kappa"] is not None]
    turned = [(v["name"], v["methods"]["profile"]) for v in unknown["viewpoints"]
              if (v["methods"]["profile"]["heading_error_deg"] or 0) > 90]
    first, mean_error = candidate_analysis(ws, paper)
    figures = {
        "pairs.transcript": F(transcript((paper_args, printed)), TIMING_COLUMN),
        "pairs.table": F(table(["heading", "method", "mean", "median", "recall@25 px", "@50 px", "@100 px",
                                "ROC AUC"], rows)),
        "pairs.paper.median": F(pixels(s["median_error"])),
        "pairs.paper.mean": F(pixels(s["mean_error"])),
        "pairs.by_classes": F(by_classes(paper, "px")),
        "pairs.bars": F(bars(px_stats(known["viewpoints"], "profile")["mean"],
                             px_stats(unknown["viewpoints"], "profile")["mean"])),
        "pairs.factor": F(factor(b["random_guess_mean"] / s["median_error"])),
        "pairs.random_candidate": F(pixels(b["random_candidate_median"])),
        "pairs.nearest_first": F(of(first, n)),
        "pairs.candidate_mean": F(pixels(mean_error)),
        "pairs.profile.median": F(pixels(px_stats(known["viewpoints"], "profile")["median"])),
        "pairs.profile.mean": F(pixels(px_stats(known["viewpoints"], "profile")["mean"])),
        "pairs.unknown.profile.mean": F(pixels(px_stats(unknown["viewpoints"], "profile")["mean"])),
        "pairs.unknown.heading": F(degrees(unknown["methods"]["profile"]["median_heading_error_deg"])),
        "pairs.unknown.turned": F("; ".join(f"{name} by {degrees(m['heading_error_deg'])}, {pixels(m['error_px'])} "
                                            "from the truth" for name, m in turned) or "none"),
        "pairs.kappa.match": F(span(kappa, "ratio")),
        "pairs.kappa.other": F(span(other, "ratio")),
        "pairs.at06": F(of(sum(k < MASK_THRESHOLD for k in kappa), len(kappa))),
        "pairs.at03.answered": F(of(sum(k >= 0.3 for k in kappa), len(kappa))),
        "pairs.at03.rejected": F(of(sum(k < 0.3 for k in other), len(other))),
        "pairs.authors.median": F(pixels(authors["summary"]["median_error"])),
        "pairs.authors.mean": F(pixels(authors["summary"]["mean_error"])),
        "pairs.authors.differ": F(clique_counts_differ(ws)),
    }
    figures["pairs.sensitivity"] = F(sensitivity(ws))
    return figures


def bars(known: float, unknown: float) -> str:
    """Whether the profile method's mean pixel errors meet the bars of 15 px (heading known) and 30 px."""
    met = [known <= 15, unknown <= 30]
    return "are both met" if all(met) else ("are not met" if not any(met) else
                                            f"are met only with the heading {'known' if met[0] else 'unknown'}")


def loaded_pairs(ws: Workspace) -> list[Any]:
    from localization.bench.pairs import PairsConfig, load_pairs

    return load_pairs(ws.root / ws.pairs_folder(), PairsConfig(aerial_size=(750, 750), ground_size=(1232, 224)))


def candidate_analysis(ws: Workspace, paper: dict[str, Any]) -> tuple[int, float]:
    """How often the candidate nearest the truth is ranked first, and the median error of the mean
    of all candidate positions (what the selection alone gives), by localization.paper.match.localize:
    the paper method as localize-pairs runs it (its MAP errors are checked against results.json)."""
    import numpy as np

    from localization.paper.match import localize

    errors = {v["name"]: v["error_px"] for v in paper["viewpoints"]}
    first, means = 0, []
    for pair in loaded_pairs(ws):
        loc = localize(pair.aerial, pair.ground)
        truth = np.asarray(pair.truth, dtype=float)
        d = np.hypot(*(np.asarray(loc.candidates, dtype=float)[:, :2] - truth).T)
        map_error = float(np.hypot(*(np.asarray(loc.map_xy) - truth)))
        if abs(map_error - errors[pair.name]) > 1e-3:
            raise AssertionError(f"{pair.name}: localize gives {map_error:.4f} px, localize-pairs {errors[pair.name]}")
        first += int(np.argmin(d) == loc.order[0])
        means.append(float(np.hypot(*(np.asarray(loc.candidates, dtype=float)[:, :2].mean(axis=0) - truth))))
    return first, statistics.median(means)


def clique_counts_differ(ws: Workspace) -> str:
    """The pairs whose aerial graph has another number of cliques with the authors' conventions."""
    from localization.paper.config import PaperConfig
    from localization.paper.match import aerial_graph

    names = []
    for pair in loaded_pairs(ws):
        ours = aerial_graph(pair.aerial, PaperConfig(conventions="osmseg")).cliques
        theirs = aerial_graph(pair.aerial, PaperConfig(conventions="authors")).cliques
        if (0 if ours is None else len(ours)) != (0 if theirs is None else len(theirs)):
            names.append(pair.name)
    return f"{len(names)} give a different clique count ({', '.join(names)})" if names else \
        "none gives a different clique count"


#: the profile method's landmark-point settings tried around the default (ProfileConfig fields)
VARIANTS = (("`d0` 100 m", {"d0_m": 100.0}), ("`d0` 400 m", {"d0_m": 400.0}),
            ("a bearing kernel of 6°", {"sigma_deg": 6.0}), ("a log-distance sd of 0.5", {"distance_sd": 0.5}))


def sensitivity(ws: Workspace) -> str:
    """Mean pixel error of the profile method (heading known / unknown) with each of VARIANTS."""
    from dataclasses import replace

    from localization.bench.pairs import PairsConfig, run_pairs

    base = PairsConfig(resolution_m=0.25, aerial_size=(750, 750), ground_size=(1232, 224), methods=("profile",))
    parts = []
    for label, change_ in VARIANTS:
        means = []
        for heading in ("known", "unknown"):
            config = replace(base, heading=heading, profile=replace(base.profile, **change_))
            r = run_pairs(loaded_pairs(ws), config, ws.root / f"variant-{len(parts)}-{heading}", plots=False)
            means.append(px_stats(r["viewpoints"], "profile")["mean"])
        parts.append(f"{label}: {number(means[0], 'px')} / {pixels(means[1])}")
    return "; ".join(parts)


# --------------------------------------------------------------------------- benchmarks (timings: never the same twice)


def benchmark(ws: Workspace, script: str, *args: str, name: str | None = None) -> dict[str, Any]:
    """``python benchmarks/SCRIPT ARGS --json FILE``: the figures it printed. ``FILE`` is
    ``NAME.json`` in the workspace (default: the script's name), so that ``--reuse`` finds it."""
    out = ws.root / ((name or Path(script).stem) + ".json")
    if ws.reuse and out.is_file():  # figures.py --keep DIR --reuse: written by an earlier run in DIR
        return cast("dict[str, Any]", json.loads(out.read_text(encoding="utf-8")))
    ws.run(str(REPO_ROOT / "benchmarks" / script), *args, "--json", str(out), python=True)
    return json.loads(out.read_text(encoding="utf-8"))


@figure_set("speed", "expensive", needs="shared data")
def speed(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_localize_graph.py --real and bench_localize_scale.py (landmark graphs, both methods at city size)"""
    g = benchmark(ws, "bench_localize_graph.py", "--real")
    synthetic, pano = g["aerial 750x750 (synthetic)"], g["panorama 1232x224 (synthetic)"]
    helsinki = g["aerial 750x750 (Helsinki OSM, grid 50)"]
    s = benchmark(ws, "bench_localize_scale.py")
    rows = [[f"{size}²", count(v["landmarks"]), count(v["cliques"]), seconds(v["banded_s"]), count(round(v["banded_mb"])),
             seconds(v["bitset_s"]), count(round(v["bitset_mb"])), seconds(v["localize_s"]), count(round(v["localize_mb"]))]
            for size, v in sorted(s["graphs"].items(), key=lambda kv: int(kv[0]))]
    big = s["graphs"][max(s["graphs"], key=int)]
    profile_rows = []
    for key, v in s["profile"].items():
        size, heading = key.split()
        profile_rows.append([f"{size}²", heading,
                             seconds(v["s_per_view"]), count(round(v["peak_mb"])), metres(v["error_m"])])
    return {
        "speed.landmarks": F(count(synthetic["landmarks"])),
        "speed.panorama.landmarks": F(count(pano["landmarks"])),
        "speed.localize": F(seconds(synthetic["localize"]["fast_s"])),
        "speed.with_extraction": F(seconds(synthetic["localize"]["with_extraction_s"])),
        "speed.reference": F(seconds(synthetic["localize"]["reference_s"])),
        "speed.ratio": F(factor(synthetic["localize"]["ratio"])),
        "speed.cliques": F(seconds(synthetic["centroid"]["fast_s"])),
        "speed.cliques.reference": F(seconds(synthetic["centroid"]["reference_s"])),
        "speed.cliques.ratio": F(factor(synthetic["centroid"]["ratio"])),
        "speed.helsinki.landmarks": F(count(helsinki["landmarks"])),
        "speed.helsinki.localize": F(seconds(helsinki["localize"]["fast_s"])),
        "speed.helsinki.with_extraction": F(seconds(helsinki["localize"]["with_extraction_s"])),
        "speed.helsinki.reference": F(seconds(helsinki["localize"]["reference_s"])),
        "speed.helsinki.ratio": F(factor(helsinki["localize"]["ratio"])),
        "speed.scale.table": F(table(["mask", "landmarks", "cliques", "cliques, banded", "MB", "the K-bit cells", "MB",
                                      "graph + candidates (localize)", "MB"], rows)),
        "speed.big.landmarks": F(count(big["landmarks"])),
        "speed.big.localize": F(seconds(big["localize_s"])),
        "speed.profile.table": F(table(["mask", "heading", "s/view", "peak MB", "error"], profile_rows)),
    }


def megabytes(values: list[float]) -> str:
    """``"137-212 MB"``, or ``"172 MB"`` when every value rounds alike."""
    low, high = count(round(min(values))), count(round(max(values)))
    return f"{low} MB" if low == high else f"{low}-{high} MB"


@figure_set("build", "expensive", needs="shared data")
def build_speed(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_build.py --long 2000 (samples per second and memory of osmseg build, local sources)"""
    b = benchmark(ws, "bench_build.py", "--long", "2000")
    cores = b["cores"]
    warm = {fmt: b["warm"][f"{cores} {fmt}"] for fmt in ("png", "jpg")}
    long = b["long"]
    floor = b["floor"]["jpg"]
    gdal = floor["parts_s"]["read+warp"]
    return {
        "build.warp": F(f"{seconds(floor['remapped_s'])} against {seconds(gdal)}"),
        "build.warp.share": F(ratio(gdal / floor["floor_s"])),
        "build.cores": F(cores),
        "build.samples": F(b["samples"]),
        "build.steady.png": F(number(warm["png"]["steady"], "rate")),
        "build.steady.jpg": F(number(warm["jpg"]["steady"], "rate")),
        "build.whole.png": F(number(warm["png"]["rate"], "rate")),
        "build.whole.jpg": F(number(warm["jpg"]["rate"], "rate")),
        "build.long.samples": F(count(long["samples"])),
        "build.long.rate": F(number(long["rate"], "rate")),
        "build.long.builder": F(megabytes(long["builder_mb"])),
        "build.long.worker": F(megabytes(long["worker_mb"])),
    }


# --------------------------------------------------------------------------- real data of others (../shared/data)


@figure_set("contrast", "cheap", needs="shared data")
def contrast(ws: Workspace) -> dict[str, Figure]:
    """grey-level standard deviation of the real aerial images in ../shared/data (osmseg.builder.filters.grey_std)"""
    import rasterio

    from osmseg.builder.filters import FilterConfig, grey_std

    def stds(path: Path, side: int = 1280, step: int = 256) -> list[float]:
        with rasterio.open(path) as src:
            rgb = src.read([1, 2, 3]).transpose(1, 2, 0)
        h, w = rgb.shape[:2]
        if h < side or w < side:
            return [grey_std(rgb)]
        return [grey_std(rgb[y:y + side, x:x + side]) for y in range(0, h - side + 1, step)
                for x in range(0, w - side + 1, step)]

    uniform = stds(ws.shared / "oam-rgb" / "brazil.tif")
    cities = [v for p in ("inria-austin/image.tif", "zurich-ortho/image.tif", "oam-rgb/manila.tif")
              for v in stds(ws.shared / p)]
    return {"contrast.uniform": F(span(uniform, "grey")), "contrast.cities": F(span(cities, "grey")),
            "contrast.margin": F(factor(min(uniform + cities) / FilterConfig.min_contrast))}


@figure_set("osm", "cheap", needs="shared data")
def osm(ws: Workspace) -> dict[str, Figure]:
    """the West Oakland extract: its longest road segment, and what node-in-box alone misses (osmseg.osm)"""
    import math

    import osmium

    from osmseg.classes import load_class_table
    from osmseg.grid import pad_bbox, sample_grid
    from osmseg.osm.features import read_features
    from osmseg.osm.localfile import LocalFileSource
    from osmseg.rasterize import rasterize

    oakland = ws.shared / "oakland-osm" / "west-oakland.osm"
    longest, kind = 0.0, ""
    for way in osmium.FileProcessor(str(oakland)).with_locations():
        if way.is_way() and "highway" in way.tags:
            pts = [(n.lon, n.lat) for n in way.nodes if n.location.valid()]
            for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
                dx = math.radians(x1 - x0) * math.cos(math.radians((y0 + y1) / 2))
                length = 6371008.8 * math.hypot(dx, math.radians(y1 - y0))  # metres on the mean sphere
                if length > longest:
                    longest, kind = length, str(way.tags.get("highway"))
    table_ = load_class_table("classes13.toml")
    grid = sample_grid(-122.30136, 37.80765, 20)  # a 150 m sample in a 380 m file, as tests/core/test_osm_sources.py
    box = pad_bbox(grid.bbox, 20)
    whole = rasterize(read_features([oakland], grid, table_), grid, table_)
    bare = LocalFileSource(oakland, ws.root / "oakland-reach0", reach=0).fetch(box)
    lost = int((rasterize(read_features(list(bare.paths), grid, table_), grid, table_) != whole).sum())
    return {"osm.longest": F(f"{metres(longest)} between two nodes of a {kind} way"), "osm.lost": F(count(lost))}


# --------------------------------------------------------------------------- training (minutes of CPU)

#: the recipe ablation the training docs quote: every variant for as many optimiser steps
ABLATION_STEPS = "400"


def ablation_row(v: dict[str, Any]) -> list[str]:
    return [f"`{v['name']}`", v["what"], count(v["steps"]), count(v["pixels_per_step"]), seconds(v["train_s"]),
            ratio(v["test_pixel_accuracy"]), ratio(v["test_miou"]), ratio(v["train_pixel_accuracy"]),
            ratio(v["test_pixel_accuracy_bn_batch"])]


@figure_set("demotrain", "expensive", needs="torch")
def demotrain(ws: Workspace) -> dict[str, Figure]:
    """osmseg demo's training and evaluation (osmseg demo --no-localize)"""
    _, printed = ws.run("demo", "--out", "demo-train", "--no-localize")
    demo = json.loads((ws.root / "demo-train" / "eval" / "metrics.json").read_text(encoding="utf-8"))
    with (ws.root / "demo-train" / "run" / "log.csv").open(encoding="utf-8") as f:
        demo_seconds = sum(float(line.split(",")[-1]) for line in f.readlines()[1:])
    return {
        "demotrain.result": F(f"{ratio(demo['pixel_accuracy'])} pixel accuracy, mIoU {ratio(demo['miou'])}, after "
                              f"{seconds(demo_seconds)} of training", r"\d[\d.,]* s\b"),
        "demotrain.transcript": F(transcript((("demo", "--out", "demo-train", "--no-localize"), printed)),
                                  r"\d[\d.,]* s\b|time \S+"),
    }


@figure_set("training", "expensive", needs="torch")
def training(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_recipe.py on the demo dataset (every recipe variant), bench_train.py"""
    dataset = ws.demo_dataset()
    picture = REPO_ROOT / "docs" / "img" / "recipe-ablation.png"
    picture.parent.mkdir(exist_ok=True)
    a = benchmark(ws, "bench_recipe.py", "--dataset", dataset, "--steps", ABLATION_STEPS, "--out", "ablation",
                  "--png", str(picture))
    v = {r["name"]: r for r in a["variants"]}
    w = a["weights"]
    loop = benchmark(ws, "bench_train.py", "--skip-full", "--steps", "8")
    cpu = loop["CPU config: width 0.125, CPU"]
    timing = r"\d[\d.,]* s\b|\| \d[\d.,]* \|(?= 0\.)"
    return {
        "training.weights": F(f"{number(w['smallest'], 'ratio')} ({w['smallest_class']}) to "
                              f"{number(w['largest'], 'ratio')} ({w['largest_class']}), "
                              f"{factor(w['largest'] / w['smallest'])} apart"),
        "training.ablation.table": F(table(["variant", "what changes", "steps", "px/step", "training",
                                            "test accuracy", "test mIoU", "train accuracy",
                                            "test accuracy, BN batch statistics"],
                                           [ablation_row(r) for r in a["variants"]]), timing),
        "training.steps": F(count(int(ABLATION_STEPS))),
        **{f"training.{name}": F(f"{ratio(r['test_pixel_accuracy'])} test pixel accuracy, mIoU {ratio(r['test_miou'])}")
           for name, r in v.items()},
        "training.loop": F(f"{factor(cpu['ratio'])} (loop {number(cpu['loop_images_per_s'], 'rate')} crops/s, bare "
                           f"forward + backward + step {number(cpu['bare_images_per_s'], 'rate')})",
                           r"[\d.]+"),
    }


# --------------------------------------------------------------------------- Kotka: both renderers, a region

KOTKA = ("helsinki-osm", "kotka.osm.pbf")
#: the rows of docs/localization.md's two-renderer table: (label, localize-bench options)
QUERY_KINDS = (
    ("panoramas, heading known", ()),
    ("panoramas, `--view-heading unknown`", ("--view-heading", "unknown")),
    ("90° photos, `--fov 90 --view-heading unknown`", ("--fov", "90", "--view-heading", "unknown")),
    ("60° photos, `--fov 60 --view-heading unknown`", ("--fov", "60", "--view-heading", "unknown")),
    ("noise `--confusion 0.1 --miss-prob 0.2 --offset 2`, `--view-heading unknown`",
     ("--confusion", "0.1", "--miss-prob", "0.2", "--offset", "2", "--view-heading", "unknown")),
)


def kotka_mask(ws: Workspace) -> tuple[str, str]:
    """The 1280² Kotka mask the localize-bench tables run on (``kotka.tif`` in the workspace, made
    once): the OSM file it was drawn from, and its resolution as ``osm_mask.py`` printed it."""
    osm = str(ws.shared.joinpath(*KOTKA))
    res, _ = ws.run(str(REPO_ROOT / "benchmarks" / "osm_mask.py"), osm, "kotka.tif", "--lon", "26.9475", "--lat",
                    "60.5337", python=True)
    return osm, res


@figure_set("renderers", "expensive", needs="shared data")
def renderers(ws: Workspace) -> dict[str, Figure]:
    """localize-bench on a 1280² Kotka OSM mask, 40 views per kind of query, drawn by the mask renderer and by the geometry renderer"""
    osm, res = kotka_mask(ws)
    rows, pooled = [], {"mask": [], "geometry": []}
    for i, (label, extra) in enumerate(QUERY_KINDS):
        for renderer in ("mask", "geometry"):
            more = ("--renderer", "geometry", "--osm", osm) if renderer == "geometry" else ()
            _, r = ws.bench("kotka.tif", "--out", f"kotka-{renderer}-{i}/", "--aerial-resolution", res.strip(),
                            "--viewpoints", "40", "--methods", "profile", "--no-negatives", *more, *extra)
            m = r["methods"]["profile"]
            pooled[renderer] += [v["methods"]["profile"] for v in r["viewpoints"]]
            rows.append([label if renderer == "mask" else "", renderer, metres(m["median_error"]),
                         *(ratio(m["recall_at"][k]) for k in ("10", "25")), ratio(m["right_wrong_auc"]),
                         ratio(m["accepted"]), ratio(m["false_accept"])])
    from localization.bench.compare import roc_auc

    def auc(rows_: list[dict[str, Any]], key: str) -> str:
        right = [v[key] for v in rows_ if v["error"] is not None and v["error"] <= 10]
        wrong = [v[key] for v in rows_ if v["error"] is None or v["error"] > 50]
        return ratio(roc_auc(right, wrong))

    geo = pooled["geometry"]
    accepted = [v for v in geo if v["confidence"] >= 0.04]
    return {
        "renderers.table": F(table(["views", "renderer", "median", "recall@10 m", "@25 m", "right/wrong AUC",
                                    "answered at 0.04", "of them wrong"], rows)),
        "renderers.auc.confidence": F(auc(geo, "confidence")),
        "renderers.auc.kappa": F(auc(geo, "kappa")),
        "renderers.pooled": F(f"{of(len(accepted), len(geo))} answered, "
                              f"{of(sum(v['error'] > 50 for v in accepted), len(accepted))} of them wrong"),
    }


#: the rows of docs/localization.md's ceiling table: (QUERY_KINDS index, the target's "right" in metres)
CEILING_KINDS = ((2, 25.0), (4, 10.0))


@figure_set("ceiling", "expensive", needs="shared data")
def ceiling(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_ceiling.py on the renderers table's 90° and noise rows: what a perfect search would reach"""
    osm, res = kotka_mask(ws)
    rows, found = [], {}
    for i, right in CEILING_KINDS:
        label, extra = QUERY_KINDS[i]
        for renderer in ("mask", "geometry"):
            more = ("--renderer", "geometry", "--osm", osm) if renderer == "geometry" else ()
            out = f"ceiling-{renderer}-{i}"
            ws.bench("kotka.tif", "--out", f"{out}/", "--aerial-resolution", res.strip(), "--viewpoints", "40", "--methods",
                     "profile", "--no-negatives", "--save-panoramas", "40", *more, *extra)
            c = benchmark(ws, "bench_ceiling.py", str(ws.root / out), str(ws.root / "kotka.tif"), "--right", f"{right:g}",
                          name=f"bench_ceiling-{out}")
            found[(i, renderer)] = c
            rows.append([label if renderer == "mask" else "", renderer, f"{right:g} m",
                         *(ratio(c["shares"][k]) for k in ("right", "lost by the search", "a tie",
                                                           "a look-alike fits better", "nothing to read")),
                         ratio(c["ceiling"])])
    return {
        "ceiling.table": F(table(["views", "renderer", "right within", "right", "lost by the search", "a tie",
                                  "a look-alike fits better", "nothing to read", "ceiling"], rows)),
        "ceiling.photo": F(ratio(found[(2, "geometry")]["ceiling"])),
        "ceiling.noise": F(ratio(found[(4, "geometry")]["ceiling"])),
    }


@figure_set("draw", "expensive", needs="shared data")
def draw(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_region_draw.py: a region's blocks drawn from the whole OSM file each, or from one pass over it"""
    rows = benchmark(ws, "bench_region_draw.py")["rows"]
    cells = [[r["case"], count(r["blocks"]), seconds(r["per_block"]["cpu_s"]), seconds(r["one_pass"]["cpu_s"]),
              factor(r["ratio"]), f"{count(r['per_block']['peak_mb'])} / {count(r['one_pass']['peak_mb'])}",
              f"{count(r['differing_px'])} of {count(r['pixels'])}"] for r in rows]
    return {"draw.table": F(table(["region, --osm files", "blocks", "per block: CPU", "one pass: CPU",
                                   "one pass / per block", "peak MB (per block / one pass)",
                                   "pixels whose class differs"], cells),
                          r"\| [\d.,]+ s \| [\d.,]+ s \| [\d.]+ \| [\d,]+ / [\d,]+ \|")}


@figure_set("memory", "expensive", needs="shared data")
def memory(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/localize_memory.py: the resident memory of one `osmseg localize` command on Kotka masks of 1280² and 6400²"""
    m = benchmark(ws, "localize_memory.py", "--work", str(ws.root / "localize-memory"))
    rows = [[f"{r['size_px']}²", r["method"], count(round(r["max_rss_mb"])), count(round(r["above_base_mb"])),
             f"{r['bytes_per_px']:.1f}", seconds(r["seconds"])] for r in m["runs"]]
    return {
        "memory.table": F(table(["mask", "method", "max RSS MB", "above the interpreter MB", "bytes per pixel",
                                 "time"], rows), r"(?m)\| [\d,]+ \| [\d,]+ \| [\d.]+ \| [\d.,]+ s \|$"),
        "memory.base": F(count(round(m["base_mb"]))),
        "memory.slope": F(" and ".join(f"{v:.1f} ({k})" for k, v in m["bytes_per_further_px"].items()),
                          r"[\d.]+"),
    }


@figure_set("horizon", "expensive", needs="shared data")
def horizon(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_horizon.py: the tilt read from the horizon of the region benchmark's 30 tilted Kotka views"""
    h = benchmark(ws, "bench_horizon.py")
    ways = h["summary"]["ways"]
    rows = [[way, f"{w['median_deg']:.2f}°", f"{w['max_deg']:.2f}°", ratio(w["within_0.25"])] for way, w in ways.items()]
    return {
        "horizon.table": F(table(["tilt read", "median error", "largest", "within 0.25°"], rows)),
        "horizon.sky": F(f"{ways['with its sky']['median_deg']:.2f}°"),
        "horizon.level": F(f"{ways['level (the baseline)']['median_deg']:.2f}°"),
    }
