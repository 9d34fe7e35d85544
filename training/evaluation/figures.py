"""Evaluation pictures: confusion matrix, qualitative panels, training curves, per-class IoU.

Every picture is drawn with matplotlib's object-oriented API on an Agg canvas created here
(osmseg.output.plotting: a Figure on its own Agg canvas), never through ``pyplot``: no
global backend is switched, no figure is registered in pyplot's figure manager (so nothing
stays open after a call, and nothing needs a display), and style settings are applied with
:func:`matplotlib.rc_context`, which restores ``rcParams`` on exit. Each PNG is rendered into
memory without a "Software" stamp (identical input gives identical bytes) and written with
:func:`osmseg.output.atomic.atomic_write_bytes`.

Class colours come from a class table in ``ClassTable.to_dict()`` form
(``{"name", "classes": [{"id", "name", "color"}]}``), as stored in checkpoints, so pictures
of a model's outputs use the same colours as the dataset's masks.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from osmseg.classes import ClassTable
from osmseg.errors import ConfigError, DatasetError
from osmseg.output.plotting import figure as _figure, legend_below, save_png as _save

__all__ = ["checkpoint_curves", "checkpoint_curves_png", "confusion_matrix_png", "draw_per_class_iou", "draw_training_curves",
           "per_class_iou_png", "qualitative_panels", "training_curves_png"]

#: Matrices up to this many classes get their values written in the cells.
MAX_ANNOTATED = 16
Panel = tuple[str, np.ndarray, np.ndarray, np.ndarray]


def _classes(class_table: ClassTable | Mapping[str, Any]) -> list[tuple[int, str, tuple[int, int, int]]]:
    """(id, name, rgb) of each class of a table (a ClassTable or its ``to_dict()``), by id."""
    table = class_table if isinstance(class_table, ClassTable) else ClassTable.from_dict(class_table)
    return sorted((c.id, c.name, c.color) for c in (table.unlabeled, *table.classes))


def _palette(class_table: Mapping[str, Any]) -> np.ndarray:
    """``(256, 3)`` uint8 lookup table of class colours by id (ids not in the table: black)."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    for cid, _, rgb in _classes(class_table):
        lut[cid] = rgb
    return lut


def _rgb01(rgb: Sequence[int]) -> tuple[float, float, float]:
    return (rgb[0] / 255, rgb[1] / 255, rgb[2] / 255)


def _names(metrics: Mapping[str, Any]) -> list[str]:
    return list(metrics.get("class_names") or metrics["per_class"])


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


# --------------------------------------------------------------------------- confusion matrix


def normalise_matrix(matrix: np.ndarray, normalise: str | None) -> np.ndarray:
    """Counts divided by row sums ("true"), column sums ("pred") or the total ("all"); rows or
    columns with no pixels become NaN (drawn blank). ``None``/"none" keeps the counts.

    >>> normalise_matrix(np.array([[3, 1], [0, 0]]), "true").tolist()
    [[0.75, 0.25], [nan, nan]]
    """
    mat = np.asarray(matrix, dtype=np.float64)
    if normalise in (None, "none"):
        return mat
    if normalise == "true":
        den = mat.sum(axis=1, keepdims=True)
    elif normalise == "pred":
        den = mat.sum(axis=0, keepdims=True)
    elif normalise == "all":
        den = np.full((1, 1), mat.sum())
    else:
        raise ConfigError(f"normalise must be 'true', 'pred', 'all' or None, got {normalise!r}")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, mat / np.where(den > 0, den, 1), np.nan)


