# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Simulator parameters: every error source is a named, documented, seeded parameter.

:class:`SimParams` is the single source of defaults (``config/sim.yaml`` is
generated from it with ``python -m robot_calib.sim.params``). Dotted names
(``imu.gyro_bias``, ``wheels.left_radius_error``, ...) are the keys of
``robot-calib simulate --set key=value``. A scenario may change the defaults
(``Scenario.defaults``); ``--set`` always wins.

Randomness: every noise stream comes from ``np.random.default_rng(seed)``
spawned into one independent child stream per sensor (see
:data:`robot_calib.sim.engine.STREAMS`), so adding a sensor or changing one
sensor's noise never changes the noise of the others.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from robot_calib.core.constants import GRAVITY
from robot_calib.core.params import describe, param


@dataclass
class RobotParams:
    """Robot kinematics (NOMINAL values: what the robot's software believes)."""

    drive_type: str = param('differential', '', 'differential (two driven wheels) or '
                            'steered_wheel (tricycle: one steered drive wheel at the front, '
                            'base_link on the rear axle centre)',
                            choices=('differential', 'steered_wheel'))
    wheel_radius: float = param(0.05, 'm', 'nominal wheel radius (diff drive: both wheels; '
                                'tricycle: the traction wheel)', minimum=1e-3)
    track_width: float = param(0.30, 'm', 'nominal distance between the left and right wheels',
                               minimum=1e-3)
    wheel_base: float = param(0.60, 'm', 'nominal distance rear axle -> steered wheel '
                              '(tricycle); for diff drive the distance to the front caster '
                              '(used for the pitch on terrain)', minimum=1e-3)
    wheel_time_constant: float = param(0.08, 's', 'first-order lag of the wheel speeds behind '
                                       'their commands (motor + controller)', minimum=0.0)
    steering_time_constant: float = param(0.15, 's', 'first-order lag of the steering angle '
                                          'behind its command (tricycle)', minimum=0.0)
    max_steering_angle: float = param(1.5708, 'rad', 'steering angle limit (tricycle)',
                                      minimum=0.0)
    height: float = param(0.15, 'm', 'height of the centre of mass above base_link (used by '
                          'the free tip-over model)', minimum=0.0)


@dataclass
class WheelParams:
    """True wheel errors and encoders (relative errors: true = nominal * (1 + error))."""

    left_radius_error: float = param(0.0, '', 'relative error of the true left wheel radius',
                                     minimum=-0.5, maximum=0.5)
    right_radius_error: float = param(0.0, '', 'relative error of the true right wheel radius',
                                      minimum=-0.5, maximum=0.5)
    radius_error: float = param(0.0, '', 'relative error of the true traction wheel radius '
                                '(tricycle)', minimum=-0.5, maximum=0.5)
    track_width_error: float = param(0.0, '', 'relative error of the true track width',
                                     minimum=-0.5, maximum=0.5)
    wheel_base_error: float = param(0.0, '', 'relative error of the true wheel base (tricycle)',
                                    minimum=-0.5, maximum=0.5)
    steering_offset: float = param(0.0, 'rad', 'steering zero offset: true angle = reading * '
                                   'steering_scale + steering_offset (CCW positive)',
                                   minimum=-0.5, maximum=0.5)
    steering_scale: float = param(1.0, '', 'steering encoder scale (see steering_offset)',
                                  minimum=0.5, maximum=2.0)
    slip_ratio: float = param(0.0, '', 'constant longitudinal slip: ground speed = rim speed * '
                              '(1 - slip_ratio)', minimum=-0.5, maximum=0.9)
    slip_coefficient: float = param(0.0, 's^2/m', 'acceleration slip: rim speed = ground '
                                    'speed * (1 + c * a), a = wheel acceleration (m/s^2)',
                                    minimum=-1.0, maximum=1.0)
    slip_episodes: list = param([], '', 'slip episodes as a flat list [t0, t1, left, right, '
                                '...]: between t0 and t1 (s) the left/right wheel ground speed '
                                'is rim speed * (1 - ratio) (tricycle: mean ratio)',
                                length_multiple=4, items=float)
    encoder_ticks: int = param(4096, 'ticks/rev', 'encoder resolution; positions are '
                               'quantised to 2 pi / ticks (0: continuous)', minimum=0)
    velocity_noise: float = param(0.0, 'rad/s', 'white noise (1 sigma) of the joint '
                                  'velocities', minimum=0.0)
    steering_noise: float = param(0.0, 'rad', 'white noise (1 sigma) of the steering reading',
                                  minimum=0.0)


