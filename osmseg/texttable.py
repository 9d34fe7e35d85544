"""Fixed-width text tables for people: one label over each column, whatever the values.

Every table a command prints (the methods of a benchmark, a region's answers, the top-k of a
localization, the per-class scores of ``osmseg eval`` and its ``metrics.txt``) goes through
:func:`text_table`, so none can have more values than labels, or a label beside its value: each
column is as wide as its widest cell, names are aligned left and numbers right, and columns are
two spaces apart, so a label of two words (``median m``) still reads, and parses, as one column.
Imports: the standard library only.

>>> print(text_table(["method", "median m", "recall"], [["profile", "0.53", "0.667"], ["paper", "93.35", "-"]]))
method   median m  recall
profile      0.53   0.667
paper       93.35       -
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = ["GAP", "text_table"]

#: what separates two columns: a cell may hold single spaces ("dirt road"), never two
GAP = "  "


def text_table(header: Sequence[str], rows: Iterable[Sequence[str]], left: int = 1) -> str:
    """``header`` over ``rows`` (strings, one per label): the first ``left`` columns aligned left,
    the others right. A row with another number of cells than labels is a bug: ValueError."""
    cells = [list(header), *(list(r) for r in rows)]
    for row in cells[1:]:
        if len(row) != len(header):
            raise ValueError(f"a table row has {len(row)} cells under {len(header)} labels: {row}")
        if any(GAP in c or "\n" in c for c in row):
            raise ValueError(f"a table cell holds two spaces or a line break: {row}")
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    return "\n".join(GAP.join(c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths))).rstrip()
                     for row in cells)
