# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Loaders for CARMEN log files (``.clf``, ``.log``, optionally gzip-compressed).

CARMEN logs are text, one message per line. The lines read here:

- ``ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp``:
  wheel odometry pose (m, m, rad) and velocities (m/s, rad/s).
- ``FLASER n r_1 ... r_n x y theta odom_x odom_y odom_theta ipc_timestamp
  ipc_hostname logger_timestamp``: a front laser scan of ``n`` ranges (m) with
  the laser pose (``x y theta``; in a corrected log the SLAM pose, in a raw log
  the odometry) and the raw odometry pose at the scan time.

Beam geometry (old CARMEN convention, a 180 deg field of view starting at
``-pi/2``): ``n`` odd (181, 361) gives ``angle_increment = pi / (n - 1)``
(0.5 deg for 361), ``n`` even (180, 360) gives ``pi / n`` (1 deg for 180);
override with ``angle_increment``. Readings at or above ``no_return_range``
(81.91 m is the SICK "no return" value) become ``inf`` as a ROS driver would
publish them.

Time ``t`` (s) is the ``ipc_timestamp``. Ground-truth relations of the
Kuemmerle et al. (2009) benchmark (``*.relations``: ``t1 t2 x y z roll pitch
yaw``, the pose of the scan at ``t2`` seen from the scan at ``t1``) carry
their own time base: ``log time = relation time - time_offset``
(976052857.34 s for the Intel Research Lab log).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import gzip
import math
from pathlib import Path
from typing import Iterator, Optional, Union

import numpy as np

from robot_calib.core.geometry import wrap_angle
from robot_calib.core.types import OdomSample, ScanSample

INTEL_RELATIONS_TIME_OFFSET = 976052857.34
"""Relations time minus Intel log time (s) (see ``../shared/data/README.md``)."""

NO_RETURN_RANGE = 81.0
"""Readings at or above this range (m) are "no return" (SICK reports 81.91 m)."""


@dataclass
class CarmenLog:
    """
    The content of one CARMEN log.

    :ivar scans: laser scans (``ScanSample``, t in s, ranges in m), in file order.
    :ivar scan_poses: (N, 3) laser pose x, y (m), yaw (rad) logged with each scan.
    :ivar scan_odom: (N, 3) raw odometry pose x, y (m), yaw (rad) logged with each scan.
    :ivar odom: odometry samples from ``ODOM`` lines (empty when the log has none).
    :ivar params: ``PARAM`` lines as ``{name: value string}``.
    """

    scans: list = field(default_factory=list)
    scan_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    scan_odom: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    odom: list = field(default_factory=list)
    params: dict = field(default_factory=dict)

    @property
    def scan_times(self) -> np.ndarray:
        """Return the scan times (s) as an array."""
        return np.array([s.t for s in self.scans])

    def odometry(self) -> list:
        """
        Return odometry samples: the ``ODOM`` lines, else one per scan from its odometry pose.

        Velocities of the per-scan odometry are finite differences (m/s, rad/s)
        of consecutive poses, expressed in the robot frame.
        """
        if self.odom:
            return list(self.odom)
        out = []
        times = self.scan_times
        for i, (t, pose) in enumerate(zip(times, self.scan_odom)):
            vx = wz = 0.0
            if i > 0 and t > times[i - 1]:
                dt = t - times[i - 1]
                d = pose[:2] - self.scan_odom[i - 1, :2]
                yaw0 = self.scan_odom[i - 1, 2]
                vx = (math.cos(yaw0) * d[0] + math.sin(yaw0) * d[1]) / dt
                wz = wrap_angle(pose[2] - yaw0) / dt
            out.append(OdomSample(t=float(t), x=float(pose[0]), y=float(pose[1]),
                                  yaw=float(wrap_angle(pose[2])), vx=float(vx), wz=float(wz)))
        return out

    def messages(self) -> Iterator[tuple]:
        """Yield ``('odom', OdomSample)`` and ``('scan', ScanSample)`` in time order."""
        items = [(s.t, 0, 'odom', s) for s in self.odometry()]
        items += [(s.t, 1, 'scan', s) for s in self.scans]
        items.sort(key=lambda item: (item[0], item[1]))
        for _, _, key, sample in items:
            yield key, sample


def _open_text(path: Union[str, Path]):
    path = Path(path)
    if path.suffix == '.gz':
        return gzip.open(path, 'rt', encoding='ascii', errors='replace')
    return open(path, 'rt', encoding='ascii', errors='replace')


def beam_increment(n: int) -> float:
    """Return the CARMEN beam spacing (rad) for ``n`` beams over a 180 deg field of view."""
    return math.pi / (n - 1) if n % 2 == 1 else math.pi / n


