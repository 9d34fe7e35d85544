"""Segmentation metrics from a confusion matrix, and class mappings for foreign labelled data.

:class:`ConfusionMatrix` follows torchvision's ``references/segmentation`` recipe: every
batch adds ``bincount(target * n + pred)`` over the pixels whose target is not
``ignore_index`` to an ``int64`` ``n x n`` matrix kept on the inputs' device (no per-batch
copies to the CPU), and :meth:`ConfusionMatrix.reduce_from_all_processes` sums it across
DDP ranks. Every number is then derived from the matrix by :func:`metrics_from_matrix`
(rows are ground truth, columns predictions):

- IoU = TP / (TP + FP + FN), precision = TP / (TP + FP), recall = TP / (TP + FN),
  F1 = 2 TP / (2 TP + FP + FN);
- pixel accuracy = trace / sum; mean accuracy = mean recall over the classes present;
- mIoU = macro mean of IoU over the classes PRESENT IN THE GROUND TRUTH (support > 0).
  A class with no ground-truth pixel has no defined IoU: it is reported as ``null`` and
  left out of the mean, as in the Cityscapes/torchvision evaluations, so a test split that
  happens to contain no water does not pull the mean down with a meaningless zero;
- FWIoU = sum(support * IoU) / sum(support) (frequency-weighted IoU).

A ratio with a zero denominator is ``None`` (JSON ``null``), never NaN.

:class:`ClassMapping` (``data_manifests/*.toml``) says how the label values of a foreign
dataset (Inria's 0/255 buildings, CamVid's 11 classes, ...) and the class names a model
predicts both map onto a common set of evaluation classes.

>>> m = ConfusionMatrix(3, ignore_index=None, class_names=["a", "b", "c"])
>>> m.update(torch.tensor([0, 0, 1, 1]), torch.tensor([0, 1, 1, 1]))
>>> r = m.compute()
>>> r["pixel_accuracy"], r["per_class"]["b"]["iou"], r["per_class"]["c"]["iou"], r["miou"]
(0.75, 0.6666666666666666, None, 0.5833333333333333)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import torch
from torch import Tensor

from osmseg.datafiles import load_toml
from osmseg.errors import ConfigError, DatasetError
from osmseg.texttable import text_table
from osmseg.units import number

__all__ = [
    "ClassMetrics", "EvalMetrics", "Metrics",
    "ConfusionMatrix",
    "metrics_from_matrix",
    "format_table",
    "ClassMapping",
    "load_class_mapping",
    "IGNORE",
]

#: Evaluation id given to pixels a :class:`ClassMapping` says to ignore.
IGNORE = 255


def _ratio(num: float, den: float) -> float | None:
    """``num / den`` as a float, or None when ``den`` is 0 (JSON has no NaN).

    >>> _ratio(1, 4), _ratio(0, 0)
    (0.25, None)
    """
    return float(num) / float(den) if den else None


def _mean(values: Sequence[float | None]) -> float | None:
    """Mean of the non-None values; None when there are none.

    >>> _mean([0.5, None, 1.0]), _mean([None])
    (0.75, None)
    """
    kept = [v for v in values if v is not None]
    return sum(kept) / len(kept) if kept else None


class ConfusionMatrix:
    """Accumulates an ``n x n`` pixel confusion matrix (rows: ground truth, cols: prediction).

    ``ignore_index`` pixels of the target (e.g. 0 = unlabeled, an OSM gap is not a class) are
    not counted; it may lie outside ``0..n-1`` (255 for mapped foreign data). ``class_names``
    (indexed by id) name the classes in :meth:`compute`; by default they are ``"0"``, ``"1"``...
    """

    def __init__(self, num_classes: int, ignore_index: int | None = 0,
                 class_names: Sequence[str] | None = None) -> None:
        if num_classes < 1:
            raise ConfigError(f"num_classes must be at least 1, got {num_classes}")
        if class_names is not None and len(class_names) != num_classes:
            raise ConfigError(f"{len(class_names)} class names given for {num_classes} classes; give one name per class id")
        self.num_classes = num_classes
        self.ignore_index = ignore_index
        self.class_names = [str(n) for n in class_names] if class_names is not None else [str(i) for i in range(num_classes)]
        self.mat: Tensor | None = None

    def reset(self) -> None:
        """Forget everything counted so far."""
        self.mat = None

    def update(self, target: Tensor | np.ndarray, pred: Tensor | np.ndarray) -> None:
        """Count one batch. ``target`` and ``pred`` are class ids of the same shape.

        ``pred`` may also be logits with one more dimension (``N x C x H x W`` against an
        ``N x H x W`` target); their argmax over dim 1 is used. A target id outside
        ``0..n-1`` (other than ``ignore_index``) is a :class:`DatasetError`.
        """
        target = torch.as_tensor(target)
        pred = torch.as_tensor(pred, device=target.device)
        if pred.dim() == target.dim() + 1:
            pred = pred.argmax(1)
        if pred.shape != target.shape:
            raise DatasetError(f"prediction shape {tuple(pred.shape)} differs from target shape {tuple(target.shape)}")
        n = self.num_classes
        target = target.reshape(-1).to(torch.int64)
        pred = pred.reshape(-1).to(torch.int64)
        if self.ignore_index is not None:
            keep = target != self.ignore_index
            target, pred = target[keep], pred[keep]
        if self.mat is None:
            self.mat = torch.zeros((n, n), dtype=torch.int64, device=target.device)
        if target.numel() == 0:
            return
        lo, hi = int(target.min()), int(target.max())
        if lo < 0 or hi >= n:
            bad = lo if lo < 0 else hi
            raise DatasetError(f"ground-truth class id {bad} is outside 0..{n - 1}; the labels do not match "
                               f"the model's {n}-class table: for foreign labels give a class mapping "
                               "(osmseg eval --mapping, e.g. inria-buildings)")
        plo, phi = int(pred.min()), int(pred.max())
        if plo < 0 or phi >= n:
            raise DatasetError(f"predicted class id {plo if plo < 0 else phi} is outside 0..{n - 1}")
        self.mat += torch.bincount(target * n + pred, minlength=n * n).reshape(n, n)

    def reduce_from_all_processes(self) -> None:
        """Sum the matrix over all DDP ranks (in place); a no-op without torch.distributed.

        Every rank must call it (it is a collective), also a rank that saw no batch.
        """
        if not torch.distributed.is_available() or not torch.distributed.is_initialized():
            return
        if self.mat is None:
            device = torch.device("cuda", torch.cuda.current_device()) if (
                torch.distributed.get_backend() == "nccl") else torch.device("cpu")
            self.mat = torch.zeros((self.num_classes, self.num_classes), dtype=torch.int64, device=device)
        torch.distributed.barrier()
        torch.distributed.all_reduce(self.mat)

    def matrix(self) -> np.ndarray:
        """The counts so far as an ``int64`` numpy array (zeros before any update)."""
        if self.mat is None:
            return np.zeros((self.num_classes, self.num_classes), dtype=np.int64)
        return self.mat.detach().cpu().numpy().astype(np.int64)

    def compute(self, class_names: Sequence[str] | None = None) -> Metrics:
        """The metrics of :func:`metrics_from_matrix` for the counts so far (JSON-able).

        ``class_names`` (indexed by id) overrides the names given to the constructor.
        """
        names = self.class_names if class_names is None else class_names
        return metrics_from_matrix(self.matrix(), names, ignore_index=self.ignore_index)


class ClassMetrics(TypedDict, total=False):
    """One class's scores in :class:`Metrics` (``ignored`` only on the ignored class)."""

    id: int
    ignored: bool
    iou: float | None
    precision: float | None
    recall: float | None
    f1: float | None
    support: int
    predicted: int


