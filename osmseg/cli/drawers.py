"""How the command line shows the steps the library reports (:mod:`osmseg.runtime.progress`).

On a terminal, tqdm bars (:class:`ProgressBars`) that leave nothing behind: the command's
summary says what was done. In a log (stderr a file or a pipe: ``make demo 2> log``, Slurm, CI)
plain lines (:class:`ProgressLines`), never a ``\\r``: a line per tenth of a task or per minute,
whichever comes first, one at its end, and one for every step that carries measured values (an
epoch of training: its losses, validation mIoU and time). ``--no-progress`` and ``-q`` silence
both. Imports: osmseg core, click and tqdm.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Literal

import click
from tqdm import tqdm

from osmseg.runtime.progress import Progress, Step
from osmseg.units import noun, percent, seconds

__all__ = ["PROGRESS_DEFAULT", "Mode", "ProgressBars", "ProgressLines", "progress_drawer", "progress_mode"]

#: how a command shows progress: bars on a terminal, lines in a log, or nothing
Mode = Literal["bars", "lines"]
PROGRESS_DEFAULT = "on, unless -q"


def progress_mode(asked: bool | None, verbosity: int, stream: Any = None) -> Mode | None:
    """How to show progress on ``stream`` (stderr): as ``--progress``/``--no-progress`` asked,
    else not at all under ``-q``; bars when it is a terminal, plain lines when it is a log.

    >>> progress_mode(True, -1, open("/dev/null", "w")), progress_mode(False, 0), progress_mode(None, -1)
    ('lines', None, None)
    >>> progress_mode(None, 0, stream=open("/dev/null", "w"))
    'lines'
    """
    if asked is False or (asked is None and verbosity < 0):
        return None
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return "bars" if isatty is not None and isatty() else "lines"


def _value(name: str, value: float | None) -> str:
    """A measured value as a log reads it: ``train loss 0.4123``; a duration named ``... seconds``
    in seconds (``epoch 3.91 s``).

    >>> _value("val mIoU", 0.512345), _value("epoch seconds", 3.9123), _value("val loss", None)
    ('val mIoU 0.5123', 'epoch 3.91 s', 'val loss -')
    """
    if name.endswith(" seconds") and value is not None:
        return f"{name.removesuffix(' seconds')} {seconds(value)}"
    return f"{name} {'-' if value is None else format(value, '.4g')}"


class ProgressBars:
    """Draws :class:`osmseg.runtime.progress.Step` reports as tqdm bars on stderr, one bar per task.

    A bar opens at its task's first step and closes when the task finishes; :meth:`close`
    closes what a failed or interrupted command left open. Bars do not stay on screen: the
    command's summary says what was done.
    """

    def __init__(self) -> None:
        self._bars: dict[str, tqdm] = {}

    def __call__(self, step: Step) -> None:
        bar = self._bars.get(step.task)
        if bar is None:
            bar = tqdm(total=step.total, desc=step.task, unit=step.unit, file=sys.stderr, dynamic_ncols=True,
                       leave=False)
            self._bars[step.task] = bar
        if step.total != bar.total:
            bar.total = step.total
        if step.info or step.values:
            bar.set_postfix_str(", ".join([f"{k}={v}" for k, v in step.info]
                                          + [_value(k, v) for k, v in step.values]), refresh=False)
        bar.update(step.done - bar.n)
        if step.finished:
            self._bars.pop(step.task).close()

    def close(self) -> None:
        for task in reversed(list(self._bars)):
            self._bars.pop(task).close()


def duration(secs: float) -> str:
    """A time span as a log line says it.

    >>> duration(4.4), duration(352), duration(3 * 3600 + 125)
    ('4 s', '5 min 52 s', '3 h 02 min')
    """
    whole = int(round(secs))
    if whole < 60:
        return f"{whole} s"
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


def _units(unit: str, count: int) -> str:
    """The unit after a count, plural unless one; nothing for tqdm's anonymous ``"it"``.

    >>> _units("batch", 7), _units("epoch", 2), _units("image", 1), _units("it", 3)
    (' batches', ' epochs', ' image', '')
    """
    return "" if unit == "it" else f" {noun(count, unit)}"


@dataclass
class _Open:
    """A task :class:`ProgressLines` has seen and that has not finished."""

    began: float       # the clock at its first step
    first: int         # units already done at its first step (a resumed build's)
    tenth: int         # the tenth of the task its last line reached
    inner: bool        # it began while another task ran (an epoch's batches within training)


class ProgressLines:
    """Draws :class:`osmseg.runtime.progress.Step` reports as plain lines for a log, never a ``\\r``::

        build: 3/30 samples (10%) in 12 s, about 1 min 48 s left; accepted 3, rejected 1
        train: 1/8 epochs (12%) in 1 min 58 s, about 13 min 46 s left; train loss 1.234, val loss 1.1, val mIoU 0.2345, epoch 1 min 58 s

    A task gets a line each time it passes a tenth of its total, at its end, and at every step
    that carries values (each epoch of training). A task begun while another runs (the batches of
    an epoch, the windows of one image among many) is the other's detail: it gets a line only
    when a minute has passed without any. So does any task between its tenths: a log shows a
    line at least every minute while steps arrive. ``clock`` and ``write`` are for tests.
    """

    def __init__(self, write: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic,
                 every_s: float = 60.0) -> None:
        self._write = write or (lambda line: click.echo(line, err=True))
        self._clock = clock
        self._every_s = every_s
        self._open: dict[str, _Open] = {}
        self._last_line = clock()

    @staticmethod
    def _tenth(step: Step) -> int:
        if step.total is None:
            return 0
        return 10 if step.total <= 0 else min(10, step.done * 10 // step.total)

    def __call__(self, step: Step) -> None:
        now = self._clock()
        task = self._open.get(step.task)
        if task is None:
            task = _Open(now, step.done, self._tenth(step), inner=bool(self._open))
            self._open[step.task] = task
        tenth = self._tenth(step)
        if (step.values or now - self._last_line >= self._every_s
                or (not task.inner and (step.finished or tenth > task.tenth))):
            self._write(self.line(step, now - task.began, step.done - task.first))
            self._last_line = now
            task.tenth = tenth
        if step.finished:
            del self._open[step.task]

    @staticmethod
    def line(step: Step, elapsed: float, counted: int) -> str:
        """The line of ``step``, ``elapsed`` seconds after its task's first step, which had
        ``counted`` fewer units done (the rate the time left is estimated from).

        >>> ProgressLines.line(Step("build", 3, 30, "sample", (("accepted", 3),)), 12.0, 3)
        'build: 3/30 samples (10%) in 12 s, about 1 min 48 s left; accepted 3'
        >>> ProgressLines.line(Step("build", 8, 12, "sample"), 8.0, 8).split(" in ")[0]  # rounded, not floored
        'build: 8/12 samples (67%)'
        >>> ProgressLines.line(Step("train", 2, 2, "epoch", (), (("train loss", 0.41234), ("epoch seconds", 1.5))), 3.1, 2)
        'train: 2/2 epochs (100%) in 3 s; train loss 0.4123, epoch 1.50 s'
        """
        if step.total is None:
            text = f"{step.task}: {step.done:,}{_units(step.unit, step.done)}"
        else:
            text = f"{step.task}: {step.done:,}/{step.total:,}{_units(step.unit, step.total)} ({percent(step.done, step.total)})"
        text += f" in {duration(elapsed)}"
        if step.total is not None and not step.finished and counted > 0:
            text += f", about {duration(elapsed / counted * (step.total - step.done))} left"
        extra = [f"{name} {value:,}" for name, value in step.info] + [_value(k, v) for k, v in step.values]
        return text + ("; " + ", ".join(extra) if extra else "")


@contextmanager
def progress_drawer(mode: Mode | None) -> Iterator[Progress | None]:
    """The callback a command passes to the library for ``mode`` (:func:`progress_mode`): bars,
    lines, or None, so that nothing is drawn and nothing is counted. Bars left open by a failed
    or interrupted command are closed on the way out."""
    if mode is None:
        yield None
        return
    if mode == "lines":
        yield ProgressLines()
        return
    bars = ProgressBars()
    try:
        yield bars
    finally:
        bars.close()
