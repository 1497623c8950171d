# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Histories of bounded size for recordings of any length.

A live node or a replay may run for hours; what it keeps for plots and
statistics must not grow with the recording. :class:`Thinned` keeps an evenly
thinned copy of a series (every 2^k-th item, k growing as needed) plus its
latest item; :class:`Reservoir` keeps a uniform random sample of values (fixed
seed) with their exact count and sum, for percentiles (cheap per value once full);
:class:`Rows` stores a growing table of floats at 8 bytes a value (a list of small
arrays costs ~20x).
"""

from __future__ import annotations

from array import array
import math
import random
from typing import Any, Callable, Iterator, Optional, Sequence

import numpy as np


class Thinned:
    """A list-like history of at most ``capacity`` items (+ the latest), evenly thinned."""

    def __init__(self, capacity: int = 20000):
        """Keep at most ``capacity`` items (an even number, at least 2)."""
        self.capacity = max(2, int(capacity) // 2 * 2)
        self.items: list = []
        self.stride = 1
        self.count = 0
        """How many items were appended in all."""
        self._tail: Optional[Any] = None
        self._make_tail: Optional[Callable[[], Any]] = None

    def append(self, item: Any) -> None:
        """Add ``item``: kept when its index is a multiple of the current stride."""
        self._make_tail = None
        if self.count % self.stride == 0:
            self.items.append(item)
            self._tail = None
            if len(self.items) >= self.capacity:
                del self.items[1::2]
                self.stride *= 2
        else:
            self._tail = item
        self.count += 1

    def append_lazy(self, make: Callable[[], Any]) -> None:
        """
        Add the item ``make()`` returns, calling ``make`` only when the item is kept.

        An item thinned out is made when read while it is still the latest one.
        ``make`` returning None (e.g. it could not decode) adds nothing.
        """
        if self.count % self.stride == 0:
            item = make()
            if item is not None:
                self.append(item)
            return
        self._tail, self._make_tail = None, make
        self.count += 1

    def _settle(self) -> None:
        """Make the latest item when it was appended lazily."""
        if self._make_tail is not None:
            self._tail, self._make_tail = self._make_tail(), None

    def __len__(self) -> int:
        """Return the number of items kept."""
        self._settle()
        return len(self.items) + (self._tail is not None)

    def __iter__(self) -> Iterator[Any]:
        """Iterate over the kept items in order, the latest last."""
        self._settle()
        yield from self.items
        if self._tail is not None:
            yield self._tail

    def __getitem__(self, index: int) -> Any:
        """Return a kept item (``[-1]`` is always the latest appended)."""
        self._settle()
        if self._tail is not None:
            if index == -1 or index == len(self.items):
                return self._tail
            if index < 0:
                index += 1
        return self.items[index]


class Reservoir:
    """Count, sum and a uniform sample (at most ``capacity`` values) of a stream of numbers."""

    def __init__(self, capacity: int = 100000, seed: int = 0):
        """Keep at most ``capacity`` values; ``seed`` fixes which ones."""
        self.capacity = int(capacity)
        self.values: list[float] = []
        self.count = 0
        self.total = 0.0
        self._rng = random.Random(seed)
        self._next: float = 0 if self.capacity > 0 else math.inf
        """Count at which the next value is kept (every one until the sample is full)."""
        self._w = 1.0

    def append(self, value: float) -> None:
        """
        Add one value.

        Once the sample is full, values are skipped over in runs of random length
        (Li 1994, algorithm L: the sample stays uniform), so that most appends
        only count and sum.
        """
        self.count += 1
        self.total += value
        if self.count < self._next:
            return
        if len(self.values) < self.capacity:
            self.values.append(value)
            self._next = self.count + 1
            if len(self.values) < self.capacity:
                return
        else:
            self.values[self._rng.randrange(self.capacity)] = value
        self._skip(self.count)

    def extend(self, values: Sequence[float]) -> None:
        """Add many values: the same sample as appending them one by one, with fewer steps."""
        if not len(values):
            return
        start = self.count
        self.count += len(values)
        self.total += math.fsum(values)
        room = self.capacity - len(self.values)
        if room > 0 and values:
            self.values.extend(values[:room])
            self._next = start + min(room, len(values)) + 1
            if len(self.values) < self.capacity:
                return
            self._skip(start + room)
        nxt, count = self._next, self.count
        if nxt > count:
            return
        # _skip inlined (the same draws in the same order): most of a long run's cost
        kept, k, w = self.values, self.capacity, self._w
        rng = self._rng
        randrange, random_, exp, log, log1p = rng.randrange, rng.random, math.exp, math.log, \
            math.log1p
        while nxt <= count:
            kept[randrange(k)] = values[nxt - start - 1]
            w *= exp(log(1.0 - random_()) / k)
            step = log1p(-w)
            nxt += (int(log(1.0 - random_()) / step) if step < 0.0 else 2**62) + 1
        self._next, self._w = nxt, w

    def _skip(self, count: int) -> None:
        """Draw the count of the next value to keep after value ``count`` (algorithm L)."""
        rng = self._rng
        self._w *= math.exp(math.log(1.0 - rng.random()) / self.capacity)
        step = math.log1p(-self._w)
        skip = int(math.log(1.0 - rng.random()) / step) if step < 0.0 else 2**62
        self._next = count + skip + 1

    def percentile(self, q: float) -> float:
        """Return the percentile ``q`` (0..100): exact up to ``capacity`` values, then sampled."""
        return float(np.percentile(self.values, q)) if self.values else float('nan')


class Rows:
    """A growable table of float rows (n, ``width``), 8 bytes a value, read like a list."""

    def __init__(self, width: int):
        """Create an empty table of rows of ``width`` floats."""
        self.width = int(width)
        self._buf = array('d')

    def append(self, row: Any) -> None:
        """Add one row (a sequence of ``width`` floats)."""
        if type(row) is tuple and len(row) == self.width:
            self._buf.extend(row)
            return
        values = np.asarray(row, dtype=float).ravel()
        if values.size != self.width:
            raise ValueError(f'a row of {self.width} values expected, got {values.size}')
        self._buf.frombytes(values.tobytes())

    def __len__(self) -> int:
        """Return the number of rows."""
        return len(self._buf) // self.width

    def drop_first(self, n: int) -> None:
        """Forget the first ``n`` rows."""
        del self._buf[:max(int(n), 0) * self.width]

    def __getitem__(self, index: Any) -> np.ndarray:
        """Return a copy of one row (width,) or of a slice of rows (k, width)."""
        w, n = self.width, len(self)
        if isinstance(index, slice):
            start, stop, step = index.indices(n)
            rows = np.array(self._buf[start * w:max(stop, start) * w], dtype=float)
            return rows.reshape(-1, w)[::step]
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError('row index out of range')
        return np.array(self._buf[index * w:(index + 1) * w], dtype=float)

    def __iter__(self) -> Iterator[np.ndarray]:
        """Iterate over the rows."""
        for i in range(len(self)):
            yield self[i]