class Metrics(TypedDict):
    """The scores of a confusion matrix (:func:`metrics_from_matrix`): what metrics.json holds.

    Ratios are None where undefined (0/0; the IoU of a class absent from the ground truth).
    """

    pixel_accuracy: float | None
    mean_accuracy: float | None
    miou: float | None
    fwiou: float | None
    num_pixels: int
    classes_present: int
    ignore_index: int | None
    class_names: list[str]
    per_class: dict[str, ClassMetrics]
    confusion_matrix: list[list[int]]


class EvalMetrics(Metrics):
    """``osmseg eval``'s metrics.json: the :class:`Metrics` and what was evaluated, and how."""

    evaluated: dict[str, Any]


def metrics_from_matrix(matrix: np.ndarray | Sequence[Sequence[int]], class_names: Sequence[str] | None = None,
                        ignore_index: int | None = None) -> Metrics:
    """All metrics of a confusion matrix (rows: ground truth, cols: prediction), JSON-able.

    Returns ``pixel_accuracy``, ``mean_accuracy`` (mean recall over classes present in the
    ground truth), ``miou`` (mean IoU over the classes present in the ground truth; absent
    classes have IoU ``None`` and are excluded), ``fwiou``, ``per_class`` (``{name: {id, iou,
    precision, recall, f1, support, predicted}}``, support = ground-truth pixels, predicted =
    pixels predicted as the class), ``confusion_matrix`` (list of lists), and for reference
    ``num_pixels``, ``classes_present``, ``class_names`` and ``ignore_index``.

    >>> r = metrics_from_matrix([[3, 1], [0, 0]], ["bg", "fg"])
    >>> r["per_class"]["fg"]
    {'id': 1, 'iou': None, 'precision': 0.0, 'recall': None, 'f1': None, 'support': 0, 'predicted': 1}
    >>> r["miou"], r["fwiou"], r["classes_present"]
    (0.75, 0.75, 1)
    """
    mat = np.asarray(matrix, dtype=np.int64)
    if mat.ndim != 2 or mat.shape[0] != mat.shape[1]:
        raise ConfigError(f"a confusion matrix must be square, got shape {mat.shape}")
    n = mat.shape[0]
    names = [str(c) for c in class_names] if class_names is not None else [str(i) for i in range(n)]
    if len(names) != n:
        raise ConfigError(f"{len(names)} class names given for a {n}x{n} confusion matrix")
    tp = np.diag(mat)
    support = mat.sum(axis=1)
    predicted = mat.sum(axis=0)
    total = int(mat.sum())
    per_class: dict[str, ClassMetrics] = {}
    ious: list[float | None] = []
    recalls: list[float | None] = []
    for i, name in enumerate(names):
        t, s, p = int(tp[i]), int(support[i]), int(predicted[i])
        iou = _ratio(t, s + p - t) if s else None  # absent from the ground truth: undefined
        recall = _ratio(t, s)
        ious.append(iou)
        recalls.append(recall)
        per_class[name] = {
            "id": i,
            **({"ignored": True} if i == ignore_index else {}),  # not scored (unlabeled: an OSM gap)
            "iou": iou,
            "precision": _ratio(t, p),
            "recall": recall,
            "f1": _ratio(2 * t, s + p) if s else None,
            "support": s,
            "predicted": p,
        }
    fw = sum(int(support[i]) * iou for i, iou in enumerate(ious) if iou is not None)
    return {
        "pixel_accuracy": _ratio(int(tp.sum()), total),
        "mean_accuracy": _mean(recalls),
        "miou": _mean(ious),
        "fwiou": _ratio(fw, total),
        "num_pixels": total,
        "classes_present": sum(1 for iou in ious if iou is not None),
        "ignore_index": ignore_index,
        "class_names": names,
        "per_class": per_class,
        "confusion_matrix": mat.tolist(),
    }