@dataclass
class ImuParams:
    """IMU: gyro and accelerometer error model and mounting (imu_link in base_link)."""

    rate: float = param(200.0, 'Hz', 'IMU sample rate', minimum=1.0)
    gyro_bias: list = param([0.0, 0.0, 0.0], 'rad/s', 'constant gyro bias x, y, z (imu_link)',
                            length=3)
    gyro_bias_sigma: float = param(0.0, 'rad/s', 'per-seed random turn-on bias (1 sigma per '
                                   'axis) added to gyro_bias; the drawn value is in truth.json',
                                   minimum=0.0)
    gyro_bias_drift: list = param([0.0, 0.0, 0.0], 'rad/s^2', 'linear bias drift x, y, z',
                                  length=3)
    gyro_warmup: list = param([0.0, 0.0, 0.0], 'rad/s', 'warm-up bias at t = 0 decaying '
                              'exponentially to 0, x, y, z', length=3)
    gyro_warmup_tau: float = param(60.0, 's', 'warm-up time constant', minimum=1e-3)
    gyro_scale: list = param([0.0, 0.0, 0.0], '', 'gyro scale error x, y, z: reading = '
                             '(1 + s) rate', length=3)
    gyro_noise: float = param(0.0, 'rad/s/sqrt(Hz)', 'gyro white noise density (angle random '
                              'walk)', minimum=0.0)
    gyro_random_walk: float = param(0.0, 'rad/s^2/sqrt(Hz)', 'gyro bias random walk density',
                                    minimum=0.0)
    accel_bias: list = param([0.0, 0.0, 0.0], 'm/s^2', 'accelerometer bias x, y, z', length=3)
    accel_scale: list = param([0.0, 0.0, 0.0], '', 'accelerometer scale error x, y, z', length=3)
    accel_noise: float = param(0.0, 'm/s^2/sqrt(Hz)', 'accelerometer white noise density',
                               minimum=0.0)
    accel_random_walk: float = param(0.0, 'm/s^3/sqrt(Hz)', 'accelerometer bias random walk '
                                     'density', minimum=0.0)
    centripetal: bool = param(True, '', 'include the centripetal acceleration v * omega in the '
                              'accelerometer (False mimics simulators that leave it out)')
    gravity: float = param(GRAVITY, 'm/s^2', 'gravity magnitude', minimum=0.0)
    x: float = param(0.0, 'm', 'imu_link position in base_link, x')
    y: float = param(0.0, 'm', 'imu_link position in base_link, y')
    z: float = param(0.05, 'm', 'imu_link position in base_link, z')
    roll: float = param(0.0, 'rad', 'imu_link mounting roll in base_link')
    pitch: float = param(0.0, 'rad', 'imu_link mounting pitch in base_link')
    yaw: float = param(0.0, 'rad', 'imu_link mounting yaw in base_link')
    frame_id: str = param('imu_link', '', 'IMU frame')