def confusion_matrix_png(metrics: Mapping[str, Any], path: Path | str, normalise: str | None = "true",
                         hide_empty: bool = True) -> Path:
    """Heat map of ``metrics["confusion_matrix"]`` (rows: ground truth, columns: prediction).

    Row-normalised by default, so the diagonal reads as each class's recall. ``hide_empty``
    drops classes with neither ground-truth nor predicted pixels (an ignored unlabeled class
    that the model never predicts). Values are written in the cells up to
    :data:`MAX_ANNOTATED` classes; the title gives the mIoU.
    """
    names = _names(metrics)
    counts = np.asarray(metrics["confusion_matrix"], dtype=np.int64)
    if counts.shape != (len(names), len(names)):
        raise ConfigError(f"confusion matrix of shape {counts.shape} does not match {len(names)} class names")
    keep = np.flatnonzero((counts.sum(0) + counts.sum(1)) > 0) if hide_empty else np.arange(len(names))
    if keep.size == 0:
        keep = np.arange(len(names))
    counts = counts[np.ix_(keep, keep)]
    labels = [names[i] for i in keep]
    values = normalise_matrix(counts, normalise)
    n = len(labels)
    vmax = 1.0 if normalise not in (None, "none") else max(1.0, float(np.nanmax(values, initial=0)))
    side = max(4.0, 0.55 * n + 2.5)
    with _figure(side + 1.0, side) as fig:
        ax = fig.add_subplot()
        cmap = matplotlib.colormaps["Blues"].with_extremes(bad="0.92")
        im = ax.imshow(np.ma.masked_invalid(values), cmap=cmap, vmin=0.0, vmax=vmax, interpolation="nearest")
        fig.colorbar(im, ax=ax, shrink=0.8, label="fraction" if normalise not in (None, "none") else "pixels")
        ax.set_xticks(range(n), labels, rotation=45, ha="right", rotation_mode="anchor")
        ax.set_yticks(range(n), labels)
        ax.set_xlabel("prediction")
        ax.set_ylabel("ground truth")
        if n <= MAX_ANNOTATED:
            for (r, c), v in np.ndenumerate(values):
                if math.isnan(v):
                    continue
                text = f"{v:.2f}" if normalise not in (None, "none") else f"{int(v):,}"
                ax.text(c, r, text, ha="center", va="center", fontsize=7 if n > 8 else 8,
                        color="white" if v > 0.55 * vmax else "black")
        over = {"true": "ground-truth rows", "pred": "prediction columns", "all": "all pixels"}.get(str(normalise))
        ax.set_title(f"Confusion matrix{f' (normalised over {over})' if over else ''}\nmIoU {_fmt(metrics.get('miou'))}")
        return _save(fig, path)


# --------------------------------------------------------------------------- qualitative panels


