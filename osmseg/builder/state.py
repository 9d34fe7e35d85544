"""Resumable build state: one small JSON file per finished attempt, written atomically.

A build is a list of *slots* (one per requested sample). Slot ``i`` tries seeded centres
``(seed, i, 0)``, ``(seed, i, 1)``, ... until one is accepted or ``max_tries`` is reached.
Each finished attempt leaves ``.osmseg-build/attempts/SSSSS-TT.json``; a finished slot
leaves ``.osmseg-build/slots/SSSSS.json``. Because a slot's outcome depends only on the
seed, the slot number and the (cached) data, an interrupted build rerun with the same
command redoes nothing finished and ends byte-identical to an uninterrupted one, and a
build split with ``--shard K/N`` (slots ``i % N == K-1``) gives the same dataset as one run.

A build holds its folder for its whole life (:meth:`BuildState.claim`, an OS lock that the
shards of the same build share: :mod:`osmseg.runtime.folderlock`), so a command with other options
started at the same moment is refused at once instead of writing its samples among ours.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, cast

from osmseg.builder.records import Attempt, SlotOutcome
from osmseg.errors import DatasetError
from osmseg.output.atomic import atomic_write_text
from osmseg.runtime.folderlock import STATE_DIR, FolderLock

#: The build state's folders of records and pictures (besides ``osm/`` and temporary ones).
STATE_SUBDIRS = ("attempts", "slots", "failures", "thumbnails", "holders")


def atomic_write_json(path: Path, obj: Any) -> None:
    """Atomically write ``obj`` as stable (sorted, indented) JSON."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, ensure_ascii=False) + "\n")


