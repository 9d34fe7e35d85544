"""The files of a training run's folder that are rewritten every epoch: log.csv, curves.png, TensorBoard.

:class:`RunFiles` writes them from rank 0 only (the other processes of a torchrun hold the same
history): the log is rewritten whole from the history, so a resumed run's log has no gaps, and
the checkpoints' paths (``last.pt``, ``best.pt``, ``model.pt``) are named here once.

Imports: osmseg core, training.devices and (for curves.png) training.evaluation.figures.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path
from typing import Any

from osmseg.output.atomic import atomic_write_bytes
from training.devices import Dist

logger = logging.getLogger(__name__)

__all__ = ["LOG_FIELDS", "RunFiles"]


LOG_FIELDS = ("epoch", "lr", "train_loss", "val_loss", "val_miou", "val_pixel_accuracy", "seconds")


class RunFiles:
    """The files of a training run's output folder; only rank 0 writes them."""

    def __init__(self, out_dir: Path, d: Dist, tensorboard: bool) -> None:
        self.out = out_dir
        self.d = d
        self.writer = None
        if d.is_main and tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self.writer = SummaryWriter(str(out_dir / "tensorboard"))
            except ImportError:  # tensorboard is optional
                self.writer = None

    @property
    def last(self) -> Path:
        return self.out / "last.pt"

    @property
    def best(self) -> Path:
        return self.out / "best.pt"

    @property
    def model(self) -> Path:
        return self.out / "model.pt"

    def write_log(self, history: list[dict[str, Any]]) -> None:
        """Rewrite log.csv from the whole history (so a resumed run's log has no gaps)."""
        if not self.d.is_main:
            return
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=LOG_FIELDS, lineterminator="\n")
        writer.writeheader()
        for row in history:
            writer.writerow({k: row.get(k) for k in LOG_FIELDS})
        atomic_write_bytes(self.out / "log.csv", buf.getvalue().encode())
        if self.writer is not None:
            row = history[-1]
            for key in ("train_loss", "val_loss", "val_miou", "val_pixel_accuracy", "lr"):
                if row.get(key) is not None:
                    self.writer.add_scalar(key, row[key], row["epoch"])
            self.writer.flush()
        try:
            from training.evaluation.figures import training_curves_png

            training_curves_png(history, self.out / "curves.png")
        except ImportError:  # matplotlib is part of the train extra; never fail a run over a picture
            logger.warning("matplotlib missing: no curves.png")

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
