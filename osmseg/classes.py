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

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from osmseg.datafiles import find_data_file, load_toml
from osmseg.errors import ClassTableError, DatasetError

RGB = tuple[int, int, int]

#: Widths outside (0, MAX_WIDTH] metres are tagging errors ("width=300" on a footway): ignored.
MAX_WIDTH = 200.0

_LENGTH = re.compile(
    r"""^\s*(?:(?P<num>\d+(?:[.,]\d+)?)\s*(?P<unit>m|metres?|meters?|cm|km|ft|feet|mi)?"""
    r"""|(?P<feet>\d+(?:\.\d+)?)\s*'\s*(?:(?P<inches>\d+(?:\.\d+)?)\s*(?:"|''))?)\s*$""",
    re.IGNORECASE,
)
_UNIT_METRES = {"m": 1.0, "metre": 1.0, "metres": 1.0, "meter": 1.0, "meters": 1.0, "cm": 0.01,
                "km": 1000.0, "ft": 0.3048, "feet": 0.3048, "mi": 1609.344}


def parse_length(text: str | None) -> float | None:
    r"""Metres from an OSM length value (``width=*``, ``diameter_crown=*``); None if unreadable.

    OSM's default unit is the metre; feet and inches are written ``12'6"``.

    >>> parse_length("7.5"), parse_length("7,5 m"), parse_length("30 cm")
    (7.5, 7.5, 0.3)
    >>> parse_length("12'"), round(parse_length("12'6\"") or 0, 3), parse_length("10 ft")
    (3.6576, 3.81, 3.048)
    >>> parse_length("narrow"), parse_length(None), parse_length("0"), parse_length("2;3")
    (None, None, None, None)
    """
    if not text:
        return None
    m = _LENGTH.match(text)
    if m is None:
        return None
    if m.group("num") is not None:
        value = float(m.group("num").replace(",", ".")) * _UNIT_METRES[(m.group("unit") or "m").lower()]
    else:
        value = float(m.group("feet")) * 0.3048 + float(m.group("inches") or 0) * 0.0254
    value = round(value, 6)
    return value if 0 < value <= MAX_WIDTH else None


def parse_lanes(text: str | None) -> int | None:
    """Number of lanes from ``lanes=*`` (the first number of "2;3"); None if unreadable.

    >>> parse_lanes("2"), parse_lanes("2;3"), parse_lanes("two"), parse_lanes("0")
    (2, 2, None, None)
    """
    m = re.match(r"\s*(\d+)", text or "")
    if m is None:
        return None
    lanes = int(m.group(1))
    return lanes if 0 < lanes <= 20 else None


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

    def matches(self, tags: Any, geometry: str) -> bool:
        """True if one of this class's rules for ``geometry`` ("area", "line", "point") matches."""
        return any(r.geometry == geometry and r.matches(tags) for r in self.rules)

    def width_for(self, tags: Mapping[str, str], geometry: str = "line") -> float | None:
        """Ground width in metres to buffer a line (or the diameter of a point) of this class.

        First readable wins: the ``width`` tag (``diameter_crown`` for points), ``lanes`` times
        ``lane_width``, ``widths[value of width_key]``, ``default_width``.  None when the class
        gives no width at all (areas).

        >>> road = load_class_table().by_name["highway"]
        >>> road.width_for({"highway": "primary", "width": "12"}), road.width_for({"highway": "residential", "lanes": "2"})
        (12.0, 7.0)
        >>> road.width_for({"highway": "primary"}), road.width_for({"highway": "road", "width": "wide"})
        (10.0, 6.0)
        """
        tagged = parse_length(tags.get("diameter_crown" if geometry == "point" else "width"))
        if tagged is not None:
            return tagged
        lanes = parse_lanes(tags.get("lanes")) if self.lane_width and geometry == "line" else None
        if lanes is not None and self.lane_width:
            return lanes * float(self.lane_width)
        if self.width_key is not None and tags.get(self.width_key) in self.widths:
            return float(self.widths[tags[self.width_key]])
        return float(self.default_width) if self.default_width is not None else None


