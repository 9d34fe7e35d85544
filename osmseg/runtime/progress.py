"""How far long work has got, told through a callback: the library reports, the caller draws.

A long-running function (``build``, ``training.run.train.run``, ``run_eval``, ``predict_files``,
``run_bench`` ...) takes ``progress: Progress | None`` and calls it with a :class:`Step` after
each unit of work. The command line turns steps into tqdm bars on a terminal and into a plain
line every tenth of a task or every minute in a log (:mod:`osmseg.cli.drawers`); a notebook or a
service may do anything else. Nothing in the library draws, prints or imports tqdm. Imports:
the standard library only.

>>> steps = []
>>> list(track("ab", steps.append, "letters", unit="letter"))
['a', 'b']
>>> [(s.task, s.done, s.total) for s in steps]
[('letters', 0, 2), ('letters', 1, 2), ('letters', 2, 2)]
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sized
from typing import NamedTuple, TypeVar

__all__ = ["Step", "Progress", "report", "track"]

T = TypeVar("T")


class Step(NamedTuple):
    """``done`` of ``total`` units of ``task`` finished (``total`` None when unknown).

    ``info`` are running counts worth showing beside the bar, e.g. ``(("accepted", 3),)``;
    ``values`` what the unit just finished measured, by the name people read (e.g. an epoch's
    ``(("train loss", 0.41), ("val mIoU", 0.52))``; None when undefined): a step with values is
    a result worth a line of its own in a log. A task ends when ``done == total``; the same
    ``task`` string always means the same bar.
    """

    task: str
    done: int
    total: int | None = None
    unit: str = "it"
    info: tuple[tuple[str, int], ...] = ()
    values: tuple[tuple[str, float | None], ...] = ()

    @property
    def finished(self) -> bool:
        """Whether this is the task's last step.

        >>> Step("x", 3, 3).finished, Step("x", 3, None).finished
        (True, False)
        """
        return self.total is not None and self.done >= self.total


Progress = Callable[[Step], None]


def report(progress: Progress | None, task: str, done: int, total: int | None, unit: str = "it",
           values: Mapping[str, float | None] | None = None, /, **info: int) -> None:
    """Call ``progress`` (when there is one) with the step ``done`` of ``total`` (``info``: running
    counts by name; ``values``: what the finished unit measured, see :class:`Step`).

    >>> report(print, "train", 1, 2, "epoch", {"train loss": 0.5})
    Step(task='train', done=1, total=2, unit='epoch', info=(), values=(('train loss', 0.5),))
    """
    if progress is not None:
        progress(Step(task, done, total, unit, tuple(info.items()), tuple((values or {}).items())))


def track(items: Iterable[T], progress: Progress | None, task: str, total: int | None = None,
          unit: str = "it") -> Iterator[T]:
    """Yield ``items``, reporting a step before the first (0 done) and after each one.

    ``total`` defaults to ``len(items)`` when it has one. A loop left early simply stops
    reporting; the caller's drawer closes what is left open.
    """
    if progress is None:
        yield from items
        return
    if total is None and isinstance(items, Sized):
        total = len(items)
    progress(Step(task, 0, total, unit))
    for done, item in enumerate(items, start=1):
        yield item
        progress(Step(task, done, total, unit))
