# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loader of the front-tractor tricycle data set (steered drive wheel with an external tracker).

``dataset.txt`` lines: ``time: T ticks: STEER TRACTION model_pose: X Y TH
tracker_pose: X Y TH``. ``STEER`` is an absolute encoder (0..8191) that wraps:
readings above half the range are negative angles. ``TRACTION`` is an
incremental 32-bit counter (5000 ticks per encoder turn) that wraps at 2^32.
The header gives the nominal conversion: steering angle = ``Ksteer * 2 pi *
ticks / 8192`` and traction travel = ``Ktraction * ticks / 5000`` (m), axle
length (rear axle to steered wheel) 1.4 m, steering offset 0, and the tracked
sensor at (1.5, 0, 0) in ``base_link``. ``tracker_pose`` is the pose of that
sensor in the tracker's world frame; ``model_pose`` is the odometry computed
with the nominal values.

Mapped to the conventions of :mod:`robot_calib.core.kinematics`: the steering
*reading* is the encoder shaft angle ``2 pi * ticks / 8192`` (rad) so the
nominal ``steering_scale`` is ``Ksteer``; the traction *rotation* is ``2 pi *
ticks / 5000`` (rad) so the nominal ``wheel_radius`` is ``Ktraction / (2 pi)``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import re
from typing import Union

import numpy as np

from robot_calib.core import kinematics as K
from robot_calib.core.kinematics import Segment

_NUM = r'([-+0-9.eE]+)'
_LINE = re.compile(rf'time:\s*{_NUM}\s+ticks:\s*{_NUM}\s+{_NUM}\s+model_pose:\s*{_NUM}\s+{_NUM}'
                   rf'\s+{_NUM}\s+tracker_pose:\s*{_NUM}\s+{_NUM}\s+{_NUM}')


@dataclass
class TricycleData:
    """The parsed run: per-sample arrays and the header's nominal values (SI)."""

    t: np.ndarray
    reading: np.ndarray
    traction: np.ndarray
    model_pose: np.ndarray
    tracker_pose: np.ndarray
    nominal: dict


def load(path: Union[str, Path]) -> TricycleData:
    """
    Parse ``dataset.txt``; unwrap both encoders.

    :param path: the data file
    """
    text = Path(path).read_text()
    header = {}
    for line in text.splitlines():
        if line.startswith('#') and ':' in line:
            key, _, val = line[1:].partition(':')
            header[key.strip()] = val.strip()
    vals = [float(v) for v in header.get('parameter_values', '0.1 0.0106141 1.4 0').split()]
    maxes = [int(v) for v in header.get('joints_max_enc_values', '8192 5000').split()]
    ksteer, ktraction, axle, offset = vals[:4]
    rows = [tuple(float(x) for x in m.groups()) for m in _LINE.finditer(text)]
    a = np.array(rows)
    steer_max, trac_max = maxes[0], maxes[1]
    st = a[:, 1].astype(np.int64)
    st = np.where(st > steer_max // 2, st - steer_max, st)  # the absolute encoder wraps
    tr = a[:, 2].astype(np.int64)
    dtr = np.diff(tr)
    dtr = (dtr + 2 ** 31) % 2 ** 32 - 2 ** 31  # 32-bit counter wrap
    trac = np.concatenate(([0], np.cumsum(dtr))).astype(float)
    nominal = {'steering_scale': ksteer, 'wheel_radius': ktraction / (2 * math.pi),
               'wheel_base': axle, 'steering_offset': offset, 'lidar_x': 1.5, 'lidar_y': 0.0,
               'lidar_yaw': 0.0}
    return TricycleData(a[:, 0], 2 * math.pi * st / steer_max, 2 * math.pi * trac / trac_max,
                        a[:, 3:6], a[:, 6:9], nominal)


def segments(data: TricycleData, lo: int = 0, hi: int = -1, window: int = 10) -> list[Segment]:
    """
    Cut samples ``lo..hi`` into segments of ``window`` steps with the tracker's motion.

    A step uses the traction increment between samples i and i+1 and the
    steering reading at sample i+1 (this is how the recorded ``model_pose``
    was integrated: it matches it to 0.1 mm). The measured motion is the tracked sensor's
    relative pose between the segment's first and last sample.
    """
    hi = len(data.t) - 1 if hi < 0 else hi
    out = []
    for i0 in range(lo, hi - window + 1, window):
        i1 = i0 + window
        steps = np.column_stack((np.diff(data.traction[i0:i1 + 1]), data.reading[i0 + 1:i1 + 1]))
        rel = K.compose(K.inverse(data.tracker_pose[i0]), data.tracker_pose[i1])
        rel[2] = math.atan2(math.sin(rel[2]), math.cos(rel[2]))
        out.append(Segment(float(data.t[i0]), float(data.t[i1]), steps, rel))
    return out


def dead_reckon(data: TricycleData, values: dict, lo: int, hi: int) -> np.ndarray:
    """
    Return the sensor poses (N, 3) predicted from samples lo..hi, anchored at the tracker.

    Odometry from the encoders with ``values`` (steering_offset,
    steering_scale, wheel_radius, wheel_base, lidar_x, lidar_y, lidar_yaw),
    started at the tracker pose of sample ``lo`` (world frame of the tracker).
    """
    lp = np.array([values['lidar_x'], values['lidar_y'], values['lidar_yaw']])
    dphi = np.diff(data.traction[lo:hi + 1])
    ds, dth = K.steered_arc(dphi, data.reading[lo + 1:hi + 1], values['wheel_radius'],
                            values['wheel_base'], values['steering_offset'],
                            values['steering_scale'])
    steps = K.arc_pose(ds, dth)
    base = K.compose(data.tracker_pose[lo], K.inverse(lp))
    poses = [base]
    for st in steps:
        base = K.compose(base, st)
        poses.append(base)
    return K.compose(np.array(poses), np.broadcast_to(lp, (len(poses), 3)))


def stages(data: TricycleData, lo: int, hi: int, straight: float = 0.05,
           min_length: float = 1.0, max_length: float = 4.0) -> list[Segment]:
    """
    Return the seed's straight stages between samples lo..hi, with the tracker's motion.

    A stage is a run of samples whose steering angle with the nominal
    conversion (``Ksteer * reading``) stays below ``straight`` (rad), at least
    ``min_length`` and at most ``max_length`` of nominal travel (m); its
    measured motion is the tracked sensor's relative pose between its first
    and last sample (what the seed gets from matching the stage's first and
    last scan).
    """
    ksteer, radius = data.nominal['steering_scale'], data.nominal['wheel_radius']
    ok = np.abs(ksteer * data.reading) < straight
    out = []
    i = lo
    while i < hi:
        if not ok[i + 1] if i + 1 <= hi else True:
            i += 1
            continue
        j, travel = i, 0.0
        while j < hi and ok[j + 1] and travel < max_length:
            travel += abs(radius * (data.traction[j + 1] - data.traction[j]))
            j += 1
        if travel >= min_length:
            steps = np.column_stack((np.diff(data.traction[i:j + 1]), data.reading[i + 1:j + 1]))
            rel = K.compose(K.inverse(data.tracker_pose[i]), data.tracker_pose[j])
            rel[2] = math.atan2(math.sin(rel[2]), math.cos(rel[2]))
            out.append(Segment(float(data.t[i]), float(data.t[j]), steps, rel))
        i = max(j, i + 1)
    return out
