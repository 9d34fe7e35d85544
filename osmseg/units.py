"""How osmseg writes a measured figure for people: one precision per kind of quantity.

Every command's summary, every picture's title and every figure the docs quote
(``docs/figures.py``) goes through these functions, so the same quantity reads the same
everywhere: a median error of ``119.32 m`` in the terminal is ``119.32 m`` in errors.png and in
the README, beside a table of ``0.32 m``.

=============  =============  =================================================================
quantity       written as     why this precision
=============  =============  =================================================================
metres         ``119.32 m``   centimetres: the best localizations are a third of a 0.3 m pixel
pixels         ``475.5 px``   a tenth of a pixel: about the centimetres above at 0.3 m/px
degrees        ``0.5°``       a tenth of a degree: an azimuth bin is 5°
ratios         ``0.925``      recall, accuracy, IoU, AUC, confidence, posterior (0..1): three
                              decimals show every step of 40 queries (0.025) exactly
seconds        ``0.188 s``    three significant digits: from 4.32 ms (``0.00432 s``) to
                              minutes, a time is as precise as its measurement
factors        ``2.66×``      three significant digits: how many times faster or closer
counts         ``1,525``      thousands separated
rates          ``9.9``        a tenth of a sample per second (``osmseg build``'s throughput)
grey levels    ``16.4``       a tenth of a level of 0-255, as the rejection reasons say it
=============  =============  =================================================================

A missing value (no answer, an undefined ratio) is ``-``. Data files (results.json,
metrics.json) keep their full precision: this is for text read by people.

>>> metres(119.3187), pixels(475.496), degrees(0.46), ratio(0.925), count(1525)
('119.32 m', '475.5 px', '0.5°', '0.925', '1,525')
>>> seconds(0.18812), seconds(0.0043219), seconds(21.0), seconds(1234.5), factor(2.658), factor(238.4)
('0.188 s', '0.00432 s', '21.0 s', '1,234 s', '2.66×', '238×')
>>> quantity(None, "m"), quantity(12.25, "px"), number(0.31999, "m"), number(0.9, "ratio")
('-', '12.2 px', '0.32', '0.900')

A column of a table holds one precision: :func:`column` writes every value of it with as many
decimals as its most exacting one needs (``0.0100`` and ``0.1200``, never ``0.0100`` over
``0.120``). A count and its noun agree (:func:`plural`): ``1 sample``, ``2 samples``.
"""

from __future__ import annotations

__all__ = ["DECIMALS", "SIGNIFICANT", "SYMBOLS", "column", "count", "degrees", "factor", "metres", "noun", "number",
           "percent", "pixels", "plural", "quantity", "ratio", "seconds"]

#: decimals written for each kind of quantity (the table above)
DECIMALS = {"m": 2, "px": 1, "deg": 1, "ratio": 3, "rate": 1, "grey": 1}
#: significant digits written for the kinds that span orders of magnitude
SIGNIFICANT = {"s": 3, "factor": 3}
#: what follows the number, per kind ("" for ratios)
SYMBOLS = {"m": " m", "px": " px", "deg": "°", "ratio": "", "s": " s", "factor": "×", "rate": "/s", "grey": ""}
MISSING = "-"


def number(value: float | None, kind: str) -> str:
    """``value`` at the precision of ``kind`` (a key of :data:`DECIMALS`), without its unit."""
    if value is None:
        return MISSING
    if kind in SIGNIFICANT:
        digits = SIGNIFICANT[kind]
        if abs(value) >= 10 ** digits:
            return f"{float(value):,.0f}"
        return f"{float(value):#.{digits}g}".rstrip(".")
    try:
        decimals = DECIMALS[kind]
    except KeyError:
        raise ValueError(f"unknown kind of quantity {kind!r}; known: {', '.join([*DECIMALS, *SIGNIFICANT])}") from None
    return f"{float(value):.{decimals}f}"


def quantity(value: float | None, kind: str) -> str:
    """``value`` at the precision of ``kind``, with its unit (``-`` when missing)."""
    text = number(value, kind)
    return text if value is None else text + SYMBOLS[kind]


