# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The fall-alert onsets a tilt pipeline gives on a simulated recording (tests and benchmarks)."""

from __future__ import annotations

from typing import Any


def fall_alert_onsets(pipeline: Any, messages: list) -> list[float]:
    """
    Feed ``(topic, sample)`` messages of a recording and return the alert onset times (s).

    ``/tf_static`` messages (lists of static transforms) and ``/imu`` samples are
    used, as :func:`robot_calib.sim.run_scenario` gives them; other topics are skipped.
    """
    onsets = []
    for topic, sample in messages:
        if topic == '/tf_static':
            for transform in sample:
                pipeline.process('tf_static', transform)
        elif topic == '/imu':
            for key, out in pipeline.process('imu', sample):
                if key == 'fall_alert' and out.value:
                    onsets.append(out.t)
    return onsets
