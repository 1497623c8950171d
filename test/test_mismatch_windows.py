# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Tests of the mismatch analyser's effect windows: when a fitted window is reported."""

import re

import numpy as np
import pytest

from robot_calib.core.constants import GRAVITY
from robot_calib.mismatch import analyse_recordings
from robot_calib.mismatch.channels import IMU_FIELDS, IMU_TYPE, Topic

BIAS = 0.02  # rad/s, the offset added to the real yaw rate


def _smooth(rng, n, width):
    """Return unit-variance noise smoothed by three passes of a ``width``-sample box."""
    x = rng.standard_normal(n + 3 * width)
    for _ in range(3):
        x = np.convolve(x, np.ones(width) / width, 'valid')
    return x[:n] / np.std(x[:n])


def _imu_motion(rng, duration: float, rate: float) -> tuple:
    """Return t, sim, real: smooth IMU motion and the same plus white sensor noise."""
    n = int(duration * rate)
    t = np.arange(n) / rate
    gyro = np.column_stack([0.8 * _smooth(rng, n, int(0.5 * rate)) for _ in range(3)])
    acc = np.column_stack([0.5 * _smooth(rng, n, int(0.5 * rate)) for _ in range(3)])
    acc[:, 2] += GRAVITY
    sim = {f: (gyro if i < 3 else acc)[:, i % 3].copy() for i, f in enumerate(IMU_FIELDS)}
    real = {f: v + rng.standard_normal(n) * (0.003 if i < 3 else 0.03)
            for i, (f, v) in enumerate(sim.items())}
    return t, sim, real


def _wandering_pair(seed, window=None, duration=200.0, rate=100.0):
    """
    Return (sim, real) IMU recordings whose yaw rates differ by an offset and a slow wander.

    The real yaw rate reads ``BIAS`` more (inside ``window`` (s) only, or
    everywhere) plus a wander the simulation does not carry: a level drawn
    every 5 s (standard deviation 6 mrad/s, smoothed over 1 s), sitting 12
    mrad/s low in the first and last 20 s (a plausible stretch of it, so an
    offset "only from 20 s to 180 s" fits the residual better than a constant).
    """
    rng = np.random.default_rng(seed)
    t, sim, real = _imu_motion(rng, duration, rate)
    n = t.size
    level = 0.006 * rng.standard_normal(int(duration / 5) + 1)
    level[:4] = level[-5:] = -0.012
    wander = np.convolve(np.repeat(level, int(5 * rate))[:n], np.ones(int(rate)) / rate, 'same')
    on = np.ones(n, bool) if window is None else (t >= window[0]) & (t < window[1])
    real['angular_velocity.z'] = real['angular_velocity.z'] + np.where(on, BIAS, 0.0) + wander
    return ({'/imu': Topic('/imu', IMU_TYPE, t.copy(), sim)},
            {'/imu': Topic('/imu', IMU_TYPE, t.copy(), real)})


def _bias(out):
    found = [f for f in out['findings'] if f['effect'] in ('gyro_bias', 'gyro_bias_drift')
             and f['channel'].endswith('angular_velocity.z')]
    assert len(found) == 1, out['findings']
    return found[0]


def test_a_constant_offset_amid_a_slow_wander_is_reported_over_the_whole_recording():
    """
    A window leaving out stretches where the residual wanders low is not reported.

    The selection's white-noise score prefers the offset from 20 s to 180 s
    (as it did before the window test, on this seeded realisation); judged
    against the wander between blocks, the step at those edges is not
    consistent (on some other realisations it is, and the window stays), so
    the offset is reported over the whole recording at the mean the data give.
    """
    out, _ = analyse_recordings(*_wandering_pair(0))
    f = _bias(out)
    assert f['window'] is None, f
    assert f['parameters']['bias'] == pytest.approx(BIAS, rel=0.25)
    assert any('change at the edges is not consistent' in n for n in out['notes'])


def test_an_offset_in_a_window_amid_the_same_wander_keeps_its_window():
    out, _ = analyse_recordings(*_wandering_pair(0, window=(40.0, 100.0)))
    f = _bias(out)
    assert f['window'] == pytest.approx([40.0, 100.0], abs=1.0)
    assert f['parameters']['bias'] == pytest.approx(BIAS, rel=0.15)


def test_a_scale_that_changes_from_block_to_block_is_refused_with_its_spread():
    """A yaw-rate scale drawn anew every 20 s: refused, and the note gives its size and spread."""
    rng = np.random.default_rng(5)
    rate, duration = 100.0, 300.0
    t, sim, real = _imu_motion(rng, duration, rate)
    levels = rng.normal(0.0, 0.1, int(duration / 20.0) + 1)
    real[IMU_FIELDS[2]] = real[IMU_FIELDS[2]] * (1.0 + levels[(t // 20.0).astype(int)])
    out, _ = analyse_recordings({'/imu': Topic('/imu', IMU_TYPE, t, sim)},
                                {'/imu': Topic('/imu', IMU_TYPE, t, real)})
    assert not [f for f in out['findings'] if f['effect'] == 'gyro_scale']
    notes = [s for s in out['notes'] if 'not consistently' in s and 'gyro_scale' in s]
    assert notes, out['notes']
    # the user reads how large it is and how far it wanders, not only that it was refused
    m = re.search(r'\(([-+.\de]+) over the recording, ([-+.\de]+) to ([-+.\de]+) from block',
                  notes[0])
    assert m, notes[0]
    whole, low, high = map(float, m.groups())
    assert low < high and high - low > 0.1, notes[0]  # levels drawn with a 0.1 spread
    assert low - 0.05 <= whole <= high + 0.05, notes[0]
