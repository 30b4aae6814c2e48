"""SampleRing: the latest N float samples of a measure, in one array of doubles.

An output keeps its last few thousand write periods, tick durations and input ages for
its p99 figures. A deque of floats holds an object per sample (~32 bytes with its slot):
five outputs' three measures fill ~1.4 MB within a minute, a daemon's RSS growing after
start. Here a sample is 8 bytes in a preallocated array, so what is kept costs the same
from the first tick. Not thread-safe: its owner locks around it (`lines.driver.OutputStats`).
"""

from __future__ import annotations

from array import array


class SampleRing:
    """The last `size` samples appended (oldest first when read)."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"a ring keeps at least one sample, not {size}")
        self._values = array("d", bytes(8 * size))
        self._size = size
        self._count = 0  # samples appended in all: the newest is at (count - 1) % size
        self._taken = 0  # `take_new` returned the samples before this count

    def append(self, value: float) -> None:
        self._values[self._count % self._size] = value
        self._count += 1

    def __len__(self) -> int:
        return min(self._count, self._size)

    def values(self) -> list[float]:
        """The samples kept, oldest first."""
        count, size = self._count, self._size
        if count <= size:
            return self._values[:count].tolist()
        start = count % size
        return self._values[start:].tolist() + self._values[:start].tolist()

    def take_new(self) -> list[float]:
        """The samples appended since the last call, oldest first (those still kept: a
        caller that waits longer than `size` samples misses the oldest)."""
        new = min(self._count - self._taken, len(self))
        self._taken = self._count
        return self.values()[len(self) - new :]
