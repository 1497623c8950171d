# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameters of ``wheel_odometry_calibration`` (the single source of the defaults).

Also the estimated quantities of each drive type, in solver order: a
differential drive's wheel radii and track width, a steered drive wheel's
steering offset and scale, wheel radius and wheel base, and for both the
lidar pose in ``base_link`` (``lidar_x``, ``lidar_y`` m, ``lidar_yaw`` rad).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from robot_calib.core.params import param

DIFF_KEYS = ('left_wheel_radius', 'right_wheel_radius', 'track_width',
             'lidar_x', 'lidar_y', 'lidar_yaw')
STEER_KEYS = ('steering_offset', 'steering_scale', 'wheel_radius', 'wheel_base',
              'lidar_x', 'lidar_y', 'lidar_yaw')
ANGLE_KEYS = ('steering_offset', 'lidar_yaw')


@dataclass
class SeedParams:
    """Seed 003 stage logic (seed-faithful mode, steered drive wheel)."""

    offset_threshold: float = param(
        0.0005, 'rad', 'A stage counts as consistent when its solved zero offset differs from '
        'the compensation it used by less than this (the seed below-threshold gate)',
        minimum=0.0)
    consecutive_stages: int = param(
        3, '', 'Consecutive consistent stages after which the compensation in effect is the '
        'calibrated zero offset (the seed counter threshold)', minimum=1)
    straight_steering: float = param(
        0.05, 'rad', 'A stretch is a straight stage while |steering angle| (nominal '
        'conversion) stays below this', minimum=0.0)
    min_stage_length: float = param(1.0, 'm', 'Shortest straight stage used', minimum=0.0)
    max_stage_length: float = param(
        4.0, 'm', 'Longest straight stage (longer ones are split so that the first and last '
        'scan still overlap)', minimum=0.1)


@dataclass
class SolverParams:
    """Improved joint estimator: outlier rejection, observability and verdict thresholds."""

    outlier_sigma: float = param(
        3.0, '', 'Segments whose residual is further than this many standard deviations '
        '(Mahalanobis, 3 dof) are rejected as outliers (slip, bad matches)', minimum=1.0)
    outlier_iterations: int = param(6, '', 'Fit / reject iterations', minimum=0)
    min_segments: int = param(20, '', 'Fewest segments for a verdict of converged', minimum=1)
    min_straight_segments: int = param(
        5, '', 'Fewest straight segments (|rotation| below straight_rotation) needed',
        minimum=0)
    min_turn_segments: int = param(
        3, '', 'Fewest turning segments needed in each direction (left and right)', minimum=0)
    straight_rotation: float = param(
        0.02, 'rad', 'A segment rotating less than this (and moving) counts as straight',
        minimum=0.0)
    turn_rotation: float = param(0.05, 'rad', 'A segment rotating more than this is a turn',
                                 minimum=0.0)
    min_motion: float = param(0.02, 'm', 'A segment moving less than this is standing still',
                              minimum=0.0)
    max_rel_std: float = param(
        0.01, '', 'Largest relative standard deviation of a length or scale for converged',
        minimum=0.0)
    max_angle_std: float = param(
        0.0087, 'rad', 'Largest standard deviation of steering offset / lidar yaw for converged',
        minimum=0.0)
    max_lidar_std: float = param(0.02, 'm', 'Largest lidar x/y standard deviation for converged',
                                 minimum=0.0)
    max_outlier_fraction: float = param(
        0.25, '', 'More outliers than this fraction of segments make the verdict fail',
        minimum=0.0, maximum=1.0)
    prior_rel_sigma: float = param(
        0.5, '', 'Weak prior on lengths and scales around nominal (relative standard '
        'deviation); keeps unobservable directions at nominal with an honest large std',
        minimum=1e-6)
    prior_angle_sigma: float = param(0.5, 'rad', 'Weak prior on angles around nominal',
                                     minimum=1e-6)
    prior_lidar_sigma: float = param(1.0, 'm', 'Weak prior on lidar x/y around nominal',
                                     minimum=1e-6)


@dataclass
class KeyframeParams:
    """Key-frame selection that cuts the drive into segments (scan match between key frames)."""

    distance: float = param(0.3, 'm', 'Travel (nominal odometry) that closes a segment',
                            minimum=0.0)
    angle: float = param(0.2, 'rad', 'Rotation (nominal odometry) that closes a segment',
                         minimum=0.0)
    max_time: float = param(3.0, 's', 'Longest segment while moving', minimum=0.1)
    max_wheel_gap: float = param(0.5, 's', 'Wheel data gap that breaks a segment', minimum=0.0)


