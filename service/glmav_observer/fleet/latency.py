"""A fixed-size latency histogram (arrival to publish): log bins, mergeable, picklable.

50 bins per decade from 1 µs to 100 s (each bin ±2.3 %): quantiles are the upper edge
of their bin. Fixed size, so that measuring a long run does not itself grow memory.
"""

from __future__ import annotations

import bisect
import math

#: upper edges of the bins, s
EDGES_S: tuple[float, ...] = tuple(10 ** (-6 + i / 50) for i in range(8 * 50 + 1))


class LatencyHistogram:
    """Counts of latencies by bin; ``add(seconds)``, ``quantile(q)``, ``merge(other)``."""

    __slots__ = ("counts",)

    def __init__(self, counts: list[int] | None = None) -> None:
        self.counts = list(counts) if counts is not None else [0] * len(EDGES_S)

    def add(self, latency_s: float) -> None:
        self.counts[min(len(EDGES_S) - 1, bisect.bisect_left(EDGES_S, latency_s))] += 1

    @property
    def n(self) -> int:
        return sum(self.counts)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile, s (NaN when empty)."""
        n = self.n
        if n == 0:
            return math.nan
        target = max(1, math.ceil(q * n))
        acc = 0
        for i, c in enumerate(self.counts):
            acc += c
            if acc >= target:
                return EDGES_S[i]
        return EDGES_S[-1]

    def merge(self, other: LatencyHistogram) -> None:
        self.counts = [a + b for a, b in zip(self.counts, other.counts, strict=True)]

    def summary_ms(self) -> dict[str, float]:
        return {
            "n": float(self.n),
            "p50_ms": 1e3 * self.quantile(0.5),
            "p99_ms": 1e3 * self.quantile(0.99),
            "max_ms": 1e3 * self.quantile(1.0),
        }
