"""Resumable build state: one small JSON file per finished attempt, written atomically.

A build is a list of *slots* (one per requested sample). Slot ``i`` tries seeded centres
``(seed, i, 0)``, ``(seed, i, 1)``, ... until one is accepted or ``max_tries`` is reached.
Each finished attempt leaves ``.osmseg-build/attempts/SSSSS-TT.json``; a finished slot
leaves ``.osmseg-build/slots/SSSSS.json``. Because a slot's outcome depends only on the
seed, the slot number and the (cached) data, an interrupted build rerun with the same
command redoes nothing finished and ends byte-identical to an uninterrupted one, and a
build split with ``--shard K/N`` (slots ``i % N == K-1``) gives the same dataset as one run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from osmseg.errors import DatasetError
from osmseg.output.atomic import atomic_write_text

STATE_DIR = ".osmseg-build"


def atomic_write_json(path: Path, obj: Any) -> None:
    """Atomically write ``obj`` as stable (sorted, indented) JSON."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, ensure_ascii=False) + "\n")


class BuildState:
    """The ``.osmseg-build`` folder of one output directory."""

    def __init__(self, out_dir: Path) -> None:
        self.root = out_dir / STATE_DIR

    def check_config(self, config: dict[str, Any]) -> None:
        """Record the build's identity, or refuse to mix two different builds in one folder.

        ``config`` holds only what decides the dataset's content (seed, area, zoom, sources,
        classes, thresholds), in its JSON form; options such as ``--offline`` or ``--shard``
        may change freely. A folder whose recorded build never finished an attempt (the
        command failed at its first request: a wrong key, a typo in a URL) holds nothing of
        that build, so a corrected command takes it over instead of being refused.
        """
        path = self.config_path
        recorded = self.recorded_config()
        if recorded is not None and recorded != config:
            if self.has_work():
                changed = sorted(k for k in set(recorded) | set(config) if recorded.get(k) != config.get(k))
                raise DatasetError(
                    f"{self.root.parent} holds a different build (differs in: {', '.join(changed)}); "
                    "use a new --out, or the same options to resume it"
                )
            recorded = None  # nothing was built with it: the new command takes the folder over
        if recorded is None:
            atomic_write_json(path, config)

    @property
    def config_path(self) -> Path:
        return self.root / "config.json"

    def recorded_config(self) -> dict[str, Any] | None:
        """The identity recorded by the first run in this folder, or None."""
        path = self.config_path
        if not path.exists():
            return None
        try:
            recorded = json.loads(path.read_text())
        except (OSError, ValueError):
            if not self.has_work():
                return None  # a torn file with nothing built after it: start afresh
            raise DatasetError(f"{path} is unreadable; delete {self.root} to start the build over") from None
        return recorded if isinstance(recorded, dict) else None

    def has_work(self) -> bool:
        """True once any attempt or slot of this folder's build has finished."""
        return any(any((self.root / d).glob("*.json")) for d in ("attempts", "slots"))

    def _attempt_path(self, slot: int, attempt: int) -> Path:
        return self.root / "attempts" / f"{slot:05d}-{attempt:02d}.json"

    def _slot_path(self, slot: int) -> Path:
        return self.root / "slots" / f"{slot:05d}.json"

    def attempt(self, slot: int, attempt: int) -> dict[str, Any] | None:
        """The recorded outcome of one attempt, or None if it never finished."""
        return _read_json(self._attempt_path(slot, attempt))

    def record_attempt(self, slot: int, attempt: int, outcome: dict[str, Any]) -> None:
        atomic_write_json(self._attempt_path(slot, attempt), outcome)
        (self.root / "failures" / f"{slot:05d}-{attempt:02d}.json").unlink(missing_ok=True)  # it worked now

    def record_failure(self, slot: int, attempt: int, reason: str) -> None:
        """Note why an attempt could not fetch its data (not an outcome: a rerun tries it again)."""
        atomic_write_json(self.root / "failures" / f"{slot:05d}-{attempt:02d}.json",
                          {"slot": slot, "attempt": attempt, "reason": reason})

    def slot(self, slot: int) -> dict[str, Any] | None:
        """The final outcome of a slot (accepted sample or gave up), or None if unfinished."""
        return _read_json(self._slot_path(slot))

    def record_slot(self, slot: int, outcome: dict[str, Any]) -> None:
        atomic_write_json(self._slot_path(slot), outcome)


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError:
        # Only possible if the file was edited by hand: atomic writes never leave halves.
        raise DatasetError(f"{path} is corrupt; delete it and rerun the same command to redo that attempt") from None
