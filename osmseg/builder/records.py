"""What a build's attempts and slots ended in, as frozen values instead of ``{"status": ...}`` dicts.

A build fills *slots* (one per requested sample); each slot tries seeded centres, one
:class:`Attempt` each, until one is accepted. The slot's :class:`SlotOutcome` is what the
manifest, the datasheet and the summary are made from. Both are stored in ``.osmseg-build/``
as JSON by :class:`osmseg.builder.state.BuildState` through :meth:`to_json`/:meth:`from_json`, in the
shape earlier osmseg releases wrote, so a folder begun by one still resumes (and a resumed
build ends byte-identical to an uninterrupted one).

The entries they carry (``sample``, ``rejection``) are the manifest's own JSON entries
(:func:`osmseg.output.manifest.sample_entry`, :func:`~osmseg.output.manifest.rejection_entry`):
the documented dataset format, not build internals, held as the manifest's typed records
(:class:`~osmseg.output.manifest.SampleRecord`, :class:`~osmseg.output.manifest.RejectionRecord`).
Imports: osmseg.errors, osmseg.output.manifest.

>>> rejection = RejectionRecord(center=None, reason="unlabeled", detail="d")
>>> Attempt.from_json(Attempt.rejected(rejection).to_json()).status
'rejected'
>>> SlotOutcome.from_json(SlotOutcome(3, "gave_up", exhausted=True).to_json())
SlotOutcome(slot=3, status='gave_up', rejected=(), sample=None, exhausted=True, attempt=None, reason=None)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, get_args

from osmseg.errors import DatasetError
from osmseg.output.manifest import JsonObject, RejectionRecord, SampleRecord

__all__ = ["Attempt", "AttemptStatus", "SlotOutcome", "SlotStatus"]

AttemptStatus = Literal["accepted", "rejected", "exhausted"]
SlotStatus = Literal["accepted", "gave_up", "failed"]


def _status(data: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> Any:
    status = data.get("status") if isinstance(data, Mapping) else None
    if status not in allowed:
        raise DatasetError(f"{where}: status {status!r} is not one of {list(allowed)}; delete the file and rerun "
                           "the same command to redo it")
    return status


@dataclass(frozen=True)
class Attempt:
    """One centre tried for a slot: ``accepted`` (its ``sample`` entry was written), ``rejected``
    (its ``rejection`` entry says why, with any OSM problems met), or ``exhausted`` (with
    ``--no-overlap``, no block of the area was left to try)."""

    status: AttemptStatus
    sample: SampleRecord | None = None
    rejection: RejectionRecord | None = None

    @classmethod
    def accepted(cls, sample: SampleRecord) -> Attempt:
        return cls("accepted", sample=sample)

    @classmethod
    def rejected(cls, rejection: RejectionRecord) -> Attempt:
        return cls("rejected", rejection=rejection)

    @classmethod
    def exhausted(cls) -> Attempt:
        return cls("exhausted")

    def to_json(self) -> JsonObject:
        if self.status == "accepted" and self.sample is not None:
            return {"status": "accepted", "sample": self.sample.to_json()}
        if self.status == "rejected" and self.rejection is not None:
            return {"status": "rejected", **self.rejection.to_json()}
        return {"status": "exhausted"}

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "attempt record") -> Attempt:
        status = _status(data, get_args(AttemptStatus), where)
        if status == "accepted":
            return cls.accepted(SampleRecord.from_json(data.get("sample"), f"{where} sample"))
        if status == "rejected":
            return cls.rejected(RejectionRecord.from_json({k: v for k, v in data.items() if k != "status"}, where))
        return cls.exhausted()


@dataclass(frozen=True)
class SlotOutcome:
    """What one slot ended in: ``accepted`` (``sample``), ``gave_up`` after ``max_tries``
    rejections (or ``exhausted`` blocks), or ``failed``: a service kept failing at ``attempt``
    (``reason``), which is not recorded, so the same command later retries it. ``rejected``
    are the rejection entries of the attempts before the last, in order."""

    slot: int
    status: SlotStatus
    rejected: tuple[RejectionRecord, ...] = ()
    sample: SampleRecord | None = None
    exhausted: bool = False
    attempt: int | None = None
    reason: str | None = None

    @property
    def unplaced(self) -> int:
        """OSM objects of a class that could not be drawn (no located node), over all attempts."""
        found = sum(r.osm_unplaced or 0 for r in self.rejected)
        return found + ((self.sample.osm_unplaced or 0) if self.sample else 0)

    def to_json(self) -> JsonObject:
        out: JsonObject = {"slot": self.slot, "status": self.status, "rejected": [r.to_json() for r in self.rejected]}
        if self.status == "accepted":
            out["sample"] = None if self.sample is None else self.sample.to_json()
        elif self.status == "failed":
            out.update(attempt=self.attempt, reason=self.reason)
        if self.exhausted:
            out["exhausted"] = True
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "slot record") -> SlotOutcome:
        status = _status(data, get_args(SlotStatus), where)
        try:
            rejected = tuple(RejectionRecord.from_json(r, f"{where} rejected[{i}]")
                             for i, r in enumerate(data["rejected"]))
            return cls(slot=int(data["slot"]), status=status, rejected=rejected,
                       sample=SampleRecord.from_json(data["sample"], f"{where} sample") if status == "accepted" else None,
                       exhausted=bool(data.get("exhausted", False)), attempt=data.get("attempt"),
                       reason=data.get("reason"))
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: not a slot record ({exc}); delete the file and rerun the same command "
                               "to redo that sample") from None
