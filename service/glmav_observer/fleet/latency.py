"""A fixed-size latency histogram (arrival to publish): log bins, mergeable, picklable.

50 bins per decade from 1 µs to 100 s (each bin ±2.3 %): quantiles are the upper edge
of their bin. Fixed size, so that measuring a long run does not itself grow memory.
"""

from __future__ import annotations

import bisect
import math

#: upper edges of the bins, s
EDGES_S: tuple[float, ...] = tuple(10 ** (-6 + i / 50) for i in range(8 * 50 + 1))


#: datagrams per block of the block statistic (:meth:`LatencyHistogram.block_quantile`):
#: a p99 of 1,000 is its 10th largest, so one stall of the machine of 50-100 ms (the 20-40
#: datagrams 2 vehicles send in it) spoils the block it falls in and no other
BLOCK = 1000


def _quantile_index(counts: list[int], n: int, q: float) -> int:
    """The bin holding the ``q`` quantile of ``n`` counts (n > 0)."""
    target = max(1, math.ceil(q * n))
    acc = 0
    for i, c in enumerate(counts):
        acc += c
        if acc >= target:
            return i
    return len(counts) - 1


class LatencyHistogram:
    """Counts of latencies by bin; ``add(seconds)``, ``quantile(q)``, ``merge(other)``.

    Beside the whole run's counts, the p99 of every block of ``BLOCK`` consecutive
    latencies is counted in the same bins (``block_quantile``): the median of the blocks'
    p99 is the p99 a run has when one stall of the machine is left out, which a p99 over
    a few thousand datagrams is not (docs/benchmarks/bench_fleet.md). A block is one
    process's consecutive latencies; merging adds the finished blocks, not the partial
    ones. Still of fixed size.
    """

    __slots__ = ("_block", "_block_n", "block_p99", "counts")

    def __init__(self, counts: list[int] | None = None) -> None:
        self.counts = list(counts) if counts is not None else [0] * len(EDGES_S)
        self._block = [0] * len(EDGES_S)
        self._block_n = 0
        #: counts of the finished blocks' p99 by bin
        self.block_p99 = [0] * len(EDGES_S)

    def add(self, latency_s: float) -> None:
        i = min(len(EDGES_S) - 1, bisect.bisect_left(EDGES_S, latency_s))
        self.counts[i] += 1
        self._block[i] += 1
        self._block_n += 1
        if self._block_n == BLOCK:
            self.block_p99[_quantile_index(self._block, BLOCK, 0.99)] += 1
            self._block = [0] * len(EDGES_S)
            self._block_n = 0

    @property
    def n(self) -> int:
        return sum(self.counts)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile, s (NaN when empty)."""
        n = self.n
        if n == 0:
            return math.nan
        return EDGES_S[_quantile_index(self.counts, n, q)]

    def block_quantile(self, q: float) -> float:
        """The ``q`` quantile of the finished blocks' p99, s (NaN without a finished
        block): ``q`` = 0.5, the median block's p99."""
        n = sum(self.block_p99)
        if n == 0:
            return math.nan
        return EDGES_S[_quantile_index(self.block_p99, n, q)]

    def merge(self, other: LatencyHistogram) -> None:
        self.counts = [a + b for a, b in zip(self.counts, other.counts, strict=True)]
        self.block_p99 = [a + b for a, b in zip(self.block_p99, other.block_p99, strict=True)]

    def __getstate__(self) -> tuple[list[int], list[int], int, list[int]]:
        return (self.counts, self._block, self._block_n, self.block_p99)

    def __setstate__(self, state: tuple[list[int], list[int], int, list[int]]) -> None:
        self.counts, self._block, self._block_n, self.block_p99 = state

    def summary_ms(self) -> dict[str, float]:
        return {
            "n": float(self.n),
            "p50_ms": 1e3 * self.quantile(0.5),
            "p99_ms": 1e3 * self.quantile(0.99),
            "max_ms": 1e3 * self.quantile(1.0),
            "p99_block_median_ms": 1e3 * self.block_quantile(0.5),
            "blocks": float(sum(self.block_p99)),
        }
