# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The ideal lidar of a ground-truth motion: beams ray-cast in a map at the true poses.

``robot-calib ideal --map MAP.yaml`` (a map_server occupancy grid, read by
:mod:`robot_calib.io.occupancy_map`) or ``--map-from-scans`` (a grid of the
real scans' end points drawn at the true poses, :func:`robot_calib.core.
raycast.grid_from_points`) writes ``/scan``: at each real scan's stamp (or,
without real scans, at ``scan_rate``), the laser pose is the true pose
(interpolated; yaw unwrapped) composed with the laser mounting of
``/tf_static`` (or ``lidar_x``, ``lidar_y``, ``lidar_yaw``), and every beam
of the real scanner's geometry (angles, range limits) is cast from it
(:func:`robot_calib.core.raycast.raycast`). The ideal scan is deskewed (every
beam from the pose at the stamp) and noiseless; beams with no occupied cell
within ``range_max`` are +inf, closer than ``range_min`` -inf (REP-117).

A map built from the real scans absorbs what the scans share: a range bias
(walls drawn ``b`` farther from where the robot saw them) and, in part, a
range scale, so the ideal scans inherit them and a comparison cannot find
them; a mounting error or a time offset blurs such a map rather than moving
it. Only a map made independently of these scans (a survey, a CAD plan, a
map from another scanner) shows the range bias and scale.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import os
from typing import Optional

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy
from robot_calib.core.raycast import grid_from_points, OccupancyGrid, raycast, scan_end_points
from robot_calib.mismatch.channels import ChannelError

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
MAP_FROM_SCANS_NOTE = ('the map was built from the real scans at the true poses: it absorbs '
                       'their range bias (and in part their range scale), so the ideal '
                       'scans share them; use --map with an independent map to see them')


@dataclass
class RealScans:
    """The real scans of a bag: stamps (s), ranges (S, B) m and the scanner's geometry."""

    topic: str
    t: np.ndarray
    ranges: np.ndarray
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    frame_id: str
    time_increment: float = 0.0
    scan_time: float = 0.0


@dataclass
class Mount:
    """The laser in the truth's body frame: x, y (m), yaw (rad), beams mirrored (upside down)."""

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    mirrored: bool = False
    source: str = 'parameters'


def read_scans(path: os.PathLike | str, topic: Optional[str] = None) -> Optional[RealScans]:
    """
    Return the LaserScan messages of a bag (None when it has none), one geometry.

    Without ``topic`` the only LaserScan topic (or ``/scan`` among several).

    :raises ChannelError: the named topic is missing, several candidates, or the
        beam count changes within the topic
    """
    from robot_calib.io import bags
    with bags.BagSet([path]) as bagset:
        streams = [s for s in bagset.streams if s.msgtype == SCAN_TYPE]
        names = sorted({s.topic for s in streams})
        if topic is not None:
            want = bags.normalize_topic(topic)
            streams = [s for s in streams if s.topic == want]
            if not streams:
                raise ChannelError(f'--scan-topic {topic}: no LaserScan topic of that name '
                                   f'(LaserScan topics: {", ".join(names) or "none"})')
        elif len(names) > 1:
            streams = [s for s in streams if s.topic == '/scan']
            if not streams:
                raise ChannelError(f'several LaserScan topics ({", ".join(names)}): say which '
                                   'with --scan-topic')
        if not streams:
            return None
        stamps, rows, first = [], [], None
        for stream, _, raw in bagset.messages(streams):
            msg = stream.to_msg(raw)
            r = np.asarray(msg.ranges, dtype=float)
            if first is None:
                first = msg
            elif r.size != rows[0].size:
                raise ChannelError(f'{stream.topic}: the beam count changes ({rows[0].size} '
                                   f'then {r.size}); one scanner geometry is needed')
            stamps.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
            rows.append(r)
    if first is None:
        return None
    t = np.array(stamps)
    order = np.argsort(t, kind='stable')
    return RealScans(streams[0].topic, t[order], np.vstack(rows)[order],
                     float(first.angle_min), float(first.angle_increment),
                     float(first.range_min), float(first.range_max), first.header.frame_id,
                     float(first.time_increment), float(first.scan_time))


def read_mount(path: os.PathLike | str, frame: str) -> Optional[Mount]:
    """Return the mounting of ``frame`` from the bag's ``/tf_static`` (one hop), or None."""
    from robot_calib.io import bags
    with bags.BagSet([path]) as bagset:
        streams = [s for s in bagset.streams if s.topic == '/tf_static']
        if not streams:
            return None
        for stream, _, raw in bagset.messages(streams):
            for tf in stream.to_msg(raw).transforms:
                if tf.child_frame_id.lstrip('/') != frame.lstrip('/'):
                    continue
                q = tf.transform.rotation
                tr = tf.transform.translation
                w, x, y, z = q.w, q.x, q.y, q.z
                yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
                # the laser's z axis down (roll pi): its angles run the other way
                mirrored = 1 - 2 * (x * x + y * y) < 0
                return Mount(tr.x, tr.y, yaw, mirrored, f'/tf_static {tf.header.frame_id} -> '
                             f'{tf.child_frame_id}')
    return None


def planar_truth(t: np.ndarray, p: np.ndarray, q: np.ndarray,
                 at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return (inside, x, y, yaw) of the truth interpolated at ``at`` (s); yaw unwrapped."""
    w, x, y, z = q.T
    yaw = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    inside = (at >= t[0]) & (at <= t[-1])
    return (inside, np.interp(at, t, p[:, 0]), np.interp(at, t, p[:, 1]),
            np.interp(at, t, yaw))


def laser_poses(x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                mount: Mount) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the laser's world poses (m, m, rad) from body poses and the mounting."""
    c, s = np.cos(yaw), np.sin(yaw)
    return x + c * mount.x - s * mount.y, y + s * mount.x + c * mount.y, yaw + mount.yaw


def beam_angles(scans: RealScans, mount: Mount) -> np.ndarray:
    """Return the beams' angles (rad) in the laser's planar frame (mirrored if upside down)."""
    a = scans.angle_min + scans.angle_increment * np.arange(scans.ranges.shape[1])
    return -a if mount.mirrored else a


def map_from_scans(scans: RealScans, lx: np.ndarray, ly: np.ndarray, lyaw: np.ndarray,
                   mount: Mount, resolution: float, min_hits: int) -> OccupancyGrid:
    """Return the grid of the real scans' end points drawn at the true laser poses."""
    ex, ey = scan_end_points(lx, ly, lyaw, beam_angles(scans, mount), scans.ranges,
                             max(scans.range_min, 1e-6),
                             scans.range_max if scans.range_max > 0 else math.inf)
    return grid_from_points(ex, ey, resolution, min_hits)


def ideal_ranges(grid: OccupancyGrid, lx: np.ndarray, ly: np.ndarray, lyaw: np.ndarray,
                 angles: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """Return the ideal ranges (S, B) m with REP-117 invalid values (+inf none, -inf near)."""
    rmax = range_max if range_max > 0 else math.inf
    r = raycast(grid, lx[:, None], ly[:, None], lyaw[:, None] + angles[None, :], rmax)
    r[np.isfinite(r) & (r < range_min)] = -math.inf
    return r


def scan_samples(t: np.ndarray, ranges: np.ndarray, scans: RealScans) -> list:
    """Return ScanSamples (deskewed: time_increment 0) of ideal ranges at stamps ``t`` (s)."""
    out = []
    for ti, r in zip(t.tolist(), ranges):
        ns = int(round(ti * 1e9))
        out.append((ns, T.ScanSample(ti, scans.angle_min, scans.angle_increment,
                                     r.astype(np.float32).astype(float), scans.range_min,
                                     scans.range_max, scans.frame_id, None, 0.0,
                                     scans.scan_time, stamp_ns=ns)))
    return out


def mount_transform(mount: Mount, base: str, frame: str, t: float) -> T.StaticTransform:
    """Return the /tf_static transform of the laser the ideal scans were cast with."""
    return T.StaticTransform(base, frame, np.array([mount.x, mount.y, 0.0]),
                             quat_from_rpy(math.pi if mount.mirrored else 0.0, 0.0, mount.yaw),
                             t)


@dataclass
class ScanRequest:
    """What ``robot-calib ideal`` was asked for the lidar: a map file or the scans' own map."""

    map_path: Optional[str] = None
    from_scans: bool = False
    scan_topic: Optional[str] = None


def derive_scans(truth_bag: os.PathLike | str, t: np.ndarray, p: np.ndarray, q: np.ndarray,
                 req: ScanRequest, prm) -> dict:
    """
    Return the ideal ``/scan`` of a truth (t s, p m, q w x y z): samples, transform, summary.

    ``prm`` is the :class:`~robot_calib.mismatch.derive.IdealParams` (mounting
    without ``/tf_static``, scanner geometry without real scans, map cell side).

    :raises ChannelError: on a request the bag cannot serve (one line)
    """
    from robot_calib.io.occupancy_map import load_map, MapError
    if req.map_path and req.from_scans:
        raise ChannelError('give --map or --map-from-scans, not both')
    scans = read_scans(truth_bag, req.scan_topic)
    notes = []
    if scans is None:
        if req.from_scans:
            raise ChannelError(f'--map-from-scans: no LaserScan topic in {truth_bag}')
        n_b = max(1, int(prm.scan_beams))
        full = prm.scan_fov >= 2 * math.pi - 1e-9
        inc = prm.scan_fov / (n_b if full else max(n_b - 1, 1))
        stamps = np.arange(t[0], t[-1] + 1e-9, 1.0 / prm.scan_rate)
        scans = RealScans('/scan', stamps, np.full((stamps.size, n_b), np.nan),
                          -math.pi if full else -0.5 * prm.scan_fov, inc, prm.scan_range_min,
                          prm.scan_range_max, prm.scan_frame, 0.0, 1.0 / prm.scan_rate)
        notes.append(f'no real scans: {n_b} beams at {prm.scan_rate:g} Hz from the scan_* '
                     'parameters')
    mount = read_mount(truth_bag, scans.frame_id)
    if mount is None:
        mount = Mount(prm.lidar_x, prm.lidar_y, prm.lidar_yaw, False,
                      'lidar_x, lidar_y, lidar_yaw')
        notes.append(f'no /tf_static for {scans.frame_id!r}: laser mounting from '
                     f'lidar_x={prm.lidar_x:g}, lidar_y={prm.lidar_y:g}, '
                     f'lidar_yaw={prm.lidar_yaw:g}')
    inside, x, y, yaw = planar_truth(t, p, q, scans.t)
    if np.count_nonzero(inside) == 0:
        raise ChannelError(f'no scan of {scans.topic} lies within the truth '
                           f'({t[0]:.3f} to {t[-1]:.3f} s)')
    keep = np.flatnonzero(inside)
    lx, ly, lyaw = laser_poses(x[keep], y[keep], yaw[keep], mount)
    if req.from_scans:
        sub = RealScans(**{**scans.__dict__, 't': scans.t[keep], 'ranges': scans.ranges[keep]})
        grid = map_from_scans(sub, lx, ly, lyaw, mount, prm.map_resolution, prm.map_min_hits)
        notes.append(MAP_FROM_SCANS_NOTE)
    else:
        try:
            grid = load_map(req.map_path)
        except MapError as exc:
            raise ChannelError(str(exc)) from None
    if not grid.occupied.any():
        raise ChannelError('the map has no occupied cell: nothing to cast the beams at')
    ranges = ideal_ranges(grid, lx, ly, lyaw, beam_angles(scans, mount), scans.range_min,
                          scans.range_max)
    base = 'base_link'
    return {'samples': scan_samples(scans.t[keep], ranges, scans),
            'tf': mount_transform(mount, base, scans.frame_id, float(t[0])),
            'topic': scans.topic, 'scans': int(keep.size), 'beams': int(ranges.shape[1]),
            'mount': mount.source, 'map': 'from scans' if req.from_scans else str(req.map_path),
            'map_cells': list(grid.occupied.shape), 'notes': notes}
