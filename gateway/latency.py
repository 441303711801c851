"""Latency histograms cheap enough for a control loop's hot path.

A sample costs one integer division and one array increment; percentiles are read off the
cumulative counts when asked (at health rate, not per cycle). Resolution is one bin width
(default 5 µs) up to the histogram's span; longer samples land in an overflow bin and still
count for ``max``.
"""

from __future__ import annotations

import numpy as np


class Histogram:
    """Durations in seconds, binned; :meth:`summary` gives n, p50, p99, p99.9 and max in µs."""

    def __init__(self, bin_s: float = 5e-6, span_s: float = 0.02) -> None:
        self.bin_s = bin_s
        self._bins = round(span_s / bin_s)
        self._counts = np.zeros(self._bins + 1, dtype=np.int64)  # last bin: overflow
        self.n = 0
        self.max_s = 0.0

    def add(self, duration_s: float) -> None:
        if not duration_s >= 0.0:  # negative (clock skew between stamps) or NaN: not a sample
            return
        k = int(duration_s / self.bin_s)
        self._counts[k if k < self._bins else self._bins] += 1
        self.n += 1
        if duration_s > self.max_s:
            self.max_s = duration_s

    def merge(self, other: Histogram) -> None:
        if other._counts.shape != self._counts.shape or other.bin_s != self.bin_s:
            raise ValueError("histograms of different binning cannot be merged")
        self._counts += other._counts
        self.n += other.n
        self.max_s = max(self.max_s, other.max_s)

    def percentile_s(self, p: float) -> float | None:
        """The ``p``-th percentile [s] (upper edge of its bin), None without samples."""
        if self.n == 0:
            return None
        rank = int(np.ceil(p / 100.0 * self.n))
        k = int(np.searchsorted(np.cumsum(self._counts), max(rank, 1)))
        if k >= self._bins:
            return self.max_s
        return min((k + 1) * self.bin_s, self.max_s)

    def summary(self) -> dict[str, float | int | None]:
        def us(v: float | None) -> float | None:
            return None if v is None else round(v * 1e6, 1)

        return {
            "n": self.n,
            "p50_us": us(self.percentile_s(50)),
            "p99_us": us(self.percentile_s(99)),
            "p999_us": us(self.percentile_s(99.9)),
            "max_us": us(self.max_s if self.n else None),
        }
