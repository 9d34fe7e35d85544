"""Class tables: which OSM tags become which class, with colours and draw order.

Tables are data files in ``data_manifests/`` (``classes13.toml`` for the 13 OSM classes,
``classes6.toml`` for AirSegNet6, which maps the 13 classes onto 6). Index 0 is always
"unlabeled": no OSM feature covers the pixel.

>>> t = load_class_table("classes13.toml")
>>> t.by_name["water"].color
(119, 242, 242)
>>> len(t.classes), t.num_classes
(13, 14)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from osmseg.errors import ClassTableError
from osmseg.manifests import load_toml

RGB = tuple[int, int, int]


@dataclass(frozen=True)
class Rule:
    """One tag rule: all of ``tags`` must match and the geometry must be of ``geometry`` kind.

    A tag value ``"*"`` matches any value, a list matches any of its values; a key written
    ``"!key"`` must be absent.
    """

    geometry: str
    tags: dict[str, Any]

    def matches(self, tags: Any) -> bool:
        """True if the OSM ``tags`` (a mapping, or osmium TagList) satisfy this rule."""
        for key, wanted in self.tags.items():
            if key.startswith("!"):
                if key[1:] in tags:
                    return False
                continue
            value = tags.get(key) if hasattr(tags, "get") else None
            if value is None:
                return False
            if wanted == "*":
                if value == "no":
                    return False
                continue
            if isinstance(wanted, list):
                if value not in wanted:
                    return False
            elif value != wanted:
                return False
        return True


@dataclass(frozen=True)
class ClassDef:
    """One class: id (label value), name, RGB colour, draw order, tag rules and line widths."""

    id: int
    name: str
    color: RGB
    order: int = 0
    rules: tuple[Rule, ...] = ()
    width_key: str | None = None
    default_width: float | None = None
    lane_width: float | None = None
    widths: dict[str, float] = field(default_factory=dict)
    coastline: bool = False
    sources: tuple[str, ...] = ()  # for mapped tables: names of base classes mapped here


@dataclass(frozen=True)
class ClassTable:
    """An ordered set of classes plus the unlabeled class 0."""

    name: str
    classes: tuple[ClassDef, ...]
    unlabeled: ClassDef
    description: str = ""
    base: "ClassTable | None" = None  # for mapped tables (classes6): the table rules come from

    @property
    def num_classes(self) -> int:
        """Number of label values including unlabeled (max id + 1)."""
        return max(c.id for c in self.classes) + 1

    @property
    def by_name(self) -> dict[str, ClassDef]:
        return {c.name: c for c in (self.unlabeled, *self.classes)}

    @property
    def by_id(self) -> dict[int, ClassDef]:
        return {c.id: c for c in (self.unlabeled, *self.classes)}

    def palette(self) -> np.ndarray:
        """``(256, 3)`` uint8 colour lookup table indexed by class id (unused ids black)."""
        lut = np.zeros((256, 3), dtype=np.uint8)
        for c in (self.unlabeled, *self.classes):
            lut[c.id] = c.color
        return lut

    def colorize(self, labels: np.ndarray) -> np.ndarray:
        """Class-index image ``(H, W)`` to an RGB image ``(H, W, 3)`` with the class colours."""
        return self.palette()[labels]

    def lookup_from_base(self) -> np.ndarray:
        """For a mapped table: ``(256,)`` uint8 array mapping base-table ids to this table's ids."""
        if self.base is None:
            return np.arange(256, dtype=np.uint8)
        lut = np.zeros(256, dtype=np.uint8)
        base_ids = {c.name: c.id for c in self.base.classes}
        for c in self.classes:
            for src in c.sources:
                lut[base_ids[src]] = c.id
        return lut

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (id, name, colour) for manifests and checkpoints."""
        return {
            "name": self.name,
            "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in (self.unlabeled, *self.classes)],
        }


def _color(value: Any, where: str) -> RGB:
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(v, int) and 0 <= v <= 255 for v in value)):
        raise ClassTableError(f"{where}: color must be three integers 0..255, got {value!r}")
    return (value[0], value[1], value[2])


def load_class_table(name: str = "classes13.toml") -> ClassTable:
    """Read a class table from ``data_manifests/`` (or a path), checking it as it goes."""
    raw = load_toml(name)
    try:
        un = raw["unlabeled"]
        unlabeled = ClassDef(id=int(un["id"]), name=un["name"], color=_color(un["color"], f"{name} unlabeled"))
        if unlabeled.id != 0:
            raise ClassTableError(f"{name}: unlabeled must have id 0")
        base = load_class_table(raw["base"]) if "base" in raw else None
        classes = []
        for entry in raw["classes"]:
            where = f"{name} class {entry.get('name', '?')!r}"
            rules = tuple(Rule(geometry=r["geometry"], tags=dict(r["tags"])) for r in entry.get("rules", ()))
            for r in rules:
                if r.geometry not in ("area", "line", "point"):
                    raise ClassTableError(f"{where}: geometry must be area, line or point, got {r.geometry!r}")
            sources = tuple(entry.get("from", ()))
            if base is not None:
                unknown = [s for s in sources if s not in base.by_name]
                if unknown:
                    raise ClassTableError(f"{where}: maps unknown base classes {unknown}")
            classes.append(
                ClassDef(
                    id=int(entry["id"]),
                    name=entry["name"],
                    color=_color(entry["color"], where),
                    order=int(entry.get("order", 0)),
                    rules=rules,
                    width_key=entry.get("width_key"),
                    default_width=entry.get("default_width"),
                    lane_width=entry.get("lane_width"),
                    widths=dict(entry.get("widths", {})),
                    coastline=bool(entry.get("coastline", False)),
                    sources=sources,
                )
            )
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ClassTableError):
            raise
        raise ClassTableError(f"{name}: malformed class table ({exc!r}); see data_manifests/classes13.toml") from None
    ids = [c.id for c in classes]
    if len(set(ids)) != len(ids) or 0 in ids or not all(0 < i < 256 for i in ids):
        raise ClassTableError(f"{name}: class ids must be unique and in 1..255, got {ids}")
    return ClassTable(name=raw.get("name", name), description=raw.get("description", ""),
                      classes=tuple(classes), unlabeled=unlabeled, base=base)
