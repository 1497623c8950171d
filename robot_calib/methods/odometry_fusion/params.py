# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameters of the ``odometry_fusion`` node (seed 004): the single source of their defaults.

:class:`FusionParams` holds the improved filter's settings and the input
geometry; :class:`SeedParams` (``FusionParams.seed``) the seed-faithful
filter's. Every field is a :func:`robot_calib.core.params.param` with its
unit and documentation (``config/robot_calib.yaml`` is generated from them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from robot_calib.core.params import param


@dataclass
class SeedParams:
    """Seed-faithful filter settings (seed 004)."""

    max_speed: float = param(2.0, 'm/s', 'Clamp of the IMU-predicted speed (robot limit)',
                             minimum=0.01)
    max_accel: float = param(3.0, 'm/s^2', 'Clamp of the IMU acceleration (robot limit)',
                             minimum=0.01)
    q_position: float = param(1e-4, 'm^2', 'Process noise Q of x, y per prediction', minimum=0.0)
    q_velocity: float = param(1e-3, 'm^2/s^2', 'Process noise Q of vx, vy per prediction',
                              minimum=0.0)
    q_accel: float = param(1e-2, 'm^2/s^4', 'Process noise Q of ax, ay per prediction',
                           minimum=0.0)
    r_position: float = param(1e-4, 'm^2', 'Odometry noise R_o of x, y per step', minimum=0.0)
    r_velocity: float = param(1e-3, 'm^2/s^2', 'Odometry noise R_o of vx, vy per step',
                              minimum=0.0)
    r_accel: float = param(1e-1, 'm^2/s^4', 'Odometry noise R_o of ax, ay per step', minimum=0.0)
    accuracy_threshold: float = param(0.95, '', 'Lidar accuracy check: valid at or above this',
                                      minimum=0.0, maximum=1.0)


@dataclass
class FusionParams:
    """Parameters of the ``odometry_fusion`` node (SI units)."""

    mode: str = param('improved', '', 'improved (default) or seed (seed-faithful 004)',
                      choices=('improved', 'seed'))
    base_frame: str = param('base_link', '', 'Robot body frame the IMU extrinsic refers to')
    odom_frame: str = param('odom', '', 'Frame of the fused pose (header.frame_id)')
    publish_tf: bool = param(False, '', 'Broadcast odom_frame -> base_frame on /tf with every '
                             'fused pose (as robot_localization does); off when another node '
                             'publishes that transform')
    imu_extrinsic: str = param(
        'auto', '', 'IMU mounting source: auto (tf_static if received, else imu_rpy if non-zero, '
        'else the up axis from gravity at start), param (imu_rpy), tf (only /tf_static), '
        'gravity (up axis from gravity)', choices=('auto', 'param', 'tf', 'gravity'))
    imu_rpy: list = param([0.0, 0.0, 0.0], 'rad',
                          'base_link -> IMU rotation as roll, pitch, yaw (R = Rz Ry Rx)', length=3)
    accel_units: str = param('auto', '', 'IMU acceleration units: auto (detected from the '
                             'gravity magnitude), mps2 or g', choices=('auto', 'mps2', 'g'))
    wheel_source: str = param('auto', '', 'Wheel input: auto (odom; joint_states only when no '
                              'odom arrives within 1 s of it), odom or joint_states',
                              choices=('auto', 'odom', 'joint_states'))
    drive_type: str = param('differential', '', 'Drive of joint_states input: differential or '
                            'steered_wheel (one steered drive wheel ahead of the rear axle)',
                            choices=('differential', 'steered_wheel'))
    wheel_radius: float = param(0.1, 'm', 'Nominal wheel radius (joint_states input)',
                                minimum=1e-4)
    track_width: float = param(0.5, 'm', 'Distance between the wheels (joint_states input)',
                               minimum=1e-3)
    left_wheel_radius: float = param(0.0, 'm', 'Left wheel radius; 0 uses wheel_radius',
                                     minimum=0.0)
    right_wheel_radius: float = param(0.0, 'm', 'Right wheel radius; 0 uses wheel_radius',
                                      minimum=0.0)
    wheel_base: float = param(0.6, 'm', 'Steered wheel: distance rear axle -> steered wheel',
                              minimum=1e-3)
    steering_joint: str = param('steering_joint', '', 'Steered wheel: steering joint name')
    traction_joint: str = param('traction_joint', '', 'Steered wheel: traction joint name')
    left_wheel_joint: str = param('left_wheel_joint', '', 'Left wheel joint name')
    right_wheel_joint: str = param('right_wheel_joint', '', 'Right wheel joint name')
    initial_pose_from_odom: bool = param(True, '', 'Start at the first odometry pose (else 0)')
    gyro_noise: float = param(0.003, 'rad/s/sqrt(Hz)', 'Gyro white-noise density (low-cost '
                              'MEMS incl. vibration)', minimum=1e-6)
    gyro_bias_walk: float = param(2e-5, 'rad/s/sqrt(s)', 'Gyro bias random walk', minimum=0.0)
    gyro_bias_init: float = param(0.01, 'rad/s', 'Initial gyro bias standard deviation',
                                  minimum=1e-6)
    accel_noise: float = param(0.5, 'm/s^2/sqrt(Hz)', 'Forward specific-force noise density as '
                               'the filter sees it: vibration, bumps and terrain pitch of a '
                               'wheeled base, not the datasheet noise', minimum=1e-6)
    accel_bias_walk: float = param(0.005, 'm/s^2/sqrt(s)', 'Accelerometer bias random walk '
                                   '(also absorbs slowly varying slope)', minimum=0.0)
    accel_bias_init: float = param(0.3, 'm/s^2', 'Initial forward accel bias std (mount tilt)',
                                   minimum=1e-6)
    lateral_slip: float = param(0.02, '1/sqrt(s)', 'Lateral position noise per unit speed '
                                '(side slip), m/s/sqrt(Hz) per m/s', minimum=0.0)
    odom_speed_noise: float = param(0.02, 'm/s', 'Wheel speed noise (constant part)',
                                    minimum=1e-6)
    odom_speed_noise_rel: float = param(0.02, '', 'Wheel speed noise per unit speed',
                                        minimum=0.0)
    odom_yaw_rate_noise: float = param(0.02, 'rad/s', 'Wheel yaw-rate noise (constant part)',
                                       minimum=1e-6)
    odom_yaw_rate_noise_rel: float = param(0.1, '', 'Wheel yaw-rate noise per unit yaw rate',
                                           minimum=0.0)
    yaw_rate_scale_init: float = param(0.3, '', 'Initial std of the odometry yaw-rate scale',
                                       minimum=1e-6)
    yaw_rate_scale_walk: float = param(0.002, '1/sqrt(s)', 'Random walk of the odometry '
                                       'yaw-rate scale (surface changes)', minimum=0.0)
    yaw_rate_offset_init: float = param(0.02, 'rad/m', 'Initial std of the odometry yaw rate '
                                        'per unit speed (left/right wheel radius mismatch)',
                                        minimum=1e-6)
    yaw_rate_offset_walk: float = param(1e-4, 'rad/m/sqrt(s)', 'Random walk of the yaw rate '
                                        'per unit speed', minimum=0.0)
    gravity_compensation: bool = param(True, '', 'Track the up direction in base_link (gyro, '
                                       'corrected by the accelerometer) and remove gravity '
                                       'from the forward acceleration on slopes')
    gravity_time_constant: float = param(5.0, 's', 'Time constant of that correction by the '
                                         'accelerometer', minimum=0.05)
    yaw_rate_fit_block: float = param(10.0, 's', 'Block of the odometry yaw-rate calibration '
                                      'over the recording: one unknown offset (the gyro bias '
                                      "error) per block, and the jackknife's unit",
                                      minimum=0.5)
    yaw_rate_fit_min_blocks: int = param(8, '', 'Blocks of accepted motion before that '
                                         'calibration is reported', minimum=3)
    yaw_rate_fit_max_delay: float = param(1.0, 's', 'That calibration searches the delay '
                                          'of the odometry behind the gyro this far either '
                                          'side of odometry_delay (0: no search)',
                                          minimum=0.0, maximum=10.0)
    bias_from_wheels: bool = param(False, '', 'Let the wheel yaw rate correct the gyro bias; '
                                   'off: the bias is a consider state there (wheel slip and '
                                   'radius mismatch mimic a bias) and is learnt at standstill')
    zero_velocity_update: bool = param(True, '', 'Wheels exactly still: pin speed and yaw rate')
    continuous_pose: bool = param(True, '', 'Standstill updates learn the speed and the biases '
                                  'without moving the pose (REP-105: odom is continuous); off: '
                                  'their cross-covariances also correct x, y and yaw, which '
                                  'can jump metres after a long drive')
    zero_velocity_threshold: float = param(1e-3, 'm/s or rad/s', 'Wheel speed and yaw rate '
                                           'below which the robot is taken as stationary',
                                           minimum=0.0)
    gate_probability: float = param(0.9999, '', 'Chi-square gate of each odometry channel '
                                    '(1 dof); 1 disables gating', minimum=0.5, maximum=1.0)
    adaptive: bool = param(True, '', 'On-line odometry noise adaptation (IAE)')
    adaptation: str = param('nis', '', 'nis: one scale per odometry channel on both its '
                            'measurement and process noise, driven to E[NIS] = 1; iae: '
                            "measurement noise only, R = C - H P H' (Mohamed & Schwarz)",
                            choices=('nis', 'iae'))
    adapt_time: float = param(10.0, 's', 'Time constant of the innovation averaging',
                              minimum=0.1)
    adapt_min: float = param(0.01, '', 'Lower bound of the noise scale factor', minimum=1e-3)
    adapt_max: float = param(100.0, '', 'Upper bound of the noise scale factor', minimum=1.0)
    nis_window: int = param(20, '', 'Odometry updates in the NIS moving average', minimum=1)
    max_speed: float = param(3.0, 'm/s', 'Physical speed limit: clamp of the speed state',
                             minimum=0.01)
    max_robot_accel: float = param(5.0, 'm/s^2', 'Forward acceleration limit of the robot: the '
                                   'IMU input is clamped to it', minimum=0.1)
    max_gyro: float = param(35.0, 'rad/s', 'Gyro readings above this are rejected', minimum=0.1)
    max_accel: float = param(160.0, 'm/s^2', 'Accelerometer readings above this are rejected',
                             minimum=1.0)
    sensor_timeout: float = param(0.5, 's', 'A sensor silent this long is stale', minimum=0.01)
    odometry_delay: float = param(0.0, 's', 'How far the wheel odometry lags its stamps '
                                  'against the IMU (improved mode): odometry stamped t is used '
                                  'as the motion at t - odometry_delay, the IMU is held that '
                                  'long, and each estimate is carried to its stamp with the gyro '
                                  'and speed; summary.json estimates.odometry_delay tells it',
                                  minimum=0.0, maximum=2.0)
    odometry_delay_auto: bool = param(False, '', 'When the yaw-rate calibration finds the '
                                      'odometry delay differing from odometry_delay (status ok, '
                                      'by 0.05 s and 3 std), apply the delay found, once, from '
                                      'then on (the odometry of that moment is dropped as stale '
                                      'for about the delay while the IMU is held)')
    max_lag: float = param(0.2, 's', 'Odometry older than the filter by more is rejected',
                           minimum=0.0)
    reset_jump: float = param(1.0, 'm', 'Odometry pose jump beyond twist*dt taken as a reset',
                              minimum=0.01)
    reinit_after: float = param(3.0, 's', 'Re-initialise after this long of rejected odometry',
                                minimum=0.1)
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics', minimum=0.05)
    seed: SeedParams = field(default_factory=SeedParams)