def metres(value: float | None) -> str:
    return quantity(value, "m")


def pixels(value: float | None) -> str:
    return quantity(value, "px")


def degrees(value: float | None) -> str:
    return quantity(value, "deg")


def ratio(value: float | None) -> str:
    return quantity(value, "ratio")


def seconds(value: float | None) -> str:
    return quantity(value, "s")


def factor(value: float | None) -> str:
    return quantity(value, "factor")


def count(value: int | None) -> str:
    return MISSING if value is None else f"{int(value):,}"


def _decimals(value: float, kind: str) -> int:
    """Decimals :func:`number` writes ``value`` of ``kind`` with (0 for significant-digit kinds past
    their digits: ``1,234 s``)."""
    if kind not in SIGNIFICANT:
        number(value, kind)  # an unknown kind: its ValueError names the known ones
        return DECIMALS[kind]
    if value == 0 or abs(value) >= 10 ** SIGNIFICANT[kind]:
        return 0
    text = f"{abs(float(value)):#.{SIGNIFICANT[kind]}g}"
    if "e" in text:  # below 1e-4: the exponent says how far the digits start
        mantissa, exponent = text.split("e")
        return max(0, len(mantissa.split(".")[1]) - int(exponent))
    return len(text.split(".")[1]) if "." in text else 0


def column(values: list[float | None], kind: str) -> list[str]:
    """The values of one table column, each without its unit, all with the same decimals: as many
    as its most exacting value needs at the precision of ``kind`` (missing ones ``-``).

    >>> column([0.0100, 0.12, None], "s"), column([0.00432, 1.5], "s"), column([0.5, 12.25], "m")
    (['0.0100', '0.1200', '-'], ['0.00432', '1.50000'], ['0.50', '12.25'])
    >>> column([1234.5, 21.0], "s")
    ['1,234.5', '21.0']
    """
    present = [v for v in values if v is not None]
    if not present:
        return [MISSING] * len(values)
    decimals = max(_decimals(v, kind) for v in present)
    return [MISSING if v is None else f"{float(v):,.{decimals}f}" for v in values]


def noun(n: int, singular: str, many: str | None = None) -> str:
    """``singular`` for one, else its plural: ``many``, or the last word with -es after s, x, z, sh
    and a soft ch (tch, rch), -ies for a consonant's y, else -s.

    >>> noun(1, "sample"), noun(0, "class"), noun(2, "batch"), noun(2, "epoch"), noun(3, "query")
    ('sample', 'classes', 'batches', 'epochs', 'queries')
    >>> noun(2, "rendered panorama"), noun(2, "day"), noun(2, "index", "indexes")
    ('rendered panoramas', 'days', 'indexes')
    """
    if n == 1:
        return singular
    if many is not None:
        return many
    if singular.endswith(("s", "x", "z", "sh", "tch", "rch")):
        return singular + "es"
    if singular.endswith("y") and singular[-2:-1] not in ("a", "e", "i", "o", "u", ""):
        return singular[:-1] + "ies"
    return singular + "s"


def plural(n: int, singular: str, many: str | None = None) -> str:
    """A count and its noun, which agree (:func:`noun`), the count as :func:`count` writes it.

    >>> plural(1, "sample"), plural(4, "viewpoint"), plural(1, "subset"), plural(1525, "spatial group")
    ('1 sample', '4 viewpoints', '1 subset', '1,525 spatial groups')
    """
    return f"{count(n)} {noun(n, singular, many)}"


def percent(done: int, total: int) -> str:
    """How much of ``total`` is ``done``, rounded to a whole percent, but 100 % only when all is
    done and 0 % only when nothing is.

    >>> percent(8, 12), percent(1, 3), percent(199, 200), percent(1, 1000), percent(0, 0)
    ('67%', '33%', '99%', '1%', '100%')
    """
    if total <= 0 or done >= total:
        return "100%"
    share = round(100 * done / total)
    return f"{min(99, max(1 if done > 0 else 0, share))}%"
