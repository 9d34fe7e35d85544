"""The figure sets of ``docs/figures.py`` on real held-out imagery (``docs/training.md``): the
networks side by side on Kampala and Austin (``heldout``), the lite0 recipe one change at a time
(``lite0``), and what carries across cities, with the ceiling of the Kampala split
(``transfer``). Each runs ``benchmarks/bench_real_heldout.py`` with three seeds: an hour or more
of CPU; ``docs/figures.py --keep DIR --reuse`` re-renders from the JSON a run left in DIR.
"""

from __future__ import annotations

import statistics
from typing import Any

from figure_sets import F, table
from figure_sets_external import benchmark
from figures import REPO_ROOT, Figure, Workspace, figure_set

from osmseg.units import ratio, seconds


def spread(figure: dict[str, float], show: Any = ratio) -> str:
    """``mean (min–max)`` over seeds, as bench_real_heldout.py's summary gives them."""
    return f"{show(figure['mean'])} ({show(figure['min'])}–{show(figure['max'])})"


#: bench_real_heldout.py's variants by name (the first whose options all appear in a variant's)
VARIANT_NAMES = (("--arch unet-lite0 --init random", "unet-lite0, random weights"),
                 ("--arch unet-lite0", "unet-lite0 from ImageNet, `lite0` recipe"),
                 ("--recipe paper --arch segnet", "SegNet as published, the dissertation's recipe"),
                 ("--arch segnet-skip", "SegNet with skips (width 0.125), `osmseg` recipe"))


def variant_name(variant: str) -> str:
    words = variant.split()
    for options, name in VARIANT_NAMES:
        if all(w in words for w in options.split()):
            return name
    return f"`{variant}`"


def _scores(r: dict[str, Any]) -> tuple[float, ...]:
    return tuple(r[w][k] for w in ("kampala", "austin") for k in ("building_iou", "pixel_accuracy"))


def _stats(values: list[float]) -> dict[str, float]:
    return {"mean": statistics.fmean(values), "min": min(values), "max": max(values)}