def _check_panel(row: Sequence[Any], index: int) -> Panel:
    if len(row) != 4:
        raise DatasetError(f"panel row {index} must be (title, image, ground truth, prediction), got {len(row)} items")
    title, image, gt, pred = row
    image, gt, pred = np.asarray(image), np.asarray(gt), np.asarray(pred)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise DatasetError(f"panel {title!r}: image must be H x W x 3 RGB, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise DatasetError(f"panel {title!r}: image must be uint8, got {image.dtype}")
    for what, mask in (("ground truth", gt), ("prediction", pred)):
        if mask.shape != image.shape[:2]:
            raise DatasetError(f"panel {title!r}: {what} shape {mask.shape} differs from image shape {image.shape[:2]}")
        if not np.issubdtype(mask.dtype, np.integer) or (mask.size and (mask.min() < 0 or mask.max() > 255)):
            raise DatasetError(f"panel {title!r}: {what} must hold integer class ids 0..255")
    return str(title), image[:, :, :3], gt, pred


def qualitative_panels(rows: Sequence[Panel], class_table: Mapping[str, Any], path: Path | str,
                       column_titles: Sequence[str] = ("image", "ground truth", "prediction"),
                       panel_inches: float = 3.0) -> Path:
    """A grid with one row per sample, image | ground truth | prediction, and a colour legend.

    ``rows`` are ``(title, rgb uint8 H x W x 3, gt ids H x W, pred ids H x W)``; masks are
    coloured with ``class_table``'s colours (ids it does not list are black). The legend
    lists every class of the table, as the dissertation's Tables 5.2-5.5 do.
    """
    panels = [_check_panel(row, i) for i, row in enumerate(rows)]
    if not panels:
        raise DatasetError("no samples to draw: give at least one (title, image, ground truth, prediction) row")
    palette = _palette(class_table)
    entries = _classes(class_table)
    aspect = max(p[1].shape[0] / max(p[1].shape[1], 1) for p in panels)
    legend_cols = min(len(entries), 5)
    legend_rows = math.ceil(len(entries) / legend_cols) if entries else 0
    height = len(panels) * panel_inches * aspect + 0.35 + 0.25 * legend_rows
    with _figure(3 * panel_inches + 0.4, height) as fig:
        axes = fig.subplots(len(panels), 3, squeeze=False)
        for r, (title, image, gt, pred) in enumerate(panels):
            shown = (image, palette[gt.astype(np.intp)], palette[pred.astype(np.intp)])
            for c, (ax, picture) in enumerate(zip(axes[r], shown)):
                # masks: nearest neighbour, so every drawn pixel has exactly a class colour
                ax.imshow(picture, interpolation="antialiased" if c == 0 else "nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0:
                    ax.set_title(column_titles[c])
            axes[r][0].set_ylabel(title)
        handles = [Patch(facecolor=_rgb01(rgb), edgecolor="0.3", linewidth=0.6, label=name) for _, name, rgb in entries]
        if handles:
            fig.legend(handles=handles, loc="outside lower center", ncol=legend_cols, frameon=False,
                       handlelength=1.6, handleheight=1.2)
        return _save(fig, path)


# --------------------------------------------------------------------------- training curves


def _number(value: Any) -> float | None:
    """A finite float from a history/CSV cell, else None ("" / "None" / nan / missing).

    >>> _number("0.5"), _number(""), _number("nan"), _number(None), _number(2)
    (0.5, None, None, None, 2.0)
    """
    if value is None or value == "" or value == "None":
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def read_history(history: Sequence[Mapping[str, Any]] | Path | str) -> list[dict[str, float | None]]:
    """Epoch rows from a list of dicts or a training ``log.csv``, every value a float or None."""
    if isinstance(history, (str, Path)):
        path = Path(history)
        try:
            with path.open(newline="") as f:
                raw: Sequence[Mapping[str, Any]] = list(csv.DictReader(f))
        except OSError as exc:
            raise DatasetError(f"cannot read training log {path}: {exc.strerror or exc}; give the run's log.csv") from None
    else:
        raw = history
    rows = [{str(k): _number(v) for k, v in row.items()} for row in raw]
    if not rows:
        raise DatasetError("the training history has no epochs yet; train at least one epoch")
    return rows


def draw_training_curves(fig: Figure, history: Sequence[Mapping[str, Any]] | Path | str, *, title: str | None = None,
                         mark: tuple[int, str] | None = None) -> tuple[Axes, Axes]:
    """:func:`training_curves_png`'s picture on ``fig``; returns its (loss, validation) axes."""
    rows = read_history(history)
    epochs = [row.get("epoch") or float(i + 1) for i, row in enumerate(rows)]

    def series(key: str) -> tuple[list[float], list[float]]:
        pairs = [(e, row[key]) for e, row in zip(epochs, rows) if row.get(key) is not None]
        return [p[0] for p in pairs], [p[1] for p in pairs]  # type: ignore[misc]

    loss_ax, score_ax = fig.subplots(1, 2)
    for key, label, color in (("train_loss", "train loss", "tab:blue"), ("val_loss", "validation loss", "tab:orange")):
        xs, ys = series(key)
        if xs:
            loss_ax.plot(xs, ys, marker="o", color=color, label=label)
    loss_ax.set_title("Loss")
    loss_ax.set_ylabel("loss")
    for key, label, color, style in (("val_miou", "validation mIoU", "tab:green", "-"),
                                     ("val_pixel_accuracy", "validation pixel accuracy", "tab:purple", "--")):
        xs, ys = series(key)
        if xs:
            score_ax.plot(xs, ys, marker="o", linestyle=style, color=color, label=label)
    score_ax.set_title("Validation")
    score_ax.set_ylim(0.0, 1.0)
    for ax in (loss_ax, score_ax):
        ax.set_xlabel("epoch")
        ax.grid(True, alpha=0.3)
        ax.xaxis.get_major_locator().set_params(integer=True)
        if mark is not None:
            ax.axvline(mark[0], color="0.25", linestyle=":", linewidth=1.5, label=mark[1], zorder=1)
    handles = [h for ax in (loss_ax, score_ax) for h in ax.get_legend_handles_labels()[0]
               if mark is None or h.get_label() != mark[1]]
    unique = handles + [h for h in loss_ax.lines if mark is not None and h.get_label() == mark[1]]  # named once, last
    if unique:  # under the axes, where it hides no point of a curve
        legend_below(fig, unique, columns=3)
    if title:
        fig.suptitle(title)
    return loss_ax, score_ax


def training_curves_png(history: Sequence[Mapping[str, Any]] | Path | str, path: Path | str, *,
                        title: str | None = None, mark: tuple[int, str] | None = None) -> Path:
    """Loss (train and validation) and validation mIoU per epoch, side by side, one legend under them.

    ``history`` is the trainer's list of per-epoch dicts or its ``log.csv``; the columns used
    are ``epoch``, ``train_loss``, ``val_loss``, ``val_miou`` and (if present)
    ``val_pixel_accuracy``. Missing or non-finite values are skipped, not drawn as zero.
    ``title`` says what the curves are (:func:`checkpoint_curves_png`); ``mark`` (epoch, label)
    draws a dotted line at that epoch, named in the legend.
    """
    with _figure(9.0, 4.0 if title is None else 4.5) as fig:
        draw_training_curves(fig, history, title=title, mark=mark)
        return _save(fig, path)


def _same_epochs(log: Sequence[Mapping[str, float | None]], history: Sequence[Mapping[str, float | None]]) -> bool:
    """Whether ``log``'s first rows are ``history``'s epochs, number for number: the log of the run
    a checkpoint with that history comes from (a later epoch never changes an earlier row)."""
    if len(log) < len(history):
        return False
    for written, kept in zip(log, history):
        for key in ("epoch", "train_loss", "val_loss", "val_miou"):
            a, b = written.get(key), kept.get(key)
            if (a is None) != (b is None) or (a is not None and b is not None and not math.isclose(a, b, rel_tol=1e-9)):
                return False
    return True


def checkpoint_curves(checkpoint: Mapping[str, Any], checkpoint_path: Path | str
                      ) -> tuple[list[dict[str, float | None]], str, tuple[int, str]]:
    """What ``osmseg eval``'s curves.png draws of a checkpoint's training: ``(epoch rows, title,
    (the checkpoint's epoch, its label))``.

    A checkpoint holds its run's history up to its own epoch (best.pt: the epoch of the best
    validation mIoU, often before the last). When the checkpoint's folder holds its run's
    ``log.csv`` (its first rows are the checkpoint's history), the rows are the whole run's;
    else the history the checkpoint holds, titled as stopping at its epoch (of the epochs the
    run planned).
    """
    checkpoint_path = Path(checkpoint_path)
    name = checkpoint_path.name
    history = read_history(list(checkpoint["history"]))
    epoch = int(checkpoint.get("epoch") or history[-1].get("epoch") or len(history))
    planned = (checkpoint.get("config") or {}).get("epochs")
    log_path = checkpoint_path.parent / "log.csv"
    try:
        log = read_history(log_path) if log_path.is_file() else None
    except DatasetError:  # unreadable or empty: not the run's log
        log = None
    rows = log if log is not None and _same_epochs(log, history) else history
    first, last = int(rows[0].get("epoch") or 1), int(rows[-1].get("epoch") or len(rows))
    of = f" of {planned} planned" if planned else ""
    if rows is log:
        title = f"The whole training run (the log.csv beside {name}): epochs {first}–{last}{of}; {name} is epoch {epoch}"
    else:
        title = f"Training history stored in {name}: epochs {first}–{last}{of}, up to the checkpoint's epoch"
        if planned and last < int(planned):
            title += "; the run's log.csv, with any later epochs, is not beside it"
    return rows, title, (epoch, f"{name}: epoch {epoch} (evaluated)")


def checkpoint_curves_png(checkpoint: Mapping[str, Any], checkpoint_path: Path | str, path: Path | str) -> Path:
    """``osmseg eval``'s curves.png: the training of the checkpoint it evaluated, titled with what
    it shows, the checkpoint's epoch marked (:func:`checkpoint_curves`)."""
    rows, title, mark = checkpoint_curves(checkpoint, checkpoint_path)
    return training_curves_png(rows, path, title=title, mark=mark)


# --------------------------------------------------------------------------- per-class IoU


def draw_per_class_iou(fig: Figure, metrics: Mapping[str, Any], class_table: Mapping[str, Any]) -> Axes:
    """:func:`per_class_iou_png`'s picture on ``fig``; returns its axes."""
    colours = {name: rgb for _, name, rgb in _classes(class_table)}
    by_id = {cid: rgb for cid, _, rgb in _classes(class_table)}
    items = list(metrics["per_class"].items())
    n = len(items)
    ax = fig.add_subplot()
    ys = np.arange(n)[::-1]
    for y, (name, c) in zip(ys, items):
        rgb = colours.get(name, by_id.get(int(c.get("id", -1)), (128, 128, 128)))
        iou = c.get("iou")
        if c.get("ignored") or iou is None:
            ax.text(0.01, y, "ignored (not scored)" if c.get("ignored") else "absent from ground truth",
                    va="center", fontsize=8, color="0.4")
            continue
        ax.barh(y, iou, color=_rgb01(rgb), edgecolor="0.2", linewidth=0.6, height=0.75)
        ax.text(min(iou + 0.01, 0.9), y, f"{iou:.3f}", va="center", fontsize=8)
    miou = metrics.get("miou")
    if miou is not None:
        line = ax.axvline(miou, color="0.2", linestyle="--", linewidth=1, label=f"mIoU {miou:.3f}")
        legend_below(fig, [line])  # under the axes: inside them it hid the value of a bar
    ax.set_yticks(ys, [name for name, _ in items])
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(-0.6, n - 0.4)
    ax.set_xlabel("IoU")
    ax.set_title("Per-class IoU")
    return ax


def per_class_iou_png(metrics: Mapping[str, Any], class_table: Mapping[str, Any], path: Path | str) -> Path:
    """Horizontal bars of each class's IoU in its class colour, with the mIoU as a dashed line
    named in a legend under the bars.

    Classes absent from the ground truth (IoU ``null``) are listed as "absent", not drawn as 0.
    """
    with _figure(6.5, max(2.5, 0.32 * len(metrics["per_class"]) + 1.5)) as fig:
        draw_per_class_iou(fig, metrics, class_table)
        return _save(fig, path)