@dataclass
class LidarParams:
    """2D lidar: beams, rate, range limits, noise and mounting (laser in base_link)."""

    rate: float = param(10.0, 'Hz', 'scan rate', minimum=0.1)
    beams: int = param(360, '', 'beams per scan (evenly over the field of view)', minimum=1)
    fov: float = param(6.283185307179586, 'rad', 'field of view (2 pi: full turn)',
                       minimum=1e-3, maximum=6.283185307179586)
    range_min: float = param(0.05, 'm', 'minimum range; closer returns are -inf (REP-117)',
                             minimum=0.0)
    range_max: float = param(12.0, 'm', 'maximum range; no return within it is +inf',
                             minimum=0.01)
    noise: float = param(0.01, 'm', 'range white noise (1 sigma)', minimum=0.0)
    dropout: float = param(0.0, '', 'probability that a beam returns NaN (invalid)',
                           minimum=0.0, maximum=1.0)
    no_return: str = param('inf', '', 'value of beams without a return: inf (REP-117) or nan',
                           choices=('inf', 'nan'))
    motion_distortion: bool = param(True, '', 'rotating lidar: beam i is measured at stamp + '
                                    'i * time_increment (the scan is distorted by motion)')
    x: float = param(0.1, 'm', 'laser position in base_link, x')
    y: float = param(0.0, 'm', 'laser position in base_link, y')
    z: float = param(0.2, 'm', 'laser position in base_link, z')
    yaw: float = param(0.0, 'rad', 'laser yaw in base_link')
    upside_down: bool = param(False, '', 'mounted upside down (roll pi in /tf_static): its '
                              'beams sweep clockwise seen from above')
    frame_id: str = param('laser', '', 'lidar frame')
    # Real-scanner effects (all off by default; truth in truth.json 'lidar_effects').
    yaw_error: float = param(0.0, 'rad', 'mounting yaw error: the scan is drawn from yaw + '
                             'yaw_error while /tf_static says yaw (lidar_mounting_yaw)',
                             minimum=-0.5, maximum=0.5)
    x_error: float = param(0.0, 'm', 'mounting x error: drawn from x + x_error, /tf_static '
                           'says x (lidar_mounting_offset)', minimum=-1.0, maximum=1.0)
    y_error: float = param(0.0, 'm', 'mounting y error: drawn from y + y_error, /tf_static '
                           'says y (lidar_mounting_offset)', minimum=-1.0, maximum=1.0)
    time_offset: float = param(0.0, 's', 'stamp offset added to latency.scan: a scan stamped '
                               't saw the motion at t - latency.scan - time_offset (negative: '
                               'stamps lead; lidar_time_offset)', minimum=-1.0, maximum=1.0)
    range_bias: float = param(0.0, 'm', 'range bias: range = (1 + range_scale) true + '
                              'range_bias (range_bias)', minimum=-1.0, maximum=1.0)
    range_scale: float = param(0.0, '', 'relative range scale error (see range_bias; '
                               'range_scale)', minimum=-0.5, maximum=0.5)
    noise_growth: float = param(0.0, 'm/m', 'range noise growth: sigma = noise + noise_growth '
                                '* true range (range_noise_growth)', minimum=0.0, maximum=1.0)
    dropout_beyond: float = param(0.0, 'm', 'beams whose true range exceeds this return '
                                  'nothing with probability dropout_beyond_rate (0: off; '
                                  'dropout_rate)', minimum=0.0)
    dropout_beyond_rate: float = param(1.0, '', 'probability of a lost return beyond '
                                       'dropout_beyond', minimum=0.0, maximum=1.0)
    dropout_incidence: float = param(0.0, 'rad', 'beams meeting the surface at an incidence '
                                     '(from its normal) above this return nothing with '
                                     'probability dropout_incidence_rate (0: off)',
                                     minimum=0.0, maximum=1.5707963267948966)
    dropout_incidence_rate: float = param(1.0, '', 'probability of a lost return at grazing '
                                          'incidence (see dropout_incidence)',
                                          minimum=0.0, maximum=1.0)


@dataclass
class OdomParams:
    """Wheel odometry (from the encoders with the nominal geometry) and joint_states rates."""

    rate: float = param(50.0, 'Hz', 'odom rate', minimum=0.1)
    joint_states_rate: float = param(50.0, 'Hz', 'joint_states rate', minimum=0.1)
    ground_truth_rate: float = param(50.0, 'Hz', 'ground_truth/odom rate', minimum=0.1)
    cmd_vel_rate: float = param(20.0, 'Hz', 'control (cmd_vel) rate', minimum=0.1)
    frame_id: str = param('odom', '', 'odometry frame')
    child_frame_id: str = param('base_link', '', 'robot frame')
    left_joint: str = param('left_wheel_joint', '', 'left wheel joint name (diff drive)')
    right_joint: str = param('right_wheel_joint', '', 'right wheel joint name (diff drive)')
    steering_joint: str = param('steering_joint', '', 'steering joint name (tricycle)')
    traction_joint: str = param('traction_joint', '', 'traction joint name (tricycle)')


@dataclass
class LatencyParams:
    """Per-sensor latency: a message stamped t carries the data measured at t - latency."""

    imu: float = param(0.0, 's', 'IMU latency', minimum=0.0, maximum=1.0)
    odom: float = param(0.0, 's', 'odom latency', minimum=0.0, maximum=1.0)
    joint_states: float = param(0.0, 's', 'joint_states latency', minimum=0.0, maximum=1.0)
    scan: float = param(0.0, 's', 'scan latency', minimum=0.0, maximum=1.0)