def read_log(path: Union[str, Path], angle_min: float = -math.pi / 2,
             angle_increment: Optional[float] = None,
             no_return_range: float = NO_RETURN_RANGE, max_scans: Optional[int] = None,
             range_min: float = 0.01) -> CarmenLog:
    """
    Read a CARMEN log (``.clf``/``.log``, ``.gz`` allowed) into a :class:`CarmenLog`.

    Malformed lines are skipped (a clear ValueError only when the file holds
    no usable line at all).

    :param path: the log file.
    :param angle_min: angle of the first beam (rad).
    :param angle_increment: beam spacing (rad); None picks it from the beam count.
    :param no_return_range: readings at or above it (m) become ``inf``.
    :param max_scans: stop after this many scans (None: all).
    :param range_min: shortest valid reading (m).
    :return: the scans, their logged poses and the odometry.
    """
    log = CarmenLog()
    poses, odoms = [], []
    with _open_text(path) as fh:
        for line in fh:
            parts = line.split()
            if not parts or parts[0].startswith('#'):
                continue
            tag = parts[0]
            try:
                if tag == 'FLASER':
                    n = int(parts[1])
                    if len(parts) < n + 9:
                        continue
                    ranges = np.array(parts[2:2 + n], dtype=float)
                    rest = parts[2 + n:]
                    pose = [float(v) for v in rest[0:3]]
                    odom = [float(v) for v in rest[3:6]]
                    t = float(rest[6])
                    ranges[ranges >= no_return_range] = np.inf
                    inc = angle_increment if angle_increment is not None else beam_increment(n)
                    log.scans.append(ScanSample(
                        t=t, angle_min=angle_min, angle_increment=inc, ranges=ranges,
                        range_min=range_min, range_max=no_return_range, frame_id='laser'))
                    poses.append(pose)
                    odoms.append(odom)
                    if max_scans is not None and len(log.scans) >= max_scans:
                        break
                elif tag == 'ODOM':
                    x, y, th, tv, rv = (float(v) for v in parts[1:6])
                    t = float(parts[7])
                    log.odom.append(OdomSample(t=t, x=x, y=y, yaw=float(wrap_angle(th)),
                                               vx=tv, wz=rv))
                elif tag == 'PARAM' and len(parts) >= 3:
                    log.params[parts[1]] = parts[2]
            except (ValueError, IndexError):
                continue
    if not log.scans and not log.odom:
        raise ValueError(f'{path}: no FLASER or ODOM line found (not a CARMEN log?)')
    log.scan_poses = np.array(poses, dtype=float).reshape(-1, 3)
    log.scan_odom = np.array(odoms, dtype=float).reshape(-1, 3)
    return log


def read_relations(path: Union[str, Path],
                   time_offset: float = INTEL_RELATIONS_TIME_OFFSET) -> np.ndarray:
    """
    Read a ``*.relations`` ground-truth file.

    :param path: the relations file (``t1 t2 x y z roll pitch yaw`` per line).
    :param time_offset: relation time minus log time (s).
    :return: (M, 5) array of ``t1, t2`` (log time, s), ``dx, dy`` (m), ``dyaw`` (rad):
        the pose of the scan at ``t2`` in the frame of the scan at ``t1``.
    """
    rows = []
    with _open_text(path) as fh:
        for line in fh:
            parts = line.split()
            if len(parts) < 8 or parts[0].startswith('#'):
                continue
            try:
                t1, t2, x, y, _, _, _, yaw = (float(v) for v in parts[:8])
            except ValueError:
                continue
            rows.append((t1 - time_offset, t2 - time_offset, x, y, wrap_angle(yaw)))
    if not rows:
        raise ValueError(f'{path}: no relation found')
    return np.array(rows, dtype=float)


def match_times(times: np.ndarray, query: np.ndarray, tolerance: float = 0.01) -> np.ndarray:
    """
    Return the index of the nearest entry of sorted ``times`` for each ``query`` (s).

    :param times: sorted times (s).
    :param query: times to look up (s).
    :param tolerance: largest accepted difference (s); farther queries give -1.
    :return: integer indices, -1 where no time is within ``tolerance``.
    """
    times = np.asarray(times, dtype=float)
    query = np.asarray(query, dtype=float)
    idx = np.clip(np.searchsorted(times, query), 1, max(len(times) - 1, 1))
    left = idx - 1
    pick = np.where(np.abs(times[left] - query) <= np.abs(times[idx] - query), left, idx)
    return np.where(np.abs(times[pick] - query) <= tolerance, pick, -1)


def relation_pairs(log: CarmenLog, relations: np.ndarray,
                   tolerance: float = 0.01) -> list[tuple[int, int, np.ndarray]]:
    """
    Pair each relation with the indices of its two scans.

    :param log: the log whose scans the relations refer to.
    :param relations: output of :func:`read_relations`.
    :param tolerance: largest time difference (s) between a relation stamp and its scan.
    :return: ``(i, j, [dx, dy, dyaw])`` for every relation whose two scans were found.
    """
    times = log.scan_times
    i = match_times(times, relations[:, 0], tolerance)
    j = match_times(times, relations[:, 1], tolerance)
    return [(int(a), int(b), relations[k, 2:5].copy())
            for k, (a, b) in enumerate(zip(i, j)) if a >= 0 and b >= 0]
