"""``benchmarks/same_bytes.py``'s comparison: two output folders that differ only in the times they
record are the same; a changed figure, a missing file or a changed weight is named."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import torch
from conftest import REPO_ROOT

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))


def write(root: Path, loss: float, seconds: float, weight: float) -> None:
    (root / "run").mkdir(parents=True)
    (root / ".osmseg-build").mkdir()
    (root / ".osmseg-build" / "http.sqlite").write_bytes(str(seconds).encode())   # state: never compared
    (root / "results.json").write_text(json.dumps({"loss": loss, "timing": {"total_s": seconds},
                                                   "views": [{"error": 1.0, "localize_s": seconds}]}))
    (root / "run" / "log.csv").write_text(f"epoch,loss,seconds\n1,{loss},{seconds}\n")
    torch.save({"model": {"w": torch.full((2, 2), weight), "n": torch.tensor(3)}, "history": [{"loss": loss, "seconds": seconds}]},
               root / "run" / "last.pt")


def test_only_what_is_not_a_time_counts(tmp_path: Path) -> None:
    from same_bytes import compare

    write(tmp_path / "a", 0.5, 12.0, 1.0)
    write(tmp_path / "b", 0.5, 99.0, 1.0)        # the same run, slower
    assert compare(tmp_path / "a", tmp_path / "b") == (3, [])
    write(tmp_path / "c", 0.25, 12.0, 1.0)       # another loss: in the JSON, the CSV and the checkpoint
    assert compare(tmp_path / "a", tmp_path / "c")[1] == ["results.json", "run/last.pt", "run/log.csv"]
    write(tmp_path / "d", 0.5, 12.0, 1.5)        # another weight
    (tmp_path / "d" / "extra.png").write_bytes(b"x")
    assert compare(tmp_path / "a", tmp_path / "d")[1] == ["extra.png (only in the other commit's)", "run/last.pt"]