def heldout_rows(report: dict[str, Any], checkpoints: tuple[str, ...] = ("model.pt", "last.pt", "best.pt"),
                 rename: Any = variant_name) -> list[list[str]]:
    """A row per method and checkpoint, mean (min–max) over the seeds of bench_real_heldout.py's runs.

    What ``model.pt`` holds is read off the scores: the moving average where its masks differ from
    ``last.pt``'s (only those seeds count), else the final weights (one row with ``last.pt``)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in report["results"]:
        groups.setdefault((r["variant"], r.get("checkpoint", "")), []).append(r)
    seeds_of = {r["seed"] for r in report["results"]}
    rows = []
    for (variant, checkpoint), members in groups.items():
        if checkpoint and checkpoint not in checkpoints:
            continue
        last = {m["seed"]: _scores(m) for m in groups.get((variant, "last.pt"), [])}
        averaged = [m for m in groups.get((variant, "model.pt"), []) if _scores(m) != last.get(m["seed"])]
        if checkpoint == "model.pt" and averaged:
            members, which = averaged, "weights averaged (`--ema 0.99`)"
        elif checkpoint == "model.pt":
            which = "final weights (model.pt)"
        elif checkpoint == "last.pt":
            if not averaged:
                continue  # the same weights as model.pt's row
            which = "final weights (last.pt; model.pt without --ema)"
        else:
            which = "best validation epoch (best.pt)" if checkpoint else ""
        seeds = sorted(m["seed"] for m in members)
        if checkpoint and set(seeds) != seeds_of:
            which += f", seeds {', '.join(map(str, seeds))} only"
        label = rename(variant) if checkpoint else f"per-pixel {variant}"
        rows.append([f"{label}: {which}" if which else label,
                     *(spread(_stats([m[w][k] for m in members])) for w, k in (
                         ("kampala", "building_iou"), ("austin", "building_iou"), ("kampala", "pixel_accuracy"),
                         ("austin", "pixel_accuracy"))),
                     spread(_stats([float(m["train_seconds"]) for m in members]), seconds)])
    return rows


HELDOUT_HEADER = ["trained by", "Kampala building IoU", "Austin building IoU", "Kampala pixel accuracy",
                  "Austin pixel accuracy", "training"]
#: the recipe ablation of unet-lite0 (docs/training.md): each row the lite0 recipe with one change,
#: at half the held-out bench's steps (10 epochs of 20), three seeds
LITE0 = "--arch unet-lite0 --init imagenet --width 1.0 --ema 0.99"
LITE0_ABLATION = ("", "--freeze-bn", "--encoder-lr 0.1", "--dice 1", "--init random")


def ablation_name(variant: str) -> str:
    """A row of the ablation by its change to the lite0 recipe (the base options dropped)."""
    words = [w for w in variant.split() if w not in LITE0.split() or w == "random"]
    change = " ".join(w for w in words if w != "random") if "random" not in words else "--init random"
    return f"`{change}`" if change else "the `lite0` recipe"


@figure_set("heldout", "expensive", needs="shared data")
def heldout(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_real_heldout.py --seeds 0 1 2: buildings on Kampala z21 samples apart from training, and on Inria Austin, SegNet and unet-lite0 beside a per-pixel baseline"""
    picture = REPO_ROOT / "docs" / "img" / "heldout.png"
    picture.parent.mkdir(exist_ok=True)
    variants = ("--arch segnet-skip", "--recipe paper --arch segnet", LITE0)
    report = benchmark(ws, "bench_real_heldout.py", "--out", "heldout", "--png", str(picture), "--seeds", "0", "1", "2",
                       *(x for v in variants for x in ("--train-args", v)))
    lite0, skip = "--arch unet-lite0", "--arch segnet-skip"

    def iou(variant: str, checkpoint: str, where: str, averaged: bool = False, show: str = "mean") -> str:
        """A network's (or baseline's) building IoU over the seeds: final weights, or (``averaged``) the
        seeds whose model.pt holds a moving average."""
        runs = [r for r in report["results"] if r.get("checkpoint", "") == checkpoint and
                all(w in r["variant"].split() for w in variant.split())]
        if averaged or checkpoint == "last.pt":
            last = {r["seed"]: _scores(r) for r in report["results"] if r["variant"] in {m["variant"] for m in runs}
                    and r.get("checkpoint") == "last.pt"}
            if averaged:
                runs = [r for r in runs if _scores(r) != last.get(r["seed"])]
        values = _stats([r[where]["building_iou"] for r in runs])
        return f"{ratio(values['min'])} to {ratio(values['max'])}" if show == "range" else ratio(values["mean"])

    return {"heldout.table": F(table(HELDOUT_HEADER, heldout_rows(report)), r"\d[\d.,]* s\b"),
            "heldout.lite0.austin": F(iou(lite0, "last.pt", "austin")),
            "heldout.lite0.austin.range": F(iou(lite0, "last.pt", "austin", show="range")),
            "heldout.lite0.kampala": F(iou(lite0, "last.pt", "kampala")),
            "heldout.lite0.ema": F(f"{iou(lite0, 'model.pt', 'kampala', averaged=True)} against "
                                   f"{iou(lite0, 'last.pt', 'kampala')} on Kampala, "
                                   f"{iou(lite0, 'model.pt', 'austin', averaged=True)} against "
                                   f"{iou(lite0, 'last.pt', 'austin')} on Austin"),
            "heldout.skip.austin": F(iou(skip, "model.pt", "austin")),
            "heldout.skip.kampala": F(iou(skip, "model.pt", "kampala")),
            "heldout.skip.best": F(f"{iou(skip, 'best.pt', 'kampala')} against {iou(skip, 'model.pt', 'kampala')}"),
            "heldout.baselines.austin": F(f"{iou('baseline balanced', '', 'austin')} balanced and "
                                          f"{iou('baseline unweighted', '', 'austin')} unweighted")}