@dataclass
class DriveParams:
    """
    Drive dynamics between the velocity command and the wheels (defaults: an ideal drive).

    Per axis (``linear``: forward speed, ``angular``: turn rate), in this order:
    deadband, dead time, steady-state gain, acceleration (rate) limit, first-order
    lag; then the coupling ``v = v (1 - turn_speed_loss |omega|)`` and the
    wheel-speed saturation. The wheels' own lag (``robot.wheel_time_constant``)
    comes after. Names and units follow the mismatch effects of the same names
    (``drive_deadband``, ``drive_dead_time``, ``drive_gain``, ``drive_rate_limit``,
    ``drive_lag``, ``turn_speed_loss``).
    """

    linear_deadband: float = param(0.0, 'm/s', 'forward-speed commands smaller than this move '
                                   'nothing (0: none)', minimum=0.0)
    angular_deadband: float = param(0.0, 'rad/s', 'turn-rate commands smaller than this move '
                                    'nothing (0: none)', minimum=0.0)
    linear_dead_time: float = param(0.0, 's', 'transport delay of the forward-speed command',
                                    minimum=0.0, maximum=5.0)
    angular_dead_time: float = param(0.0, 's', 'transport delay of the turn-rate command',
                                     minimum=0.0, maximum=5.0)
    linear_gain: float = param(0.0, '', 'relative steady-state gain error of the forward '
                               'speed: it settles at (1 + gain) x command', minimum=-0.9,
                               maximum=2.0)
    angular_gain: float = param(0.0, '', 'relative steady-state gain error of the turn rate: '
                                'it settles at (1 + gain) x command', minimum=-0.9, maximum=2.0)
    linear_rate_limit: float = param(0.0, 'm/s^2', 'largest forward acceleration (0: no limit)',
                                     minimum=0.0)
    angular_rate_limit: float = param(0.0, 'rad/s^2', 'largest turn-rate acceleration (0: no '
                                      'limit)', minimum=0.0)
    linear_time_constant: float = param(0.0, 's', 'first-order lag of the forward speed behind '
                                        'its command (0: none)', minimum=0.0, maximum=10.0)
    angular_time_constant: float = param(0.0, 's', 'first-order lag of the turn rate behind '
                                         'its command (0: none)', minimum=0.0, maximum=10.0)
    linear_damping: float = param(0.0, '', 'damping of a second-order forward response of '
                                  'mean delay linear_time_constant (0: first order; below 1 '
                                  'it overshoots)', minimum=0.0, maximum=10.0)
    angular_damping: float = param(0.0, '', 'damping of a second-order turn-rate response of '
                                   'mean delay angular_time_constant (0: first order)',
                                   minimum=0.0, maximum=10.0)
    turn_speed_loss: float = param(0.0, 's/rad', 'forward speed lost in turns: v = v (1 - k '
                                   '|omega|), omega the turn rate after its dynamics (floored '
                                   'at 0)', minimum=0.0, maximum=10.0)
    max_wheel_speed: float = param(0.0, 'rad/s', 'wheel-speed saturation: the faster wheel is '
                                   'capped and the other scaled alike, so speed and turn rate '
                                   'shrink together (0: none)', minimum=0.0)

    def active(self) -> bool:
        """Return True when any dynamics differ from the ideal drive."""
        return any(getattr(self, f.name) != 0.0 for f in dataclasses.fields(self))


@dataclass
class SimParams:
    """All simulator parameters (one dataclass, nested groups give dotted names)."""

    mode: str = param('improved', '', 'unused by the simulator; kept for the common params '
                      'contract', choices=('improved', 'seed'))
    rate: float = param(1000.0, 'Hz', 'internal rate of the true state', minimum=10.0)
    start_time: float = param(0.0, 's', 'time of the first sample (bag time)', minimum=0.0)
    robot: RobotParams = dataclasses.field(default_factory=RobotParams)
    wheels: WheelParams = dataclasses.field(default_factory=WheelParams)
    imu: ImuParams = dataclasses.field(default_factory=ImuParams)
    lidar: LidarParams = dataclasses.field(default_factory=LidarParams)
    odom: OdomParams = dataclasses.field(default_factory=OdomParams)
    latency: LatencyParams = dataclasses.field(default_factory=LatencyParams)
    drive: DriveParams = dataclasses.field(default_factory=DriveParams)


VECTOR_PARAMS = ('imu.gyro_bias', 'imu.gyro_bias_drift', 'imu.gyro_warmup', 'imu.gyro_scale',
                 'imu.accel_bias', 'imu.accel_scale')
"""Parameters that must be 3-vectors (x, y, z)."""


def yaml_text() -> str:
    """Return the documented YAML of the defaults (``config/sim.yaml``)."""
    lines = ['# Simulator defaults (robot-calib simulate; override with --set key=value).',
             '# Generated from robot_calib/sim/params.py (python -m robot_calib.sim.params).',
             '# Scenarios may change some defaults; --set always wins.', 'sim:']
    groups: dict[str, list[Any]] = {}
    for info in describe(SimParams):
        group, _, name = info.name.rpartition('.')
        groups.setdefault(group, []).append((name, info))
    for group, items in groups.items():
        indent = '  '
        if group:
            lines.append(f'  {group}:')
            indent = '    '
        for name, info in items:
            unit = f' [{info.unit}]' if info.unit else ''
            lines.append(f'{indent}# {info.doc}{unit}')
            value = info.default
            if isinstance(value, bool):
                text = 'true' if value else 'false'
            elif isinstance(value, str):
                text = f"'{value}'"
            else:
                text = repr(value)
            lines.append(f'{indent}{name}: {text}')
    return '\n'.join(lines) + '\n'


if __name__ == '__main__':
    print(yaml_text(), end='')
