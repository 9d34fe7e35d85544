"""``osmseg eval``: run a checkpoint over labelled images and report what the field reports.

Whole images are predicted the way ``osmseg predict`` does (split-join or rescale), compared
with their labels in one confusion matrix, and written to an output folder:
``metrics.json`` (pixel accuracy, per-class IoU/precision/recall/F1, mIoU over classes present
in the ground truth, FWIoU, the matrix), ``metrics.txt`` (a table), ``confusion_matrix.png``,
``per_class_iou.png``, ``panels.png`` (image | ground truth | prediction with a legend) and,
when the checkpoint carries its training history, ``curves.png`` (the whole run from the
``log.csv`` beside the checkpoint when it is that run's, else the history up to the
checkpoint's epoch; the checkpoint's epoch marked).

Foreign labelled data (e.g. Inria's building masks) is compared through a class mapping
(``data_manifests/inria-buildings.toml``) that maps both the labels and the model's classes
onto the evaluation classes.

A dataset's images are placed by its manifest (each sample's ``ground_resolution_m`` and
``bounds_3857``), so they are resampled for ``--resolution`` as a GeoTIFF of the same place
would be, and an evaluation far from the training data's resolution is warned about once.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from osmseg.classmatch import Correspondence
from osmseg.errors import DatasetError
from osmseg.images import read_label, read_rgb
from osmseg.output.atomic import atomic_write_bytes
from osmseg.output.manifest import refuse_busy
from osmseg.runtime.progress import Progress, track
from osmseg.units import plural
from training.datasets.classes import eval_correspondence
from training.datasets.patches import SampleFiles, dataset_fingerprint, discover_dataset
from training.evaluation.figures import (
    checkpoint_curves_png,
    confusion_matrix_png,
    per_class_iou_png,
    qualitative_panels,
)
from training.evaluation.metrics import ConfusionMatrix, EvalMetrics, Metrics, format_table, load_class_mapping
from training.inference.predict import predict_image
from training.inference.resolution import (
    GroundPlace,
    dataset_places,
    known_resolution,
    target_resolution,
    warn_resolutions,
)
from training.inference.windows import InferenceOptions
from training.models.checkpoint import load_checkpoint, model_from_checkpoint, run_checkpoint
from training.models.spec import ModelSpec

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalOptions:
    """How to predict and what to compare."""

    mode: str = "split-join"  # split-join | rescale
    join: str = "blend"  # blend | crop (split-join only)
    tta: bool = False
    split: str = "test"  # which of the checkpoint's splits, for the dataset it was trained on
    mapping: str | None = None  # class mapping TOML for foreign labels
    panels: int = 4  # samples shown in panels.png
    batch_size: int = 4
    device: str = "auto"  # auto: the GPU when there is one, as in training
    resolution_m: float | str | None = None  # resample georeferenced inputs to this ground pixel size first
    # (metres, or "model": the training data's, recorded in the checkpoint)


def choose_files(checkpoint: dict[str, Any], dataset: Path | None, pairs: Sequence[tuple[Path, Path]],
                 split: str) -> tuple[list[SampleFiles], str]:
    """The images to evaluate and a phrase saying which (recorded in metrics.json)."""
    if pairs:
        return [SampleFiles(name=Path(img).stem, image=Path(img), label=Path(lab)) for img, lab in pairs], "given pairs"
    if dataset is None:
        raise DatasetError("give a DATASET folder or --pair IMAGE LABEL")
    files, _ = discover_dataset(dataset)
    same = checkpoint.get("dataset_sha256") is not None and checkpoint.get("dataset_sha256") == dataset_fingerprint(dataset)
    if same and split != "all":
        wanted = set(checkpoint["splits"][split])
        chosen = [f for f in files if f.name in wanted]
        if (checkpoint.get("config") or {}).get("split_by") == "image" and split == "test":
            logger.warning("the model's splits were drawn by image (--split-by image): test images may share "
                           "ground with training images, so these numbers can be optimistic")
        return chosen, f"the '{split}' split the model was trained with ({plural(len(chosen), 'image')})"
    if split != "all":
        logger.warning("%s is not the dataset the model was trained on: evaluating all its %s "
                       "(--split applies to the training dataset only)", dataset, plural(len(files), "image"))
    return files, f"all {plural(len(files), 'image')} (not the dataset the model was trained on)"


def evaluate_images(model: torch.nn.Module, spec: ModelSpec, files: Sequence[SampleFiles], opts: EvalOptions,
                    match: Correspondence | None = None, progress: Progress | None = None,
                    places: Mapping[str, GroundPlace] | None = None,
                    ) -> tuple[Metrics, list[tuple[str, np.ndarray, np.ndarray, np.ndarray]], dict[str, Any]]:
    """Metrics over ``files``, the first panels' arrays, and the table they were computed in.

    ``match`` (:func:`training.datasets.classes.eval_correspondence`) says how the labels' ids and the
    model's are compared: the labels mapped onto the model's classes (a 13-class dataset for
    AirSegNet6), or the outputs onto the labels' (AirSegNet13 on a 6-class dataset); None: the
    labels are in the model's ids. ``places`` (:func:`dataset_places`, by sample name) place the
    images whose files do not say where they lie, for ``opts.resolution_m``. How far the images'
    ground resolution is from the training data's is said once for all of them
    (:func:`training.inference.predict.warn_resolutions`), before the first is predicted.
    """
    places = places or {}
    names = spec.class_names  # by output id: the table lists classes in rule order, not id order
    mapping = load_class_mapping(opts.mapping) if opts.mapping else None
    label_lut = match.labels if match is not None else None
    output_lut = match.outputs if match is not None else None
    if mapping is not None:
        eval_table = mapping.class_table_dict()
        matrix = ConfusionMatrix(mapping.num_classes, ignore_index=mapping.ignore_index)
        class_names = list(mapping.classes)  # a mapping's classes are numbered by position
    elif match is not None and output_lut is not None:  # compared in the labels' classes
        eval_table = match.table.to_dict()
        ignore = None if spec.ignore_index is None else int(output_lut[spec.ignore_index])
        matrix = ConfusionMatrix(match.table.num_classes, ignore_index=ignore)
        class_names = match.table.names_by_id()
    else:
        eval_table = spec.class_table
        matrix = ConfusionMatrix(spec.num_classes, ignore_index=spec.ignore_index)
        class_names = spec.class_names  # by id
    target_m = target_resolution(opts.resolution_m, spec)
    warn_resolutions([(str(f.image), known_resolution(f.image, places.get(f.name))) for f in files], spec, target_m)
    inference = InferenceOptions(opts.mode, opts.join, None, opts.tta, opts.batch_size, opts.device)
    panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
    for f in track(files, progress, "evaluate", unit="image"):
        rgb = read_rgb(f.image)
        truth = read_label(f.label)
        if truth.shape != rgb.shape[:2]:
            raise DatasetError(f"{f.label}: label is {truth.shape[1]}x{truth.shape[0]} but the image is "
                               f"{rgb.shape[1]}x{rgb.shape[0]}; give labels on the image's grid")
        pred = predict_image(model, spec, f.image, inference, target_m,  # exactly what `osmseg predict` writes
                             place=places.get(f.name), warn=False)
        if mapping is not None:
            truth, pred = mapping.map_gt(truth), mapping.map_pred(pred, names)
        else:
            truth = label_lut[truth] if label_lut is not None else truth
            pred = output_lut[pred] if output_lut is not None else pred
        matrix.update(torch.from_numpy(truth.astype(np.int64)).flatten(), torch.from_numpy(pred.astype(np.int64)).flatten())
        if len(panels) < opts.panels:
            panels.append((f.name, rgb, truth, pred))
    return matrix.compute(class_names), panels, eval_table


def run_eval(checkpoint_path: Path, dataset: Path | None, out_dir: Path, opts: EvalOptions,
             pairs: Sequence[tuple[Path, Path]] = (), progress: Progress | None = None) -> EvalMetrics:
    """Evaluate a checkpoint and write metrics and pictures into ``out_dir`` (``progress``: a
    step per image evaluated)."""
    refuse_busy(dataset, *(path for pair in pairs for path in pair))  # a build is writing them
    checkpoint_path = run_checkpoint(checkpoint_path)  # a run's folder: its model.pt
    checkpoint = load_checkpoint(checkpoint_path)
    model, spec = model_from_checkpoint(checkpoint_path, device=opts.device)
    # the labels' class table against the model's, before anything is predicted: refused when
    # they cannot be compared (--mapping declares how foreign labels compare)
    match = None if opts.mapping else eval_correspondence(checkpoint, checkpoint_path, spec.table, dataset, pairs)
    files, which = choose_files(checkpoint, dataset, pairs, opts.split)
    if not files:
        raise DatasetError(f"nothing to evaluate: the '{opts.split}' split is empty; use --split all")
    places = dataset_places(dataset) if not pairs else {}
    scores, panels, table = evaluate_images(model, spec, files, opts, match, progress, places)
    metrics: EvalMetrics = {**scores, "evaluated": {
        "checkpoint": str(checkpoint_path), "images": which, "mode": opts.mode, "join": opts.join, "tta": opts.tta,
        "mapping": opts.mapping, "resolution_m": target_resolution(opts.resolution_m, spec)}}
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_dir / "metrics.json", (json.dumps(metrics, indent=2, sort_keys=True) + "\n").encode())
    atomic_write_bytes(out_dir / "metrics.txt", (format_table(metrics) + "\n").encode())
    confusion_matrix_png(metrics, out_dir / "confusion_matrix.png")
    per_class_iou_png(metrics, table, out_dir / "per_class_iou.png")
    qualitative_panels(panels, table, out_dir / "panels.png")
    if checkpoint.get("history"):  # the whole run when its log.csv is at hand, the checkpoint's epoch marked
        checkpoint_curves_png(checkpoint, checkpoint_path, out_dir / "curves.png")
    return metrics
