# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What every node says about itself: a logger safe at any severity, and its input health.

- :class:`NodeLog`: rclpy forbids one call site to log at two severities
  ("Logger severity cannot be changed between calls"), so a helper that sends
  every level through one line breaks the node at its second severity. Here
  each severity has its own call site, and throttling is by message key (our
  own clock), so two different warnings never silence each other.
- :func:`input_health`: from the pipeline's counters, one diagnostic status
  per period: waiting for data, input stale, every message rejected (with the
  reasons), an input slower than its kind's expected minimum rate
  (:data:`MIN_RATE_HZ`), or OK; the values are the counters and the measured
  rate per input.
"""

from __future__ import annotations

import time
from typing import Any, Optional

LEVELS = ('debug', 'info', 'warn', 'error')
OK, WARN, ERROR, STALE = 0, 1, 2, 3

MIN_RATE_HZ = {'imu': 20.0, 'odom': 5.0, 'joint_states': 5.0, 'scan': 2.0}
"""The slowest rate (Hz) an input of each kind is expected at; slower is a warning.

Far below what these sensors publish (IMU 100-1000 Hz, wheel odometry 20-100
Hz, 2D lidar 5-40 Hz) and near where the methods stop working: the attitude
and heading integrations need the gyro often, the wheel steps and scan-to-scan
matching need small motions."""


class NodeLog:
    """Log through an rclpy logger: one call site per severity, throttled per message key."""

    def __init__(self, logger: Any, clock=time.monotonic):
        """Wrap ``logger`` (an rclpy logger); ``clock`` gives seconds (for the throttle)."""
        self.logger = logger
        self.clock = clock
        self._last: dict[str, float] = {}

    def __call__(self, level: str, message: str, throttle_s: float = 0.0,
                 key: Optional[str] = None) -> bool:
        """
        Log ``message`` at ``level``; return False when throttled away.

        :param level: 'debug', 'info', 'warn' (or 'warning') or 'error'
        :param throttle_s: at most one message of this ``key`` per this many seconds
        :param key: what the throttle counts (default: the message itself)
        """
        if throttle_s > 0.0:
            k = key if key is not None else message
            now = self.clock()
            last = self._last.get(k)
            if last is not None and now - last < throttle_s:
                return False
            self._last[k] = now
            if len(self._last) > 1000:
                self._last.clear()
        if level == 'debug':
            self.logger.debug(message)
        elif level == 'info':
            self.logger.info(message)
        elif level in ('warn', 'warning'):
            self.logger.warning(message)
        else:
            self.logger.error(message)
        return True


def _reasons(counts: dict) -> str:
    out = [f'{k[len("rejected_"):]} {v}' for k, v in sorted(counts.items())
           if k.startswith('rejected_') and v]
    return ', '.join(out) or 'none'


def input_health(counts: dict, previous: dict, idle_s: dict, inputs: list,
                 stale_s: float, period_s: float = 0.0,
                 kinds: Optional[dict] = None) -> tuple[int, str, list]:
    """
    Return (level, message, key-values) of a node's inputs over the last period.

    :param counts: the pipeline's counters per input key (``read``, ``accepted``,
        ``rejected_<reason>``) now
    :param previous: the same a period ago
    :param idle_s: seconds since each input's last message (missing: never)
    :param inputs: the required input keys
    :param stale_s: silence (s) after which an input that was arriving is stale
    :param period_s: seconds since ``previous`` (0: no rate is measured)
    :param kinds: the sample kind of each input key (for :data:`MIN_RATE_HZ`)
    """
    level, problems, values = OK, [], []
    for key in inputs:
        now, before = counts.get(key, {}), previous.get(key, {})
        read = now.get('read', 0) - before.get('read', 0)
        accepted = now.get('accepted', 0) - before.get('accepted', 0)
        values += [(f'{key}.read', str(now.get('read', 0))),
                   (f'{key}.accepted', str(now.get('accepted', 0))),
                   (f'{key}.rejected', _reasons(now))]
        expected = MIN_RATE_HZ.get((kinds or {}).get(key, key), 0.0)
        rate = read / period_s if period_s > 0 and key in previous else None
        if rate is not None:
            values += [(f'{key}.rate_hz', f'{rate:.1f}'),
                       (f'{key}.expected_min_hz', f'{expected:.1f}')]
        if key not in idle_s:
            level = max(level, WARN)
            problems.append(f'waiting for {key}')
        elif read > 0 and accepted == 0:
            level = max(level, ERROR)
            problems.append(f'every {key} message rejected ({_reasons(now)})')
        elif idle_s[key] > stale_s:
            level = max(level, STALE)
            problems.append(f'{key} stale: nothing for {idle_s[key]:.1f} s')
        elif rate is not None and rate < expected:
            level = max(level, WARN)
            problems.append(f'{key} at {rate:.1f} Hz, expected at least {expected:.0f} Hz')
    return level, '; '.join(problems) or 'inputs OK', values
