"""The colours of the marks every localization picture and map shares (class colours come from the
class table): the answers, the candidates or best distinct alternative, the truth. Kept apart from
:mod:`~localization.common.figures` so that a map that is not drawn with matplotlib (the region's
HTML map) uses the same colours without importing it.

Imports: nothing.
"""

from __future__ import annotations

__all__ = ["CANDIDATE", "TOP_K", "TRUTH"]

CANDIDATE = "#ff9900"
TOP_K = "#00c000"
TRUTH = "#ff1a1a"
