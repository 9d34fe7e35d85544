"""The null hypothesis of a search: how well does this query fit a place it was *not* taken at?

A view from another town still has a best place in this one, and a best place that stands a
little above its neighbours: its confidence alone (:mod:`localization.profile.search`) cannot tell
"here, and nowhere else" from "nowhere". The yardstick is the query itself, rearranged:
:func:`scrambled` cuts its profile into azimuth sectors and puts them back in a seeded order
that is no rotation (a derangement of the sectors' ring order), so it keeps everything the view
holds — how much of each class, at what distances, sector by sector — but not where each thing
stands relative to the others. No place was photographed that way, so the best score a scrambled
query reaches in a district is what the district gives *any* view with these contents: its
look-alike capacity. A query from here fits its place better than that; a query from elsewhere
does not (the region search compares the two: :mod:`localization.region.search`).

The scrambles are a function of the query's shape and the seed: the same for every block and
shard, and recorded nowhere because nothing about them is random beyond the fixed seed.

Imports: numpy, localization.profile.profiles.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from localization.profile.profiles import QueryProfile

__all__ = ["NULL_SECTORS", "NULL_SCRAMBLES", "null_queries", "sector_order", "scrambled"]

#: sectors the azimuth ring is cut into (45 degrees each)
NULL_SECTORS = 8
#: scrambled copies of a query searched beside it
NULL_SCRAMBLES = 2


def sector_order(sectors: int, seed: int) -> list[int]:
    """A seeded order of ``sectors`` (at least 5) sectors in which no two sectors that stood side
    by side on the ring still do, in either direction: neither a rotation nor a mirror image of
    the view (a street seen both ways looks much the same), nor a part of one.

    >>> order = sector_order(8, 0)
    >>> sorted(order) == list(range(8)), any((order[(i + 1) % 8] - order[i]) % 8 in (1, 7) for i in range(8))
    (True, False)
    >>> sector_order(8, 0) == sector_order(8, 0) != sector_order(8, 1)
    True
    """
    rng = np.random.default_rng(seed)
    while True:
        order = [int(v) for v in rng.permutation(sectors)]
        if all((order[(i + 1) % sectors] - order[i]) % sectors not in (1, sectors - 1) for i in range(sectors)):
            return order


def _rearranged(q: np.ndarray, order: list[int]) -> np.ndarray:
    bins = q.shape[-1]
    edges = np.linspace(0, bins, len(order) + 1).round().astype(int)
    return np.concatenate([q[..., edges[s]:edges[s + 1]] for s in order], axis=-1)


def scrambled(query: QueryProfile, seed: int, sectors: int = NULL_SECTORS) -> QueryProfile:
    """``query`` with its azimuth sectors in :func:`sector_order` (each camera-height variant alike).

    >>> q = QueryProfile(np.arange(16.0).reshape(1, 1, 16), np.array([5.0]), ("building",), None, 360.0)
    >>> s = scrambled(q, 0, sectors=8)
    >>> bool(s.q.sum() == q.q.sum()), sorted(s.q.ravel().tolist()) == q.q.ravel().tolist(), bool((s.q != q.q).any())
    (True, True, True)
    """
    order = sector_order(sectors, seed)
    variants = tuple(dataclasses.replace(v, q=_rearranged(v.q, order)) for v in query.variants)
    return dataclasses.replace(query, q=_rearranged(query.q, order), variants=variants)


def null_queries(query: QueryProfile, scrambles: int = NULL_SCRAMBLES) -> list[QueryProfile]:
    """The scrambled copies of ``query`` to search for the null (seeds 0 to ``scrambles - 1``).

    A query read at several camera heights (its ``variants``) gives one query whose variants are
    every copy's: a search scores each position once for all of them (the rays read once) and
    keeps the best, so its best score is the best of the copies searched one by one. Otherwise
    the copies themselves (a search of one variant may skip positions that cannot win).

    >>> q = QueryProfile(np.arange(16.0).reshape(1, 1, 16), np.array([5.0]), ("building",), None, 360.0)
    >>> [len(n.variants) for n in null_queries(q)]
    [0, 0]
    >>> both = null_queries(dataclasses.replace(q, variants=(q, dataclasses.replace(q, q=q.q * 2))))
    >>> len(both), len(both[0].variants), both[0].variants[2].q.tolist() == scrambled(q, 1).q.tolist()
    (1, 4, True)
    """
    copies = [scrambled(query, seed) for seed in range(max(1, scrambles))]
    if not query.variants:
        return copies
    variants = tuple(v for copy in copies for v in copy.variants)
    return [dataclasses.replace(copies[0], q=np.mean([v.q for v in variants], axis=0), variants=variants)]
