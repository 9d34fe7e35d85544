"""Which class tables a run's labels and its model are in, and whether they can be compared.

A label mask is class ids, and ids mean nothing without their table: id 3 is "grass" in
``classes13.toml``, "natural" in ``classes6.toml``, "Road" in ``camvid.toml``. Reading the labels
of one table as another's counts one class's pixels as another's, with numbers that look fine.
So every command that puts a model's classes beside labels asks here first, and refuses (exit
2, one line naming both tables and their first difference) what cannot be compared:

* ``osmseg train`` (:func:`run_tables`): the labels' table is the dataset's own (``manifest.json``
  or ``classes.toml``), else ``--classes``, else a preset's; the model learns the preset's table,
  else ``--classes``, else the labels'. A table that maps another (``classes6.toml``, whose
  ``base`` is ``classes13.toml``) turns the labels into the model's classes.
* ``osmseg eval`` (:func:`eval_correspondence`): the checkpoint's table against the dataset's (or
  the ``--pair`` labels', when a GeoTIFF's class tags or their dataset say it); through a shipped
  mapping in either direction, or the user's own ``--mapping``.
* ``osmseg predict`` (:func:`check_mask_folder`): masks written into a dataset folder must be in
  its classes.

The rules are :func:`osmseg.classmatch.correspondence`'s. Imports: osmseg core and training.datasets.patches.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rasterio.errors import RasterioError

from osmseg.classes import ClassTable, load_class_table
from osmseg.classmatch import Correspondence, correspondence, difference, same_classes, shipped_mapped_tables, within
from osmseg.errors import ClassTablesDiffer, ConfigError, DatasetError
from osmseg.images import is_tiff
from training.datasets.patches import dataset_class_table
from training.models.networks import PRESETS

__all__ = ["has_class_table", "run_tables", "model_classes", "eval_correspondence", "check_mask_folder"]

#: the folders of an osmseg dataset that hold one file per sample
SAMPLE_FOLDERS = ("images", "labels", "segmented", "geo")

#: what ``eval`` suggests when its tables differ (options ``eval`` has)
EVAL_FIX = ("evaluate it on labels of its classes, or compare both through a class mapping "
            "(--mapping FILE, e.g. inria-buildings)")


def has_class_table(root: Path) -> bool:
    """Whether dataset ``root`` says what its label ids mean (manifest.json or classes.toml)."""
    return (Path(root) / "manifest.json").is_file() or (Path(root) / "classes.toml").is_file()


def _table_file(root: Path) -> str:
    """Where dataset ``root``'s table is written, for messages."""
    return str(Path(root) / ("manifest.json" if (Path(root) / "manifest.json").is_file() else "classes.toml"))


def _mapped(*tables: ClassTable | None) -> list[ClassTable]:
    """``tables`` that map another (a ``base``), then the shipped ones."""
    return [t for t in tables if t is not None and t.base is not None] + shipped_mapped_tables()


def run_tables(dataset: Path, classes: str | None, model: str) -> tuple[ClassTable, ClassTable, np.ndarray | None]:
    """``(the labels' table, the model's table, the lookup from label ids to model ids or None)``
    of ``osmseg train DATASET [--classes CLASSES] --model MODEL`` (see the module doc)."""
    own = dataset_class_table(dataset) if has_class_table(dataset) else None
    given = load_class_table(str(classes)) if classes is not None else None  # a broken table: refused here
    preset = load_class_table(PRESETS[model]) if model in PRESETS else None
    labels = own or given or preset  # without a table of its own, --classes says what the labels mean
    if labels is None:
        raise ConfigError(f"{dataset} has no manifest.json or classes.toml, and --model {model} is not one of "
                          f"{', '.join(sorted(PRESETS))}; give the class table of the labels with --classes FILE.toml")
    if own is not None and preset is not None and given is not None and not same_classes(given, preset):
        raise ClassTablesDiffer(
            f"--model {model} predicts the classes of {preset.name!r}, --classes {classes} gives those of "
            f"{given.name!r} ({difference(given, preset, '--classes', f'--model {model}')}): leave out --classes, or "
            f"name a model of your own (--model NAME) to learn the table of --classes")
    learnt = preset or (given if own is not None else None) or labels
    if preset is not None:
        model_is, fix = (f"--model {model}", "train a model of your own name (--model NAME) on the labels' table, "
                         "or give labels of the model's classes")
    else:
        model_is, fix = (f"--model {model} with --classes {classes}",
                         f"leave out --classes ({_table_file(dataset)} says what the labels mean), or give a table "
                         "that maps the dataset's classes (as classes6.toml maps classes13.toml's)")
    labels_are = (f"but {_table_file(dataset)} is labelled with" if own is not None else
                  f"but --classes {classes} says the labels are in" if given is not None else
                  f"but {dataset} is labelled with")
    match = correspondence(labels, learnt, _mapped(learnt, given), outputs_may_map=False, model_is=model_is,
                           labels_are=labels_are, fix=fix)
    return labels, match.table, match.labels