@figure_set("lite0", "expensive", needs="shared data")
def lite0_ablation(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_real_heldout.py --seeds 0 1 2 --epochs 10 --steps-per-epoch 20: the lite0 recipe, one change a row"""
    variants = [f"{LITE0} {v}".strip() for v in LITE0_ABLATION]
    report = benchmark(ws, "bench_real_heldout.py", "--out", "ablation", "--seeds", "0", "1", "2", "--epochs", "10",
                       "--steps-per-epoch", "20", *(x for v in variants for x in ("--train-args", v)))
    return {"lite0.ablation": F(table(HELDOUT_HEADER, heldout_rows(report, ("model.pt", "last.pt"),
                                                                   rename=ablation_name)), r"\d[\d.,]* s\b")}


#: what carries across cities (docs/training.md): unet-lite0 from ImageNet by the lite0 recipe at the
#: held-out bench's budget, with crops zoomed out up to 1.5x (crops of 256-384 px resized to 256),
#: alone and with issue 32's other settings (no colour jitter, a Dice term); each its own bench run
TRANSFER = "--arch unet-lite0 --init imagenet --width 1.0"
TRANSFER_VARIANTS = (("transfer-zoom", "--crop-scale 1.5"), ("transfer-zoom-dice", "--crop-scale 1.5 --jitter 0 --dice 1"))


def transfer_name(variant: str) -> str:
    """A row by its change to unet-lite0's lite0 recipe."""
    change = " ".join(w for w in variant.split() if w not in TRANSFER.split())
    return f"unet-lite0, `{change}`" if change else "unet-lite0, the `lite0` recipe"


@figure_set("transfer", "expensive", needs="shared data")
def transfer(ws: Workspace) -> dict[str, Figure]:
    """benchmarks/bench_real_heldout.py --seeds 0 1 2, unet-lite0 with zoomed-out crops, and --fit-test: the ceiling of the Kampala split"""
    seeds = ("--seeds", "0", "1", "2")
    reports = {name: benchmark(ws, "bench_real_heldout.py", "--out", name, *seeds, "--train-args",
                               f"{TRANSFER} {change}", name=name) for name, change in TRANSFER_VARIANTS}
    ceiling = benchmark(ws, "bench_real_heldout.py", "--out", "transfer-ceiling", *seeds, "--fit-test", "--train-args",
                        TRANSFER, name="transfer-ceiling")
    rows = [row for name, _ in TRANSFER_VARIANTS
            for row in heldout_rows(reports[name], ("model.pt",), rename=transfer_name) if row[0].startswith("unet")]
    rows += [row for row in heldout_rows(reports[TRANSFER_VARIANTS[0][0]], ("model.pt",), rename=transfer_name)
             if row[0].startswith("per-pixel")]  # the same seeds' baselines
    rows += [["trained on the test mosaics too (a ceiling): " + row[0], *row[1:]]
             for row in heldout_rows(ceiling, ("model.pt",), rename=transfer_name)]

    def iou(report: dict[str, Any], variant: str, where: str) -> float:
        """Mean building IoU over the seeds of a network's model.pt (or a baseline's)."""
        runs = [r for r in report["results"] if r.get("checkpoint", "model.pt") == "model.pt" and r["variant"] == variant]
        return statistics.fmean(r[where]["building_iou"] for r in runs)

    zoom, both = (reports[n] for n, _ in TRANSFER_VARIANTS)
    fitted = iou(ceiling, TRANSFER, "kampala")
    return {
        "transfer.table": F(table(HELDOUT_HEADER, rows), r"\d[\d.,]* s\b"),
        "transfer.zoom.austin": F(ratio(iou(zoom, f"{TRANSFER} {TRANSFER_VARIANTS[0][1]}", "austin"))),
        "transfer.zoom.kampala": F(ratio(iou(zoom, f"{TRANSFER} {TRANSFER_VARIANTS[0][1]}", "kampala"))),
        "transfer.both.austin": F(ratio(iou(both, f"{TRANSFER} {TRANSFER_VARIANTS[1][1]}", "austin"))),
        "transfer.both.kampala": F(ratio(iou(both, f"{TRANSFER} {TRANSFER_VARIANTS[1][1]}", "kampala"))),
        "transfer.ceiling.kampala": F(ratio(fitted)),
        "transfer.ceiling.austin": F(ratio(iou(ceiling, TRANSFER, "austin"))),
        "transfer.ceiling.baseline": F(ratio(iou(ceiling, "baseline balanced", "kampala"))),
    }