def format_table(metrics: Mapping[str, Any]) -> str:
    """A fixed-width table of per-class IoU, precision, recall, F1 and support, plus summaries.

    ``-`` marks an undefined value (0/0, or IoU of a class absent from the ground truth). A class
    the metrics leave out (the ignored one: unlabeled) is named under the table, not given a row
    without values.

    >>> print(format_table(metrics_from_matrix([[3, 1], [0, 0]], ["bg", "fg"])))
    class    IoU  precision  recall     F1  support
    -----------------------------------------------
    bg     0.750      1.000   0.750  0.857        4
    fg         -      0.000       -      -        0
    -----------------------------------------------
    pixel accuracy   0.750  (4 pixels)
    mean accuracy    0.750
    mIoU             0.750  (over 1 of 2 classes present in the ground truth)
    FWIoU            0.750
    """
    per_class = metrics["per_class"]
    scored = {name: c for name, c in per_class.items() if not c.get("ignored")}
    table = text_table(["class", "IoU", "precision", "recall", "F1", "support"],
                       [[name, *(number(c[k], "ratio") for k in ("iou", "precision", "recall", "f1")),
                         f"{c['support']:,}"] for name, c in scored.items()])
    rule = "-" * max(len(line) for line in table.splitlines())
    header, *rows = table.splitlines()
    lines = [header, rule, *rows, rule]
    ignored = [name for name in per_class if name not in scored]
    if ignored:
        lines.append(f"not scored: {', '.join(ignored)} (its pixels are left out, as in training)")
    present = metrics.get("classes_present", sum(1 for c in per_class.values() if c["iou"] is not None))

    def ratio_(key: str) -> str:
        return f"{number(metrics[key], 'ratio'):>6}"

    lines += [
        f"pixel accuracy  {ratio_('pixel_accuracy')}  ({metrics.get('num_pixels', 0):,} pixels)",
        f"mean accuracy   {ratio_('mean_accuracy')}",
        f"mIoU            {ratio_('miou')}  (over {present} of {len(scored)} classes present in the ground truth)",
        f"FWIoU           {ratio_('fwiou')}",
    ]
    return "\n".join(lines)