def model_classes(model: str, dataset_table: ClassTable) -> tuple[ClassTable, np.ndarray | None]:
    """The table a model named ``model`` learns on labels of ``dataset_table``, and the lookup from
    the labels' ids to it (None when they are the same): a preset's table (``airsegnet6`` on a
    13-class dataset learns the 6-class mapping), else the dataset's own."""
    if model not in PRESETS:
        return dataset_table, None
    table = load_class_table(PRESETS[model])
    match = correspondence(dataset_table, table, _mapped(table), outputs_may_map=False, model_is=f"--model {model}",
                           labels_are="but the dataset is labelled with",
                           fix="train a model of your own name (--model NAME) on the dataset's table")
    return match.table, match.labels


def _pair_table(label: Path) -> tuple[ClassTable, str] | None:
    """The table a ``--pair`` label file says it is in: a GeoTIFF's class tags, else the dataset it
    lies in (``DATASET/labels/NAME.png``); None when nothing says."""
    if is_tiff(label):
        from osmseg.output.geotiff import read_class_table

        try:
            table = read_class_table(label)
        except (OSError, RasterioError, DatasetError):  # unreadable here: the evaluation's own reading says why
            table = None
        if table is not None:
            return table, str(label)
    root = Path(label).parent.parent
    if Path(label).parent.name == "labels" and has_class_table(root):
        return dataset_class_table(root), _table_file(root)
    return None


def eval_correspondence(checkpoint: dict[str, Any], checkpoint_path: Path, model: ClassTable, dataset: Path | None,
                        pairs: Sequence[tuple[Path, Path]]) -> Correspondence | None:
    """How ``osmseg eval`` compares the labels with ``model``'s outputs (without ``--mapping``):
    None when nothing says what the labels' ids mean (they are taken as the model's); a
    ClassTablesDiffer when their table cannot be compared with the model's."""
    found: list[tuple[ClassTable, str]] = []
    if dataset is not None:
        if has_class_table(dataset):
            found.append((dataset_class_table(dataset), _table_file(dataset)))
    else:
        for _, label in pairs:
            table = _pair_table(label)
            if table is not None and not any(same_classes(table[0], t) for t, _ in found):
                found.append(table)
    if not found:
        return None
    if len(found) > 1:
        (a, where_a), (b, where_b) = found[:2]
        raise ConfigError(f"the --pair labels are in different class tables ({a.name!r} in {where_a}, {b.name!r} in "
                          f"{where_b}): evaluate them in separate runs")
    labels, where = found[0]
    trained_with = (checkpoint.get("config") or {}).get("classes")
    own: ClassTable | None = None
    if isinstance(trained_with, str):
        try:
            own = load_class_table(trained_with)  # a mapped table of the user's, if it is still there
        except ConfigError:
            own = None
    return correspondence(labels, model, _mapped(own), model_is=str(checkpoint_path),
                          labels_are=f"but {where} is labelled with", fix=EVAL_FIX)


def check_mask_folder(out_dir: Path, model: ClassTable, checkpoint: Path) -> None:
    """ClassTablesDiffer when ``osmseg predict --out`` is a dataset folder (or one of its
    ``labels/``-like folders) whose table the model's masks are not in: they would sit among labels
    that say another table."""
    out_dir = Path(out_dir)
    for root in (out_dir, out_dir.parent if out_dir.name in SAMPLE_FOLDERS else None):
        if root is None or not has_class_table(root):
            continue
        folder = dataset_class_table(root)
        if not within(model, folder):
            raise ClassTablesDiffer(
                f"{checkpoint} predicts the classes of {model.name!r}, but --out {out_dir} is "
                f"{'a dataset' if root == out_dir else 'in a dataset'} labelled "
                f"with {folder.name!r} ({_table_file(root)}; {difference(model, folder, 'the model', 'the dataset')}): "
                "its masks would be read as the dataset's classes; give another --out")