class BuildState:
    """The ``.osmseg-build`` folder of one output directory."""

    def __init__(self, out_dir: Path) -> None:
        self.root = out_dir / STATE_DIR
        self.identity: dict[str, Any] | None = None  # set by check_config
        self.lock = FolderLock(self.root)

    def claim(self, config: dict[str, Any], command: str) -> None:
        """Take the folder for the build ``config`` (its identity, as :meth:`check_config` takes it)
        until :meth:`release` or the end of this process: an OS lock, shared with processes of the
        same build (its shards and workers). Refuses, with what holds it, a folder that a build with
        other options holds now; otherwise checks or records the options (:meth:`check_config`).
        ``command`` (without secrets) names this process to a command that is refused."""
        with self.lock.deciding() as others:
            if others:
                self.identity = config
                recorded = self.recorded_config() or {}
                if recorded != config:
                    raise DatasetError(f"{self.root.parent} is being built by another osmseg build "
                                       f"({self.lock.describe_holders()}) with other options (differs in: "
                                       f"{', '.join(_differences(recorded, config)) or 'its options file'}): "
                                       "wait for it to end, or use another --out")
            else:
                self.check_config(config)
            self.lock.hold(command or "osmseg build")

    def join(self, config: dict[str, Any]) -> None:
        """Hold the folder with the build process that claimed it (a worker of that build)."""
        self.identity = config
        self.lock.hold("")

    def release(self) -> None:
        """Let go of the folder (the end of the process does it too)."""
        self.lock.release()

    def check_config(self, config: dict[str, Any]) -> None:
        """Record the build's identity, or refuse to mix two different builds in one folder.

        ``config`` holds only what decides the dataset's content (seed, area, zoom, sources,
        classes, thresholds), in its JSON form; options such as ``--offline`` or ``--shard``
        may change freely. A folder whose recorded build has no accepted sample yet (the command
        failed early: a wrong key, a typo in a URL, a zoom the provider lacks) holds nothing a
        user would miss, so a corrected command takes it over: the old build's rejected attempts
        and failure notes are cleared (they belong to the old options), then the new identity is
        recorded.
        """
        self.identity = config
        recorded = self.recorded_config()
        if recorded is not None and recorded != config:
            if self.has_samples():
                raise DatasetError(
                    f"{self.root.parent} holds a different build (differs in: {', '.join(_differences(recorded, config))}); "
                    "use a new --out, or the same options to resume it"
                )
            for folder in ("attempts", "slots", "failures"):  # the old options' work: not this build's
                for record in (self.root / folder).glob("*.json"):
                    record.unlink(missing_ok=True)
            recorded = None
        if recorded is None:
            atomic_write_json(self.config_path, config)

    @property
    def config_path(self) -> Path:
        return self.root / "config.json"

    @property
    def thumbnails(self) -> Path:
        """Folder of the small pictures the overview sheet is drawn from (see :mod:`osmseg.output.overview`)."""
        return self.root / "thumbnails"

    def recorded_config(self) -> dict[str, Any] | None:
        """The identity recorded by the first run in this folder, or None."""
        path = self.config_path
        if not path.exists():
            return None
        try:
            recorded = json.loads(path.read_text())
        except (OSError, ValueError):
            recorded = None
        if not isinstance(recorded, dict):
            if not self.has_samples():
                return None  # a torn or foreign file with nothing built after it: start afresh
            raise DatasetError(f"{path} is unreadable; delete {self.root} to start the build over")
        return recorded

    def has_samples(self) -> bool:
        """True once any attempt of this folder's build was accepted (sample files were written)."""
        for record in (self.root / "attempts").glob("*.json"):
            try:
                if json.loads(record.read_text()).get("status") == "accepted":
                    return True
            except (OSError, ValueError, AttributeError):
                return True  # unreadable: assume the worst, never throw work away
        return False

    def check_owner(self) -> None:
        """Refuse to go on when another command (other options) took the folder over meanwhile.

        Called before each record: a shard started with other options cannot then leave its
        samples in a folder whose manifest will describe another build.
        """
        if self.identity is None or self.recorded_config() == self.identity:
            return
        if not self.config_path.exists():
            raise DatasetError(f"{self.root.parent} was deleted while this build ran (its build state is gone): "
                               "run the same command again to build it anew")
        raise DatasetError(f"{self.root.parent} was taken over by a build with other options while this one "
                           "ran; use a new --out for one of them")

    def _attempt_path(self, slot: int, attempt: int) -> Path:
        return self.root / "attempts" / f"{slot:05d}-{attempt:02d}.json"

    def _slot_path(self, slot: int) -> Path:
        return self.root / "slots" / f"{slot:05d}.json"

    def attempt(self, slot: int, attempt: int) -> Attempt | None:
        """The recorded outcome of one attempt, or None if it never finished."""
        path = self._attempt_path(slot, attempt)
        data = _read_json(path)
        return None if data is None else Attempt.from_json(data, str(path))

    def record_attempt(self, slot: int, attempt: int, outcome: Attempt) -> None:
        self.check_owner()
        atomic_write_json(self._attempt_path(slot, attempt), outcome.to_json())
        (self.root / "failures" / f"{slot:05d}-{attempt:02d}.json").unlink(missing_ok=True)  # it worked now

    def record_failure(self, slot: int, attempt: int, reason: str) -> None:
        """Note why an attempt could not fetch its data (not an outcome: a rerun tries it again)."""
        atomic_write_json(self.root / "failures" / f"{slot:05d}-{attempt:02d}.json",
                          {"slot": slot, "attempt": attempt, "reason": reason})

    def slot(self, slot: int) -> SlotOutcome | None:
        """The final outcome of a slot (accepted sample or gave up), or None if unfinished."""
        path = self._slot_path(slot)
        data = _read_json(path)
        return None if data is None else SlotOutcome.from_json(data, str(path))

    def has_slot(self, slot: int) -> bool:
        """Whether the slot has its final outcome (without reading it)."""
        return self._slot_path(slot).exists()

    def reopen(self, slot: int, first: int, max_tries: int) -> None:
        """Make a finished slot unfinished from attempt ``first`` on, so that it is built again from
        there (its earlier attempts stand): used when a server's "no imagery here" rejected that
        attempt, a verdict every run asks again. The slot's record goes first, then the attempts'
        from the last back to ``first``: a process killed in between leaves an unfinished slot whose
        remaining records are still true, and the next run goes on from them."""
        self.check_owner()
        self._slot_path(slot).unlink(missing_ok=True)
        for attempt in reversed(range(first, max_tries)):
            self._attempt_path(slot, attempt).unlink(missing_ok=True)

    def record_slot(self, outcome: SlotOutcome) -> None:
        self.check_owner()
        atomic_write_json(self._slot_path(outcome.slot), outcome.to_json())


def _differences(recorded: dict[str, Any], config: dict[str, Any]) -> list[str]:
    """The options (identity keys) in which two builds differ.

    >>> _differences({"seed": 3, "zoom": 18}, {"seed": 4, "zoom": 18, "classes": "c6"})
    ['classes', 'seed']
    """
    return sorted(k for k in set(recorded) | set(config) if recorded.get(k) != config.get(k))


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    try:
        return cast("dict[str, Any] | None", json.loads(path.read_text()))
    except ValueError:
        # Only possible if the file was edited by hand: atomic writes never leave halves.
        raise DatasetError(f"{path} is corrupt; delete it and rerun the same command to redo that attempt") from None