# --------------------------------------------------------------------------- class mappings

_DEFAULT_COLORS = [(0, 0, 0), (255, 255, 0), (50, 50, 255), (0, 100, 0), (119, 242, 242), (128, 181, 255),
                   (255, 0, 0), (255, 128, 0), (160, 32, 240), (128, 128, 128), (255, 255, 255), (139, 69, 19)]


@dataclass(frozen=True)
class ClassMapping:
    """How a foreign dataset's labels and a model's predictions map onto evaluation classes.

    ``classes`` are the evaluation classes (evaluation id = position); ``ground_truth`` maps a
    label value to an evaluation class, ``ignore`` lists label values left out of the metrics
    (void pixels), ``prediction`` maps a model class name to an evaluation class, with ``"*"``
    for every class not named. ``colors`` (optional) colour the evaluation classes in pictures.
    """

    name: str
    classes: tuple[str, ...]
    ground_truth: dict[int, str]
    prediction: dict[str, str]
    ignore: tuple[int, ...] = ()
    colors: dict[str, tuple[int, int, int]] = field(default_factory=dict)
    source: str = ""

    @property
    def num_classes(self) -> int:
        return len(self.classes)

    @property
    def ignore_index(self) -> int | None:
        """The evaluation id of ignored pixels (for :class:`ConfusionMatrix`), None if none are."""
        return IGNORE if self.ignore else None

    def map_gt(self, labels: np.ndarray) -> np.ndarray:
        """Foreign label values to evaluation ids (``uint8``; ignored values become :data:`IGNORE`).

        A value present in ``labels`` that the mapping does not list is a :class:`DatasetError`.
        """
        labels = np.asarray(labels)
        if not np.issubdtype(labels.dtype, np.integer):
            raise DatasetError(f"ground-truth labels must be integers, got {labels.dtype}; give an index mask, not a colour image")
        values = np.unique(labels)
        known = set(self.ground_truth) | set(self.ignore)
        unknown = [int(v) for v in values if int(v) not in known]
        if unknown:
            raise DatasetError(f"ground-truth value(s) {unknown[:10]} are not in class mapping {self.name!r} "
                               f"({self.source or 'ground_truth table'}); add them under [ground_truth] or to ignore")
        # every value present is listed, so all are >= 0 and a table up to the largest one will do
        lut = np.full(int(values.max(initial=0)) + 1, IGNORE, dtype=np.uint8)
        ids = {name: i for i, name in enumerate(self.classes)}
        for value, cls in self.ground_truth.items():
            if value < len(lut):
                lut[value] = ids[cls]
        return lut[labels.astype(np.intp)]

    def prediction_lookup(self, model_class_names: Sequence[str] | Mapping[int, str]) -> np.ndarray:
        """``(max model id + 1,)`` uint8 table: model class id -> evaluation id."""
        names = dict(model_class_names.items()) if isinstance(model_class_names, Mapping) else dict(enumerate(model_class_names))
        missing = [n for n in self.prediction if n != "*" and n not in names.values()]
        if missing:
            raise ConfigError(f"class mapping {self.name!r} names model classes {missing} that the model does not have "
                              f"(it has {sorted(names.values())}); fix [prediction]")
        ids = {name: i for i, name in enumerate(self.classes)}
        lut = np.zeros(max(names) + 1 if names else 1, dtype=np.uint8)
        for model_id, model_name in names.items():
            target = self.prediction.get(model_name, self.prediction.get("*"))
            if target is None:
                raise ConfigError(f"model class {model_name!r} is not mapped by class mapping {self.name!r}; "
                                  f"add it (or \"*\") under [prediction]")
            lut[model_id] = ids[target]
        return lut

    def map_pred(self, pred: np.ndarray, model_class_names: Sequence[str] | Mapping[int, str]) -> np.ndarray:
        """Model class ids to evaluation ids (``uint8``), via the model's class names (index = id)."""
        lut = self.prediction_lookup(model_class_names)
        pred = np.asarray(pred)
        if pred.size and (int(pred.min()) < 0 or int(pred.max()) >= len(lut)):
            raise DatasetError(f"predicted class id {int(pred.max())} is outside the model's {len(lut)} classes")
        return lut[pred.astype(np.int64)]

    def class_table_dict(self) -> dict[str, Any]:
        """The evaluation classes in ``ClassTable.to_dict()`` form, for pictures and reports."""
        return {
            "name": self.name,
            "classes": [{"id": i, "name": c, "color": list(self.colors.get(c, _DEFAULT_COLORS[i % len(_DEFAULT_COLORS)]))}
                        for i, c in enumerate(self.classes)],
        }


