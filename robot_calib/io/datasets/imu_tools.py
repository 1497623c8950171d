# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader for the imu_tools sample bags (ROS 1, real IMUs; ``phidgets_imu_upside_down.bag``).

Each bag holds one ``sensor_msgs/Imu`` topic (raw gyro rad/s, specific force
m/s^2) next to a magnetometer topic; :func:`load_imu` finds the IMU topic and
returns its samples in receive order.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Union

from robot_calib.core.types import ImuSample
from robot_calib.io.bags import list_topics, read_messages

BAGS = ('phidgets_imu_upside_down.bag', 'ardrone_imu.bag', 'sparkfun_razor.bag')
"""The bags of the imu_tools sample folder."""


def imu_topic(path: Union[str, os.PathLike]) -> Optional[str]:
    """Return the sensor_msgs/Imu topic of a bag with the most messages, or None."""
    topics = [(count, topic) for topic, (msgtype, count) in list_topics([path]).items()
              if msgtype == 'sensor_msgs/msg/Imu']
    return max(topics)[1] if topics else None


def load_imu(path: Union[str, os.PathLike], topic: Optional[str] = None) -> list[ImuSample]:
    """Return the IMU samples of ``topic`` (default: the bag's Imu topic) in receive order."""
    path = Path(path)
    topic = topic or imu_topic(path)
    if topic is None:
        return []
    out: list[ImuSample] = []
    for msg in read_messages([path], [topic]):
        out.extend(s for s in msg.samples if isinstance(s, ImuSample))
    return out
