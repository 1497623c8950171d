# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Bounded histories: evenly thinned series and a reservoir for percentiles."""

import numpy as np
import pytest
from robot_calib.core.series import Reservoir, Rows, Thinned


def test_thinned_stays_bounded_even_and_ends_at_the_latest():
    s = Thinned(capacity=100)
    for i in range(100003):
        s.append(i)
    kept = list(s)
    assert len(kept) <= 101 and len(s) == len(kept)
    assert kept[0] == 0 and kept[-1] == 100002 and s[-1] == 100002
    steps = np.diff(kept[:-1])
    assert np.all(steps == steps[0])  # evenly thinned
    assert s.count == 100003


def test_thinned_is_a_plain_list_while_small():
    s = Thinned(capacity=10)
    for i in range(5):
        s.append((i, i * 2))
    assert list(s) == [(i, i * 2) for i in range(5)] and s[-1] == (4, 8) and s[0] == (0, 0)
    assert not Thinned()


@pytest.mark.parametrize('n', [7, 100, 1001])
def test_thinned_lazy_items_are_made_only_where_kept_and_match_eager(n):
    eager, lazy, made = Thinned(capacity=16), Thinned(capacity=16), []

    def make(i):
        made.append(i)
        return i
    for i in range(n):
        eager.append(i)
        lazy.append_lazy(lambda i=i: make(i))
    assert list(lazy) == list(eager) and lazy[-1] == eager[-1] == n - 1
    assert len(lazy) == len(eager) and lazy.count == eager.count
    assert set(eager) <= set(made) and len(made) == len(set(made))    # each made once
    if n > 32:
        assert len(made) < n / 2             # items thinned out as they came were not made


def test_thinned_lazy_item_that_cannot_be_made_adds_nothing():
    s = Thinned(capacity=16)
    for i in range(5):
        s.append_lazy(lambda i=i: None if i == 2 else i)
    assert list(s) == [0, 1, 3, 4]


def test_reservoir_keeps_exact_count_and_sum_and_close_percentiles():
    r = Reservoir(capacity=5000, seed=1)
    values = np.random.default_rng(2).exponential(1.0, 200000)
    for v in values:
        r.append(float(v))
    assert r.count == values.size and abs(r.total - values.sum()) < 1e-6 * values.sum()
    assert len(r.values) == 5000
    assert abs(r.percentile(50) - np.percentile(values, 50)) < 0.05
    assert abs(r.percentile(99) - np.percentile(values, 99)) < 0.5


def test_reservoir_sample_is_uniform_over_the_whole_stream():
    """Every part of a long stream is kept in proportion (skipping keeps the sample uniform)."""
    n, k = 400000, 4000
    r = Reservoir(capacity=k, seed=3)
    for i in range(n):
        r.append(float(i))
    counts = np.histogram(r.values, bins=8, range=(0, n))[0]
    assert len(r.values) == k and len(set(r.values)) == k
    assert np.all(np.abs(counts - k / 8) < 4 * np.sqrt(k / 8)), counts
    assert r.count == n and r.total == n * (n - 1) / 2


def test_reservoir_extend_keeps_what_appending_one_by_one_keeps():
    values = np.random.default_rng(5).exponential(1.0, 30000).tolist()
    for capacity in (0, 1, 7, 1000, 40000):
        one, many = Reservoir(capacity, seed=2), Reservoir(capacity, seed=2)
        for v in values:
            one.append(v)
        sizes = np.random.default_rng(capacity).integers(0, 3000, 100)
        edges = np.minimum(np.cumsum(sizes), len(values)).tolist()
        for a, b in zip([0] + edges, edges + [len(values)]):
            many.extend(values[a:b])
        assert many.values == one.values and many.count == one.count == len(values)
        assert many.total == pytest.approx(one.total, rel=1e-12)


def test_reservoir_extend_with_nothing_changes_nothing():
    for r in (Reservoir(4, seed=1), Reservoir(0, seed=1)):
        r.extend([])
        assert r.values == [] and r.count == 0
        r.extend([1.0, 2.0])
        r.extend([])
        assert r.count == 2 and r.total == 3.0


def test_rows_read_like_a_list_of_arrays():
    rows = Rows(3)
    data = np.arange(30, dtype=float).reshape(10, 3) * 0.5
    for r in data:
        rows.append(r)
    assert len(rows) == 10
    assert np.array_equal(rows[0], data[0]) and np.array_equal(rows[-1], data[-1])
    assert np.array_equal(rows[2:5], data[2:5]) and rows[7:3].shape == (0, 3)
    assert np.array_equal(np.asarray(list(rows)), data)
    rows[0][0] = 99.0  # a copy: the table is unchanged
    assert rows[0][0] == 0.0
    with pytest.raises(ValueError):
        rows.append([1.0, 2.0])
    with pytest.raises(IndexError):
        rows[10]