def _rgb(value: Any, where: str) -> tuple[int, int, int]:
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(v, int) and 0 <= v <= 255 for v in value)):
        raise ConfigError(f"{where}: a colour must be three integers 0..255, got {value!r}")
    return (value[0], value[1], value[2])


def load_class_mapping(path_or_name: str | Path) -> ClassMapping:
    """Read a class mapping TOML: a path, or a name in ``data_manifests/`` (``"inria-buildings"``).

    >>> m = load_class_mapping("inria-buildings")
    >>> m.classes, m.map_gt(np.array([[0, 255]], dtype=np.uint8)).tolist()
    (('background', 'building'), [[0, 1]])
    >>> m.map_pred(np.array([0, 1, 2]), ["unlabeled", "building", "highway"]).tolist()
    [0, 1, 0]
    """
    name = str(path_or_name)
    if not Path(name).exists() and not name.endswith(".toml"):
        name += ".toml"
    raw = load_toml(name)
    where = f"class mapping {name}"
    classes = raw.get("classes")
    if not (isinstance(classes, list) and classes and all(isinstance(c, str) and c for c in classes)):
        raise ConfigError(f"{where}: 'classes' must be a non-empty list of class names")
    if len(set(classes)) != len(classes) or len(classes) > 255:
        raise ConfigError(f"{where}: 'classes' must be unique and at most 255, got {classes}")

    def check_class(value: Any, key: str) -> str:
        if value not in classes:
            raise ConfigError(f"{where}: {key} maps to unknown class {value!r}; use one of {classes}")
        return str(value)

    gt_raw = raw.get("ground_truth")
    if not isinstance(gt_raw, dict) or not gt_raw:
        raise ConfigError(f"{where}: needs a [ground_truth] table of label value = \"class\"")
    ground_truth: dict[int, str] = {}
    for key, value in gt_raw.items():
        try:
            label = int(key)
        except ValueError:
            raise ConfigError(f"{where}: [ground_truth] key {key!r} is not an integer label value") from None
        if label < 0:
            raise ConfigError(f"{where}: [ground_truth] label value {label} is negative")
        ground_truth[label] = check_class(value, f"[ground_truth] {key}")
    ignore = raw.get("ignore", [])
    if not (isinstance(ignore, list) and all(isinstance(v, int) and v >= 0 for v in ignore)):
        raise ConfigError(f"{where}: 'ignore' must be a list of label values, got {ignore!r}")
    clash = sorted(set(ignore) & set(ground_truth))
    if clash:
        raise ConfigError(f"{where}: label values {clash} are both mapped and ignored; keep one")
    pred_raw = raw.get("prediction")
    if not isinstance(pred_raw, dict) or not pred_raw:
        raise ConfigError(f"{where}: needs a [prediction] table of model class = \"class\" (\"*\" for the rest)")
    prediction = {str(k): check_class(v, f"[prediction] {k}") for k, v in pred_raw.items()}
    colors = {check_class(k, "[colors]"): _rgb(v, f"{where} [colors] {k}") for k, v in raw.get("colors", {}).items()}
    unknown_keys = sorted(set(raw) - {"name", "description", "classes", "ground_truth", "ignore", "prediction", "colors"})
    if unknown_keys:
        raise ConfigError(f"{where}: unknown keys {unknown_keys}; see data_manifests/inria-buildings.toml")
    return ClassMapping(name=str(raw.get("name", Path(name).stem)), classes=tuple(classes), ground_truth=ground_truth,
                        prediction=prediction, ignore=tuple(ignore), colors=colors, source=str(name))
