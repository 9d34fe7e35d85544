"""``--shard K/N``: one piece of work split into N commands, as array jobs split it.

A shard owns the items ``i`` with ``i % N == K - 1`` (a stable rule: the same item goes to the
same shard on every machine and every rerun). The builder splits its slots this way and a
region search (:mod:`localization.region.search`) its blocks. Imports: osmseg.errors.
"""

from __future__ import annotations

from dataclasses import dataclass

from osmseg.errors import ConfigError

__all__ = ["Shard"]


@dataclass(frozen=True)
class Shard:
    """``--shard K/N``: this process does items (slots, blocks) ``i`` with ``i % N == K - 1``."""

    index: int  # 1-based K
    count: int  # N

    @classmethod
    def parse(cls, text: str) -> Shard:
        """Parse ``K/N``.

        >>> Shard.parse("2/8")
        Shard(index=2, count=8)
        """
        try:
            k, n = (int(v) for v in text.split("/"))
        except ValueError:
            raise ConfigError(f"--shard {text!r}: expected K/N, e.g. 1/4") from None
        if not 1 <= k <= n:
            raise ConfigError(f"--shard {text!r}: need 1 <= K <= N")
        return cls(k, n)

    def owns(self, slot: int) -> bool:
        return slot % self.count == self.index - 1