@dataclass
class WheelCalibParams:
    """Parameters of ``wheel_odometry_calibration`` (geometry named like the result keys)."""

    mode: str = param('improved', '', 'improved (joint ML estimate) or seed (seed 003 stages; '
                      'differential drive: the Censi et al. closed form)',
                      choices=('improved', 'seed'))
    drive_type: str = param('auto', '', 'Drive type of the robot; auto: told by the joints in '
                            'joint_states (steering + traction joint: steered_wheel; left + '
                            'right wheel joint: differential), never guessed from odometry',
                            choices=('auto', 'differential', 'steered_wheel'))
    wheel_radius: float = param(0.05, 'm', 'Nominal wheel radius (steered wheel: traction '
                                'wheel; differential: both wheels unless set below)',
                                minimum=1e-6)
    wheel_base: float = param(1.0, 'm', 'Nominal distance from the rear axle to the steered '
                              'wheel (steered wheel)', minimum=1e-6)
    track_width: float = param(0.3, 'm', 'Nominal distance between the wheels (differential)',
                               minimum=1e-6)
    left_wheel_radius: float = param(0.0, 'm', 'Nominal left wheel radius (0: wheel_radius)',
                                     minimum=0.0)
    right_wheel_radius: float = param(0.0, 'm', 'Nominal right wheel radius (0: wheel_radius)',
                                      minimum=0.0)
    steering_offset: float = param(0.0, 'rad', 'Nominal steering zero offset (true = scale * '
                                   'reading + offset)')
    steering_scale: float = param(1.0, '', 'Nominal steering scale', minimum=1e-6)
    steering_joint: str = param('steering_joint', '', 'Steering joint name in joint_states')
    traction_joint: str = param('traction_joint', '', 'Traction joint name in joint_states')
    left_wheel_joint: str = param('left_wheel_joint', '', 'Left wheel joint name')
    right_wheel_joint: str = param('right_wheel_joint', '', 'Right wheel joint name')
    lidar_x: float = param(0.0, 'm', 'Nominal lidar x in base_link (a /tf_static base_link -> '
                           'scan frame transform overrides it)')
    lidar_y: float = param(0.0, 'm', 'Nominal lidar y in base_link')
    lidar_yaw: float = param(0.0, 'rad', 'Nominal lidar yaw in base_link')
    base_frame: str = param('base_link', '', 'Robot base frame for /tf_static look-ups')
    redeskew: bool = param(
        True, '', 'At the end, deskew the key-frame scans again with the calibrated odometry, '
        're-match them and solve once more (removes the bias a wrong nominal geometry leaves)')
    max_segments: int = param(
        4096, '', 'Most segments kept for the solve. Past it every other one is dropped and '
        'later ones are kept at twice the stride, so the kept ones still span the whole drive '
        'while memory and solve time stay bounded on long recordings and robots calibrating '
        'for days (a 10-minute calibration drive cuts about 3000; 0: keep all)', minimum=0)
    scan_time_offset: float = param(
        0.0, 's', 'Added to every scan stamp before it is paired with the wheel data (a '
        'negative value for a lidar whose stamps lag the measurement)', minimum=-1.0,
        maximum=1.0)
    range_margin: float = param(
        0.05, '', "Returns farther than (1 - range_margin) x the scan's range_max are not "
        'matched: near the limit only the returns whose noise fell short survive, so far walls '
        'read closer and every scan-matched length comes out short (a 4 m lidar: 0.1 % short, '
        'up to 2 std)', minimum=0.0, maximum=0.5)
    update_period: float = param(2.0, 's', 'Period of the estimate update and status message',
                                 minimum=0.0)
    keyframe: KeyframeParams = field(default_factory=KeyframeParams)
    solver: SolverParams = field(default_factory=SolverParams)
    seed: SeedParams = field(default_factory=SeedParams)

    def nominal(self) -> dict[str, float]:
        """Return the nominal value of every estimated quantity (SI)."""
        rl = self.left_wheel_radius or self.wheel_radius
        rr = self.right_wheel_radius or self.wheel_radius
        return {'left_wheel_radius': rl, 'right_wheel_radius': rr,
                'track_width': self.track_width, 'steering_offset': self.steering_offset,
                'steering_scale': self.steering_scale, 'wheel_radius': self.wheel_radius,
                'wheel_base': self.wheel_base, 'lidar_x': self.lidar_x,
                'lidar_y': self.lidar_y, 'lidar_yaw': self.lidar_yaw}


def keys_of(drive_type: str) -> tuple[str, ...]:
    """Return the estimated quantities of a drive type, in solver order."""
    return DIFF_KEYS if drive_type == 'differential' else STEER_KEYS
