# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulated-and-real pairs built from the real recordings in ../shared/data, for the benchmarks.

The builders know nothing of what effect a pair holds: the simulated side is
derived from a ground truth with nominal parameters, the real side is the
recording as it is.

- :func:`broad_pair`: a BROAD trial: the ideal IMU of the optical truth
  (orientation and position) vs the real IMU.
- :func:`null_pairs`: pairs that hold nothing: a real IMU split into its even
  and odd samples, and an ideal IMU against itself plus white noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from robot_calib.io.datasets import broad
from robot_calib.mismatch.channels import Topic

import mismatch_protocols as P  # noqa: I100 - a sibling module

SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data'


def broad_trials() -> list:
    """Return the BROAD trial files (empty when the data is absent)."""
    folder = SHARED / 'broad'
    return broad.list_trials(folder) if folder.is_dir() else []


def broad_pair(path) -> tuple:
    """Return (trial, sim, real) of one BROAD trial file."""
    trial = broad.load_trial(path)
    sim, real = P.broad_pair(trial)
    return trial, sim, real


def _split(rec: dict, start: int) -> dict:
    return {k: Topic(tp.name, tp.msgtype, tp.t[start::2],
                     {f: x[start::2] for f, x in tp.fields.items()}) for k, tp in rec.items()}


def null_pairs(path, seed: int = 0) -> dict:
    """
    Return pairs of one BROAD trial that differ by nothing but noise.

    ``even_odd``: the real IMU's even samples as "sim", its odd samples as
    "real"; ``ideal_noise``: the ideal IMU against itself plus white noise of
    a low-cost IMU (0.005 rad/s, 0.05 m/s^2).
    """
    trial, sim, real = broad_pair(path)
    rng = np.random.default_rng(seed)
    tp = sim['/imu']
    noisy = {f: x + rng.standard_normal(x.size) * (0.005 if f.startswith('angular') else 0.05)
             for f, x in tp.fields.items()}
    plain = {'/imu': Topic(tp.name, tp.msgtype, tp.t, dict(tp.fields))}
    return {'even_odd': (_split(real, 0), _split(real, 1)),
            'ideal_noise': (plain, {'/imu': Topic(tp.name, tp.msgtype, tp.t, noisy)})}


# robot_localization's test launch file: base_link -> imu_link, roll pi/2, yaw -pi/2 (data README)
HUSKY_IMU_RPY = (np.pi / 2, 0.0, -np.pi / 2)


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def husky_pair(path=None) -> tuple:
    """
    Return (sim, real) of robot_localization's Husky bag: IMU yaw rate vs wheel odometry.

    The "simulated" yaw rate is the IMU's, turned into base_link by the
    mounting of the bag's test; the "real" one is the wheel odometry's (a
    skid-steer Husky, whose wheels slide sideways when it turns). Both as
    ``/odom`` yaw rates.
    """
    from robot_calib.mismatch.channels import ODOM_TYPE, read_bag
    rec = read_bag(path or SHARED / 'robot_localization' / 'test1.bag')
    imu, odom = rec['/imu/data'], rec['/husky_velocity_controller/odom']
    gyro = np.column_stack([imu.fields[f'angular_velocity.{a}'] for a in 'xyz'])
    yaw_rate = (gyro @ _rpy_matrix(*HUSKY_IMU_RPY).T)[:, 2]
    sim = {'/odom': Topic('/odom', ODOM_TYPE, imu.t, {'twist.twist.angular.z': yaw_rate})}
    real = {'/odom': Topic('/odom', ODOM_TYPE, odom.t,
                           {'twist.twist.angular.z': odom.fields['twist.twist.angular.z']})}
    return sim, real


def tricycle_pair(path=None, half: int = 2) -> tuple:
    """
    Return (sim, real) of the tricycle: joints derived from the external tracker vs the encoders.

    The simulation is the nominal robot of the data set's header (steering
    gain, traction wheel radius, wheel base, the tracked sensor 1.5 m ahead
    of base_link) following the tracked motion: its steering angle
    ``atan2(omega L, v)`` and traction wheel rate ``sqrt(v^2 + (omega L)^2) / r``
    from the base's speed and yaw rate (central differences over +-``half``
    samples: a box kernel, which the real channels are compared through).
    The real joints are the encoders with the same nominal conversion.
    """
    from robot_calib.core import kinematics as K
    from robot_calib.io.datasets import tricycle
    from robot_calib.mismatch.channels import JOINT_STATE_TYPE
    data = tricycle.load(path or SHARED / 'tricycle' / 'dataset.txt')
    nom = data.nominal
    offset = np.array([nom['lidar_x'], nom['lidar_y'], nom['lidar_yaw']])
    inv = np.broadcast_to(K.inverse(offset), data.tracker_pose.shape)
    base = K.compose(data.tracker_pose, inv)
    t, n, h = data.t, data.t.size, half
    v = np.full(n, np.nan)
    w = np.full(n, np.nan)
    rel = K.compose(K.inverse(base[:-2 * h]), base[2 * h:])
    span = t[2 * h:] - t[:-2 * h]
    v[h:n - h] = rel[:, 0] / span
    w[h:n - h] = np.arctan2(np.sin(rel[:, 2]), np.cos(rel[:, 2])) / span
    length = nom['wheel_base']
    steer = np.arctan2(w * length, np.abs(v)) * np.sign(np.where(v == 0, 1.0, v))
    rate = np.sign(v) * np.hypot(v, w * length) / nom['wheel_radius']
    dt = float(np.median(np.diff(t)))
    box = ('box', h * dt)
    sim = {'/joint_states': Topic('/joint_states', JOINT_STATE_TYPE, t,
                                  {'position.steering_joint': steer,
                                   'velocity.traction_joint': rate},
                                  {'position.steering_joint': box,
                                   'velocity.traction_joint': box})}
    trac_rate = np.gradient(data.traction, t)
    real = {'/joint_states': Topic('/joint_states', JOINT_STATE_TYPE, t,
                                   {'position.steering_joint': nom['steering_scale'] *
                                    data.reading + nom['steering_offset'],
                                    'velocity.traction_joint': trac_rate})}
    return sim, real
