"""Per-source token buckets of the lighting server: how many datagrams one source host may have
served per second and how much of the server's CPU time they may take (so one source's flood
is dropped for the cost of a dictionary look-up, before any parsing, and cannot delay other
devices' replies), and how many error replies it may be sent (a forged source address cannot
turn the server into a reflector)."""

from __future__ import annotations

from collections import OrderedDict


class SourceBuckets:
    """Token buckets keyed by source host: `rate_per_s` tokens a second, at most `burst` held.
    `rate_per_s` 0 turns the limit off. At most `max_sources` buckets are kept (the least
    recently used dropped first: a source seen again starts with a full bucket)."""

    def __init__(self, rate_per_s: float, burst: float, max_sources: int = 65536):
        self.rate, self.burst, self.max_sources = rate_per_s, burst, max_sources
        self._buckets: OrderedDict = OrderedDict()   # host -> [tokens, time of last refill]

    def allowed(self, host, now: float) -> bool:
        """True when `host` has tokens left at server time `now` (s); spends none (`charge`)."""
        if not self.rate or host is None:
            return True
        b = self._bucket(host, now)
        return b[0] > 0.0

    def charge(self, host, cost: float) -> None:
        """Spend `cost` tokens of `host` (its bucket may go below zero: it then waits longer)."""
        b = self._buckets.get(host)
        if b is not None:
            b[0] -= cost

    def _bucket(self, host, now: float) -> list:
        b = self._buckets.get(host)
        if b is None:
            b = self._buckets[host] = [self.burst, now]
            if len(self._buckets) > self.max_sources:
                self._buckets.popitem(last=False)
        else:
            self._buckets.move_to_end(host)
            b[0] = min(self.burst, b[0] + (now - b[1]) * self.rate)
            b[1] = now
        return b

    def take(self, host, now: float) -> bool:
        """True (and one token spent) when `host` may be served at server time `now` (s)."""
        if not self.rate or host is None:
            return True
        b = self._bucket(host, now)
        if b[0] >= 1.0:
            b[0] -= 1.0
            return True
        return False