@dataclass(frozen=True)
class ClassTable:
    """An ordered set of classes plus the unlabeled class: id 0 in osmseg's tables; another id
    where a dataset has its own convention (CamVid's void is 11: ``camvid.toml``)."""

    name: str
    classes: tuple[ClassDef, ...]
    unlabeled: ClassDef
    description: str = ""
    base: ClassTable | None = None  # for mapped tables (classes6): the table rules come from
    hidden: tuple[Rule, ...] = ()  # features not visible from above (tunnels...): never drawn

    @property
    def num_classes(self) -> int:
        """Number of label values including unlabeled (max id + 1)."""
        return max(c.id for c in (self.unlabeled, *self.classes)) + 1

    @property
    def by_name(self) -> dict[str, ClassDef]:
        return {c.name: c for c in (self.unlabeled, *self.classes)}

    @property
    def by_id(self) -> dict[int, ClassDef]:
        return {c.id: c for c in (self.unlabeled, *self.classes)}

    def classify(self, tags: Any, geometry: str) -> ClassDef | None:
        """The first class (in file order) with a rule for ``geometry`` that ``tags`` match.

        >>> t = load_class_table()
        >>> t.classify({"highway": "residential", "surface": "gravel"}, "line").name
        'dirt road'
        >>> t.classify({"highway": "residential"}, "line").name, t.classify({"highway": "residential"}, "area")
        ('highway', None)
        """
        for c in self.classes:
            if c.matches(tags, geometry):
                return c
        return None

    def is_hidden(self, tags: Any) -> bool:
        """True if ``tags`` mark a feature that cannot be seen from above (``hidden`` rules).

        >>> t = load_class_table()
        >>> t.is_hidden({"highway": "primary", "tunnel": "yes"}), t.is_hidden({"highway": "primary", "tunnel": "no"})
        (True, False)
        """
        return any(r.matches(tags) for r in self.hidden)

    def rule_keys(self, *geometries: str) -> frozenset[str]:
        """Tag keys that some rule for one of ``geometries`` requires (for pre-filtering OSM data).

        >>> sorted(load_class_table().rule_keys("point"))
        ['natural']
        """
        return frozenset(k for c in self.classes for r in c.rules if r.geometry in geometries
                         for k in r.tags if not k.startswith("!"))

    @property
    def coastline_class(self) -> ClassDef | None:
        """The class that sea built from ``natural=coastline`` is drawn as (None: no sea)."""
        return next((c for c in self.classes if c.coastline), None)

    def palette(self) -> np.ndarray:
        """``(256, 3)`` uint8 colour lookup table indexed by class id (unused ids black)."""
        lut = np.zeros((256, 3), dtype=np.uint8)
        for c in (self.unlabeled, *self.classes):
            lut[c.id] = c.color
        return lut

    def colorize(self, labels: np.ndarray) -> np.ndarray:
        """Class-index image ``(H, W)`` to an RGB image ``(H, W, 3)`` with the class colours.

        ``np.take`` rather than fancy indexing: the same pixels, ~4x faster on a 1280 px mask.
        """
        return np.take(self.palette(), np.asarray(labels), axis=0)

    @property
    def has_rules(self) -> bool:
        """Whether the table can draw OSM: its classes (or, mapped, its base's) carry tag rules. A
        table read back from a manifest or a checkpoint (:meth:`from_dict`) names classes only."""
        rules = self.base or self
        return any(c.rules for c in rules.classes)

    def lookup_from_base(self) -> np.ndarray:
        """For a mapped table: ``(256,)`` uint8 array mapping base-table ids to this table's ids."""
        if self.base is None:
            return np.arange(256, dtype=np.uint8)
        lut = np.full(256, self.unlabeled.id, dtype=np.uint8)  # base classes this table drops are unlabeled
        base_ids = {c.name: c.id for c in self.base.classes}
        for c in self.classes:
            for src in c.sources:
                lut[base_ids[src]] = c.id
        return lut

    def names_by_id(self, count: int | None = None) -> list[str]:
        """Class names indexed by class id, ``0 .. count - 1`` (default: ``num_classes``).

        The table lists classes in rule order (``classes13.toml`` puts dirt road, id 12, second),
        so its ``classes`` are never indexed by position: this is the list a confusion matrix,
        a model's output channels or a legend is indexed with. Ids the table does not define
        are named ``classN``.

        >>> load_class_table().names_by_id()[:4], load_class_table().names_by_id()[12]
        (['unlabeled', 'building', 'highway', 'grass'], 'dirt road')
        """
        n = self.num_classes if count is None else count
        known = self.by_id
        return [known[i].name if i in known else f"class{i}" for i in range(n)]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (id, name, colour) for manifests and checkpoints; :meth:`from_dict` reads it."""
        out: dict[str, Any] = {
            "name": self.name,
            "classes": [{"id": c.id, "name": c.name, "color": list(c.color)} for c in (self.unlabeled, *self.classes)],
        }
        if self.unlabeled.id != 0:  # osmseg's own tables keep the form they always had
            out["unlabeled"] = self.unlabeled.id
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "class table") -> ClassTable:
        """A table from its :meth:`to_dict` form (manifest.json, checkpoints, GeoTIFF tags).

        The one reader of that form: ids must be unique integers in 0..255 with the unlabeled
        id (``unlabeled``, default 0) and at least one class more, colours three integers 0..255. Tag rules are not part of
        the form: the result names and colours classes, it does not rasterise OSM.

        >>> t = load_class_table("classes6.toml")
        >>> ClassTable.from_dict(t.to_dict()).to_dict() == t.to_dict()
        True
        >>> ClassTable.from_dict({"classes": [{"id": 1, "name": "a", "color": [0, 0, 0]}]}, "x.json")
        Traceback (most recent call last):
        osmseg.errors.DatasetError: x.json: class ids must be unique, in 0..255, with the unlabeled id (0) and one class more
        """
        try:
            entries = data["classes"]
            defs = [ClassDef(id=int(c["id"]), name=str(c["name"]), color=_color(list(c["color"]), where))
                    for c in entries]
        except (KeyError, TypeError, ValueError, ClassTableError):
            raise DatasetError(f"{where}: classes must be a list of {{id, name, color}} "
                               "with colours of three integers 0..255") from None
        ids = [c.id for c in defs]
        void = data.get("unlabeled", 0) if isinstance(data, Mapping) else 0
        if (len(set(ids)) != len(ids) or not all(0 <= i < 256 for i in ids) or void not in ids or len(defs) < 2):
            raise DatasetError(f"{where}: class ids must be unique, in 0..255, with the unlabeled id ({void}) and "
                               "one class more")
        unlabeled = next(c for c in defs if c.id == void)
        name = data.get("name", "dataset") if isinstance(data, Mapping) else "dataset"
        return cls(name=str(name), classes=tuple(c for c in defs if c.id != void), unlabeled=unlabeled)


def _color(value: Any, where: str) -> RGB:
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(v, int) and 0 <= v <= 255 for v in value)):
        raise ClassTableError(f"{where}: color must be three integers 0..255, got {value!r}")
    return (value[0], value[1], value[2])


def check_distinct_colors(name: str, classes: tuple[ClassDef, ...]) -> None:
    """ClassTableError naming the first two classes (unlabeled included) that share a colour.

    The colour masks (``segmented/*.png``, ``*_color.png``) are read back by colour, so two
    classes of one colour would make them ambiguous.

    >>> a, b = ClassDef(1, "building", (255, 255, 0)), ClassDef(5, "forest", (255, 255, 0))
    >>> check_distinct_colors("mine.toml", (a, b))
    Traceback (most recent call last):
    osmseg.errors.ClassTableError: mine.toml: classes 'building' (id 1) and 'forest' (id 5) have the same colour [255, 255, 0]: give each class its own colour, or the colour masks cannot tell them apart
    """
    seen: dict[RGB, ClassDef] = {}
    for c in classes:
        first = seen.setdefault(c.color, c)
        if first is not c:
            raise ClassTableError(
                f"{name}: classes {first.name!r} (id {first.id}) and {c.name!r} (id {c.id}) have the same colour "
                f"{list(c.color)}: give each class its own colour, or the colour masks cannot tell them apart")


def machine_name(name: str) -> str:
    """A class name as files and catalogues spell it (letters, digits, ``-``, ``_``): the STAC
    classification extension's ``name``, which must keep the classes of a table apart.

    >>> machine_name("dirt road")
    'dirt_road'
    """
    return re.sub(r"[^0-9A-Za-z_-]+", "_", name).strip("_") or "class"


def _field(entry: Any, key: str, where: str) -> Any:
    """``entry[key]``, or a ClassTableError naming what lacks it."""
    if not isinstance(entry, Mapping):
        raise ClassTableError(f"{where} must be a table of id, name and color; see data_manifests/classes13.toml")
    if key not in entry:
        raise ClassTableError(f"{where} lacks {key!r}: give each class an id, a name and a color "
                              "(see data_manifests/classes13.toml)")
    return entry[key]


def _check_classes(name: str, unlabeled: ClassDef, classes: list[ClassDef]) -> None:
    """ClassTableError naming ``name`` unless the classes have distinct names, ids 0..N and colours."""
    everyone = (unlabeled, *classes)
    names: dict[str, ClassDef] = {}
    for c in everyone:
        first = names.setdefault(machine_name(c.name).lower(), c)
        if first is not c:
            same = "the same name" if first.name == c.name else "names that differ only in case or punctuation"
            raise ClassTableError(f"{name}: classes {first.name!r} (id {first.id}) and {c.name!r} (id {c.id}) have "
                                  f"{same}: give each class its own name")
    ids = sorted(c.id for c in everyone)
    if ids != list(range(len(ids))):
        repeated = sorted({i for i in ids if ids.count(i) > 1})
        missing = sorted(set(range(len(ids))) - set(ids))
        problem = f"id {repeated[0]} is given twice" if repeated else f"id {missing[0]} is missing"
        raise ClassTableError(f"{name}: class ids, unlabeled included, must be 0..{len(ids) - 1} each once ({problem}; "
                              f"got {ids}): number the classes 0..N")
    check_distinct_colors(name, everyone)


def load_class_table(name: str = "classes13.toml") -> ClassTable:
    """Read a class table from ``data_manifests/`` (or a path), checking it whole before it is used:
    distinct names and colours, ids 0..N (unlabeled included), every field there. A broken table
    is one ClassTableError that names the file and what to fix, before anything is built with it.

    A table is read once per process while its file is unchanged (the tables are frozen values):
    a command that meets the same table at several steps does not parse it again.
    """
    path = find_data_file(name)
    try:
        stat = path.stat()
    except OSError:
        return _read_class_table(name)  # its one-line error
    return _cached_class_table(name, str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=64)
def _cached_class_table(name: str, path: str, mtime_ns: int, size: int) -> ClassTable:
    """:func:`_read_class_table`, once per file version (the path, time and size are the key)."""
    return _read_class_table(name)


def _read_class_table(name: str) -> ClassTable:
    """The checks and parsing of :func:`load_class_table`."""
    raw = load_toml(name)
    try:
        un = raw.get("unlabeled")
        if un is None:
            raise ClassTableError(f'{name}: lacks the unlabeled class: add unlabeled = {{ id = 0, name = "unlabeled", '
                                  'color = [0, 0, 0] }')
        uid, uname, ucolour = (_field(un, key, f"{name} unlabeled") for key in ("id", "name", "color"))
        if isinstance(uid, bool) or not isinstance(uid, int):
            raise ClassTableError(f"{name} unlabeled: id must be an integer 0..255, got {uid!r}")
        unlabeled = ClassDef(id=uid, name=str(uname), color=_color(ucolour, f"{name} unlabeled"))
        if not 0 <= unlabeled.id < 256:
            raise ClassTableError(f"{name}: the unlabeled id must be in 0..255")
        base = load_class_table(raw["base"]) if "base" in raw else None
        classes = []
        entries = raw.get("classes")
        if not isinstance(entries, list) or not entries:
            raise ClassTableError(f"{name}: no [[classes]]: give at least one class besides unlabeled "
                                  "(see data_manifests/classes13.toml)")
        for number, entry in enumerate(entries, start=1):
            where = (f"{name} class {entry['name']!r}" if isinstance(entry, Mapping) and "name" in entry
                     else f"{name} [[classes]] entry {number}")
            cid, cname, colour = (_field(entry, key, where) for key in ("id", "name", "color"))
            if isinstance(cid, bool) or not isinstance(cid, int):
                raise ClassTableError(f"{where}: id must be an integer 0..255, got {cid!r}")
            rules = tuple(Rule(geometry=r["geometry"], tags=dict(r["tags"])) for r in entry.get("rules", ()))
            for r in rules:
                if r.geometry not in ("area", "line", "point"):
                    raise ClassTableError(f"{where}: geometry must be area, line or point, got {r.geometry!r}")
            if any(r.geometry != "area" for r in rules) and entry.get("default_width") is None:
                raise ClassTableError(f"{where}: has line or point rules, so it needs a default_width (metres)")
            sources = tuple(entry.get("from", ()))
            if base is not None:
                unknown = [s for s in sources if s not in base.by_name]
                if unknown:
                    raise ClassTableError(f"{where}: maps unknown base classes {unknown}")
            classes.append(
                ClassDef(
                    id=int(cid),
                    name=str(cname),
                    color=_color(colour, where),
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
        raise ClassTableError(f"{name}: malformed class table ({_what_is_wrong(exc)}); see data_manifests/classes13.toml"
                              ) from None
    _check_classes(name, unlabeled, classes)
    try:
        hidden = tuple(Rule(geometry="any", tags=dict(tags)) for tags in raw.get("hidden", ()))
    except (TypeError, ValueError):
        raise ClassTableError(f"{name}: hidden must be a list of tag tables like {{ tunnel = \"*\" }}") from None
    return ClassTable(name=raw.get("name", name), description=raw.get("description", ""),
                      classes=tuple(classes), unlabeled=unlabeled, base=base, hidden=hidden)


def _what_is_wrong(exc: Exception) -> str:
    """An exception from reading a table's entries in words (never its Python repr).

    >>> _what_is_wrong(KeyError("tags")), _what_is_wrong(ValueError("invalid literal for int() with base 10: 'x'"))
    ("an entry lacks 'tags'", "invalid literal for int() with base 10: 'x'")
    """
    if isinstance(exc, KeyError):
        return f"an entry lacks {exc.args[0]!r}" if exc.args else "an entry lacks a field"
    return str(exc).strip().splitlines()[0] if str(exc).strip() else "a value of the wrong type"

