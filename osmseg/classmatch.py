"""Whether labels of one class table and a model's outputs of another can be compared, and how.

Class ids mean nothing without their table: id 3 is "grass" in ``classes13.toml``, "natural" in
``classes6.toml``, "Road" in ``camvid.toml``. Reading the ids of one table as another's counts one
class's pixels as another's, with numbers that look fine. :func:`correspondence` says how two
tables compare (the same ids, or through a mapped table such as ``classes6.toml``, whose ``base``
is ``classes13.toml``), or refuses in one line naming both. ``osmseg train``, ``eval`` and
``predict`` ask it (:mod:`training.datasets.classes`). Imports: osmseg.classes, osmseg.datafiles, osmseg.errors.

>>> t13, t6 = load_class_table("classes13.toml"), load_class_table("classes6.toml")
>>> same_classes(t13, t13), within(t6, t13)
(True, False)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from osmseg.classes import ClassTable, load_class_table
from osmseg.datafiles import DATA_DIR, load_toml
from osmseg.errors import ClassTablesDiffer

__all__ = ["Correspondence", "correspondence", "difference", "same_classes", "shipped_mapped_tables", "within"]


def _ids(table: ClassTable) -> dict[int, str]:
    return {c.id: c.name for c in (table.unlabeled, *table.classes)}


def same_classes(a: ClassTable, b: ClassTable) -> bool:
    """Whether two tables give every id the same class name (and the same unlabeled id); their
    names, colours and rules may differ."""
    return a.unlabeled.id == b.unlabeled.id and _ids(a) == _ids(b)


def within(a: ClassTable, b: ClassTable) -> bool:
    """Whether every id of ``a`` names the same class in ``b`` (and unlabeled is the same id): an id
    of ``a`` means the same in ``b``, so data of ``a`` can be read as ``b``'s.

    >>> t13, t6 = load_class_table("classes13.toml"), load_class_table("classes6.toml")
    >>> within(t13, t13), within(t6, t13), within(ClassTable("b", t13.classes[:1], t13.unlabeled), t13)
    (True, False, True)
    """
    return a.unlabeled.id == b.unlabeled.id and _ids(a).items() <= _ids(b).items()


def difference(a: ClassTable, b: ClassTable, a_is: str = "the labels", b_is: str = "the model") -> str:
    """The first way the ids of ``a`` do not mean the same in ``b``, in words ('' when they do).

    >>> difference(load_class_table("classes6.toml"), load_class_table("classes13.toml"))
    "id 3 is 'natural' in the labels, 'grass' in the model"
    >>> difference(load_class_table("camvid.toml"), load_class_table("classes13.toml"))
    'unlabeled is id 11 in the labels, 0 in the model'
    """
    if a.unlabeled.id != b.unlabeled.id:
        return f"unlabeled is id {a.unlabeled.id} in {a_is}, {b.unlabeled.id} in {b_is}"
    theirs = _ids(b)
    for i, name in sorted(_ids(a).items()):
        if i not in theirs:
            return f"id {i} ({name!r}) of {a_is} is not among the ids 0..{max(theirs)} of {b_is}"
        if theirs[i] != name:
            return f"id {i} is {name!r} in {a_is}, {theirs[i]!r} in {b_is}"
    return ""


def shipped_mapped_tables() -> list[ClassTable]:
    """The mapped class tables shipped in ``data_manifests/`` (those with a ``base``, as
    ``classes6.toml`` maps the 13 classes onto 6): the declared ways between two tables."""
    found = []
    for path in sorted(DATA_DIR.glob("*.toml")):
        raw = load_toml(str(path))
        if "base" in raw and "classes" in raw and "unlabeled" in raw:
            found.append(load_class_table(str(path)))
    return found


@dataclass(frozen=True)
class Correspondence:
    """How labels of one class table and a model's outputs of another are compared: both in
    ``table``, the labels through ``labels`` and the outputs through ``outputs`` (``(256,)`` uint8
    lookups from their ids to ``table``'s; None where the ids are already ``table``'s)."""

    table: ClassTable
    labels: np.ndarray | None = None
    outputs: np.ndarray | None = None


def correspondence(labels: ClassTable, model: ClassTable, mapped: Sequence[ClassTable] = (), *,
                   outputs_may_map: bool = True, model_is: str = "the model",
                   labels_are: str = "but the labels are in", fix: str = "") -> Correspondence:
    """How labels of table ``labels`` compare with the outputs of a model of table ``model``.

    * the labels' ids mean the same in the model's table (:func:`within`): compared as they are;
    * a mapped table of ``mapped`` (``classes6.toml``) is the model's and its base holds the labels'
      ids: the labels are mapped onto the model's classes (AirSegNet6 on a 13-class dataset);
    * with ``outputs_may_map``, a mapped table holds the labels' ids and its base the model's: the
      model's outputs are mapped onto the labels' classes (AirSegNet13 on a 6-class dataset).

    Anything else cannot be compared (the ids of one table read as another's would count the
    pixels of one class as another's): a :class:`~osmseg.errors.ClassTablesDiffer` naming both tables
    and the first difference; ``model_is`` and ``labels_are`` ("but DATASET is labelled with") say
    where each table comes from, ``fix`` what to do.

    >>> t13, t6 = load_class_table("classes13.toml"), load_class_table("classes6.toml")
    >>> c = correspondence(t13, t6, [t6])
    >>> c.table.name, int(c.labels[4]), c.outputs
    ('osm6', 3, None)
    >>> c = correspondence(t6, t13, [t6])
    >>> c.table.name, c.labels, int(c.outputs[4])
    ('osm6', None, 3)
    >>> correspondence(load_class_table("camvid.toml"), t13, [t6], model_is="best.pt", fix="use --mapping")
    Traceback (most recent call last):
    osmseg.errors.ClassTablesDiffer: best.pt predicts the classes of 'osm13', but the labels are in 'camvid' (unlabeled is id 11 in the labels, 0 in the model): use --mapping
    """
    if within(labels, model):
        return Correspondence(model)
    for table in mapped:
        if table.base is not None and same_classes(table, model) and within(labels, table.base):
            return Correspondence(model, labels=table.lookup_from_base())
    if outputs_may_map:
        for table in mapped:
            if table.base is not None and within(labels, table) and within(model, table.base):
                return Correspondence(table, outputs=table.lookup_from_base())
    raise ClassTablesDiffer(f"{model_is} predicts the classes of {model.name!r}, {labels_are} {labels.name!r} "
                            f"({difference(labels, model)}){': ' + fix if fix else ''}")
