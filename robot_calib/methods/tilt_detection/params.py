# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameters of ``tilt_detection`` (the single source of their defaults).

:class:`TiltParams` holds the node's ROS parameters; ``seed`` and ``improved``
hold the settings of the two estimator variants (:mod:`.seed`, :mod:`.improved`).
Units: time s, rates rad/s (settings in deg/s where named so), angles rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from robot_calib.core.constants import GRAVITY
from robot_calib.core.params import param

CLEAR_MARGIN = 0.0873
"""Default hysteresis between ``fall_angle`` and ``clear_angle`` (rad, 5 deg)."""


@dataclass(frozen=True)
class SeedFilterParams:
    """Noise settings of the seed's per-axis Kalman filter (seed 002)."""

    q_angle: float = param(0.001, 'rad^2', 'Process noise of the angle state per step '
                           '(seed: Q_angle)', minimum=0.0)
    q_gyro: float = param(0.0005, '(rad/s)^2', 'Process noise of the gyro bias state per step '
                          '(seed: Q_gyro)', minimum=0.0)
    r_angle: float = param(0.03, 'rad^2', 'Variance of the accelerometer angle observation '
                           '(seed: R)', minimum=1e-12)


@dataclass(frozen=True)
class ImprovedFilterParams:
    """Settings of the whole-sphere attitude estimator (physically motivated defaults)."""

    tau_acc: float = param(3.0, 's', 'Time constant of the low-pass filter of the acceleration '
                           'in the almost-inertial frame (longer: less trust in the '
                           'accelerometer during linear acceleration)', minimum=0.01)
    bias_sigma_init: float = param(0.5, 'deg/s', 'Initial gyro bias uncertainty (1 sigma)',
                                   minimum=0.0)
    bias_forgetting_time: float = param(100.0, 's', 'Time in which the bias uncertainty grows '
                                        'by 0.1 deg/s (bias random walk)', minimum=1.0)
    bias_clip: float = param(2.0, 'deg/s', 'Largest gyro bias the estimator accepts',
                             minimum=0.0)
    bias_sigma_motion: float = param(0.1, 'deg/s', 'Noise of the bias measurement made from '
                                     'inclination corrections in motion', minimum=1e-6)
    bias_vertical_factor: float = param(1e-4, '', 'Relative weight of the bias about the '
                                        'vertical axis in motion (unobservable from gravity)',
                                        minimum=1e-12)
    bias_sigma_rest: float = param(0.03, 'deg/s', 'Noise of the bias measurement at rest',
                                   minimum=1e-6)
    bias_update_period: float = param(0.05, 's', 'Period of the gyro bias Kalman update (the '
                                      'corrections in between are averaged)', minimum=0.0)
    scale_estimation: bool = param(True, '', 'Also estimate the gyro scale factors in motion '
                                   '(from the inclination corrections while turning)')
    scale_sigma_init: float = param(0.01, '', 'Initial gyro scale-factor uncertainty (1 sigma, '
                                    'relative)', minimum=0.0)
    scale_clip: float = param(0.05, '', 'Largest relative gyro scale error accepted',
                              minimum=0.0)
    motion_bias: bool = param(True, '', 'Estimate the gyro bias in motion')
    rest_bias: bool = param(True, '', 'Estimate the gyro bias at rest')
    rest_min_time: float = param(1.5, 's', 'Time the IMU must be still to count as at rest',
                                 minimum=0.0)
    rest_tau: float = param(0.5, 's', 'Time constant of the rest-detection low-pass filters',
                            minimum=0.01)
    rest_gyro_threshold: float = param(2.0, 'deg/s', 'Largest gyro deviation from its mean at '
                                       'rest', minimum=0.0)
    rest_accel_threshold: float = param(0.5, 'm/s^2', 'Largest accelerometer deviation from '
                                        'its mean at rest', minimum=0.0)
    rest_snap_angle: float = param(5.0, 'deg', 'When the IMU is still and the filtered '
                                   'acceleration and the mean accelerometer reading disagree by '
                                   'more than this, the filter restarts from the mean (fast '
                                   'recovery after gyro saturation or a gap; 0: off)',
                                   minimum=0.0)
    rest_snap_time: float = param(0.5, 's', 'How long the IMU must be still (and not '
                                  'turning) before such a restart', minimum=0.0)


@dataclass(frozen=True)
class TiltParams:
    """Parameters of ``tilt_detection`` (names are the node's ROS parameters)."""

    mode: str = param('improved', '', "Estimator: 'improved' (whole-sphere attitude filter) "
                      "or 'seed' (the seed's per-axis Kalman filter)",
                      choices=('improved', 'seed'))
    fall_angle: float = param(math.pi / 4, 'rad', 'Tilt from upright that raises the fall '
                              'alert', minimum=0.0, maximum=math.pi)
    fall_min_duration: float = param(0.02, 's', 'How long the tilt must exceed fall_angle '
                                     'before the alert is raised', minimum=0.0)
    clear_angle: float = param(-1.0, 'rad', 'Tilt below which the robot counts as upright '
                               'again; negative: fall_angle - 0.0873', maximum=math.pi)
    clear_duration: float = param(1.0, 's', 'Upright time that clears the alert', minimum=0.0)
    mounting_rpy: list = param([0.0, 0.0, 0.0], 'rad', 'Rotation of the IMU frame in base_link '
                               '(roll, pitch, yaw); replaced by /tf_static when present', length=3)
    use_tf_static: bool = param(True, '', 'Take the IMU mounting rotation from /tf_static '
                                '(base_link -> IMU frame) when available')
    base_frame: str = param('base_link', '', 'Robot body frame the tilt refers to')
    accel_units: str = param('auto', '', 'Accelerometer units: auto (told from the gravity '
                             'magnitude: 9.81 m/s^2 or 1 g; an IMU whose driver removed gravity '
                             'is reported and raises no alert), mps2 or g',
                             choices=('auto', 'mps2', 'g'))
    max_accel: float = param(16.0 * GRAVITY, 'm/s^2', 'Specific-force norm above which a sample '
                             'is rejected (sensor saturation or garbage)', minimum=0.0)
    max_gyro: float = param(35.0, 'rad/s', 'Rate norm above which a sample is rejected',
                            minimum=0.0)
    max_dt: float = param(0.5, 's', 'Gap between samples above which the filter restarts from '
                          'the accelerometer', minimum=0.0)
    stop_on_alert: bool = param(False, '', 'Publish a zero-velocity cmd_vel while the fall '
                                'alert is raised (cmd_vel is advertised only then)')
    stop_message: str = param('TwistStamped', '', 'Message type of the stop command: '
                              "TwistStamped (what Jazzy's diff_drive_controller takes) or "
                              'Twist', choices=('TwistStamped', 'Twist'))
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics messages (0: every '
                                      'sample)', minimum=0.0)
    seed: SeedFilterParams = field(default_factory=SeedFilterParams)
    improved: ImprovedFilterParams = field(default_factory=ImprovedFilterParams)

    def __post_init__(self) -> None:
        """Check the values that depend on each other."""
        if len(self.mounting_rpy) != 3:
            raise ValueError('mounting_rpy needs 3 values (roll, pitch, yaw in rad)')
        if self.effective_clear_angle() > self.fall_angle:
            raise ValueError('clear_angle must not exceed fall_angle')

    def effective_clear_angle(self) -> float:
        """Return clear_angle (rad), resolving a negative value to fall_angle - 0.0873."""
        if self.clear_angle < 0.0:
            return max(0.0, self.fall_angle - CLEAR_MARGIN)
        return self.clear_angle
