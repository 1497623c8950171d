# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameters of ``gyro_line_calibration`` (seed 000): the single source of their defaults.

:class:`GyroLineParams` holds the shared input handling (heading source,
mountings, trust guards), the line fitting (:class:`~robot_calib.core.lines.LineParams`),
condition 2 (:class:`MatchParams`) and one group per variant:
:class:`SeedParams` (:mod:`.seed`) and :class:`ImprovedParams` (:mod:`.improved`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from robot_calib.core.lines import LineParams
from robot_calib.core.params import param

_DEG = math.pi / 180.0


@dataclass
class MatchParams:
    """Condition 2 (seed 000, S31-S33) and the correction threshold."""

    length_tolerance: float = param(1.0, 'm', 'Condition 2 (a): largest length difference.',
                                    minimum=0.0)
    endpoint_tolerance: float = param(0.5, 'm', 'Condition 2 (b): largest start-point and '
                                      'end-point distances.', minimum=0.0)
    angle_tolerance: float = param(8.0 * _DEG, 'rad', 'Condition 2 (c): largest angle '
                                   'difference (modulo pi).', minimum=0.0, maximum=math.pi / 2)
    angle_threshold: float = param(0.1 * _DEG, 'rad', 'Correct only when the angle error is '
                                   'above this.', minimum=0.0)


@dataclass
class SeedParams:
    """The seed-faithful mode: phases, weights and re-calibration."""

    phase: str = param('work', '', 'Initial phase: work (store references) or edge_following '
                       '(calibrate); the gyro_line/edge_following topic overrides it.',
                       choices=('work', 'edge_following'))
    phase_switch_time: float = param(0.0, 's', 'If > 0: switch to edge following this long '
                                     'after the first sample (0: never by time).', minimum=0.0)
    w1: float = param(0.8, '', 'Weight of the reference angle (w2 = 1 - w1, w1 > w2).',
                      minimum=0.5, maximum=1.0)
    recalibration_time: float = param(20.0, 's', 'Re-calibrate with a second line after this '
                                      'time while still edge-following.', minimum=0.0)
    recalibration_length_ratio: float = param(1.5, '', "N: a line N times the first line's "
                                              'length is used as the second line (N > 1).',
                                              minimum=1.0)
    max_references: int = param(2000, '', 'Most reference lines stored.', minimum=1)


@dataclass
class ImprovedParams:
    """The automatic mode: filter noise, reference life cycle and wrong-wall guards."""

    heading_sigma0: float = param(0.1 * _DEG, 'rad', 'Initial heading uncertainty (1 sigma).',
                                  minimum=0.0)
    gyro_noise: float = param(0.001, 'rad/sqrt(s)', 'Gyro angle random walk (with margin: a '
                              'consumer MEMS gyro has 1e-4 to 3e-4).', minimum=0.0)
    odom_yaw_noise: float = param(0.005, 'rad/sqrt(s)', 'Random walk of the odometry yaw when it '
                                  'stands in for the gyro (wheel slip).', minimum=0.0)
    bias_sigma0: float = param(60.0 * _DEG / 3600.0, 'rad/s', 'Initial gyro bias uncertainty '
                               "(60 deg/h). Set your gyro's turn-on bias when it is larger "
                               '(0.0087 = 0.5 deg/s for many consumer parts): with a bias far '
                               'beyond this the heading drifts while the filter reports it '
                               'certain.', minimum=0.0)
    bias_walk: float = param(2.0e-5, 'rad/s/sqrt(s)', 'Gyro bias random walk.', minimum=0.0)
    scale_sigma0: float = param(0.01, '', 'Initial gyro scale-error uncertainty (set the '
                                "gyro's specified sensitivity tolerance when larger, e.g. 0.03).",
                                minimum=0.0)
    standstill_update: bool = param(True, '', 'Learn the gyro bias while the odometry stands '
                                    'still (zero angular rate update).')
    standstill_speed: float = param(0.002, 'm/s', 'Odometry slower than this (and turning '
                                    'slower than standstill_rate) stands still.', minimum=0.0)
    standstill_rate: float = param(0.002, 'rad/s', 'Odometry yaw rate below which it may stand '
                                   'still.', minimum=0.0)
    standstill_settle: float = param(0.25, 's', 'The odometry must have stood still this long '
                                     'before the gyro is read as its bias.', minimum=0.0)
    standstill_block: float = param(0.5, 's', 'Standstill time averaged into one bias '
                                    'update.', minimum=0.0)
    standstill_max_rate: float = param(0.035, 'rad/s', 'A mean gyro rate above this while the '
                                       'odometry stands still is motion (pushed, carried), not '
                                       'bias.', minimum=0.0)
    odom_noise: float = param(0.02, 'm/sqrt(m)', 'Odometry position noise per sqrt(metre).',
                              minimum=0.0)
    line_sigma: float = param(0.03, 'm', 'Extra 1-sigma distance noise of a fitted line.',
                              minimum=0.0)
    line_angle_sigma: float = param(0.3 * _DEG, 'rad', 'Extra 1-sigma angle noise of a line.',
                                    minimum=0.0)
    gate_chi2: float = param(9.21, '', 'Chi-square gate (2 dof) on the innovation.',
                             minimum=0.0)
    overlap_margin: float = param(0.3, 'm', 'A reference must overlap the new line within '
                                  'this plus 3 sigma of position.', minimum=0.0)
    ambiguity_distance: float = param(0.1, 'm', 'Two gated references farther apart than this '
                                      'make a line ambiguous.', minimum=0.0)
    ambiguity_angle: float = param(1.0 * _DEG, 'rad', 'Two gated references whose angles differ '
                                   'by more than this make a line ambiguous (facets of a curved '
                                   'wall).', minimum=0.0)
    consistency_sigma: float = param(3.0, '', 'Lines of one scan must agree within this many '
                                     'sigma.', minimum=0.0)
    min_support: int = param(2, '', 'Distinct references (or agreeing scans) a correction '
                             'needs.', minimum=1)
    support_window: float = param(3.0, 's', 'Time over which supporting matches count.',
                                  minimum=0.0)
    confirm_scans: int = param(3, '', 'Scans a tentative reference must be seen in.', minimum=1)
    confirm_time: float = param(1.0, 's', 'Time a tentative reference must span.', minimum=0.0)
    tentative_timeout: float = param(5.0, 's', 'A tentative reference unseen this long is '
                                     'dropped.', minimum=0.0)
    reference_max_heading_sigma: float = param(2.0 * _DEG, 'rad', 'No new reference while the '
                                               'heading is more uncertain.', minimum=0.0)
    reference_max_position_sigma: float = param(0.5, 'm', 'No new reference while the '
                                                'position is more uncertain.', minimum=0.0)
    retire_conflicts: int = param(3, '', 'A reference that disagreed this often (and with more '
                                  'than a third of its matches) is retired.', minimum=1)
    max_references: int = param(400, '', 'Most references kept (least recently seen dropped).',
                                minimum=1)
    update_interval: float = param(0.5, 's', 'Shortest time between two filter updates.',
                                   minimum=0.0)
    lock_contradiction: float = param(0.5, '', 'Share of the lines lying on references over '
                                      'the last 50 scans that, disagreeing with them, means the '
                                      'heading lost the walls (diagnostics WARN).',
                                      minimum=0.0, maximum=1.0)
    lock_min_contradictions: int = param(10, '', 'Fewest disagreeing lines over those scans for '
                                         'that verdict.', minimum=1)
    lock_hold: float = param(120.0, 's', 'The warning holds this long after the walls last '
                             'contradicted the heading.', minimum=0.0)
    refine_references: bool = param(True, '', 'Refine a reference with every supported match '
                                    '(Kalman-weighted angle and distance).')
    reference_floor: bool = param(False, '', 'Never let the heading variance fall below the '
                                  'best reference used (its error is common to every match).')
    correct_position: bool = param(True, '', 'Also correct the position across matched walls.')


@dataclass
class GyroLineParams:
    """Parameters of ``gyro_line_calibration`` (seed 000)."""

    mode: str = param('improved', '', 'improved (automatic) or seed (explicit work then '
                      'edge-following phases).', choices=('improved', 'seed'))
    heading_source: str = param('auto', '', 'imu (gyro z), odom (odometry yaw stands in for '
                                'the gyro) or auto (gyro when IMU data arrive).',
                                choices=('auto', 'imu', 'odom'))
    imu_rpy: list = param([0.0, 0.0, 0.0], 'rad', 'IMU mounting roll, pitch, yaw in base_link '
                          '(used until /tf_static gives it).', length=3)
    laser_pose: list = param([0.0, 0.0, 0.0], 'm, m, rad', 'Laser x, y, yaw in base_link '
                             '(used until /tf_static gives it).', length=3)
    base_frame: str = param('base_link', '', 'Robot body frame in /tf_static.')
    map_frame: str = param('map', '', 'Frame of the corrected pose (header.frame_id of the '
                           'output): drift-corrected, it may jump at a correction (REP-105 map).')
    publish_tf: bool = param(False, '', 'Broadcast the correction map_frame -> odometry frame '
                             'on /tf with every corrected pose (as a localizer does).')
    max_dt: float = param(0.5, 's', 'A larger gap between two IMU or odometry samples is a '
                          'time jump (not integrated; no correction until trusted again).',
                          minimum=0.0)
    max_speed: float = param(2.0, 'm/s', 'Faster odometry steps are resets.', minimum=0.0)
    max_turn_rate: float = param(1.5, 'rad/s', 'No line is used while turning faster.',
                                 minimum=0.0)
    carried_rate: float = param(0.3, 'rad/s', 'Gyro rate while the odometry is stopped that '
                                'means the robot is carried.', minimum=0.0)
    carried_scan_change: float = param(0.3, '', 'Fraction of beams changing by > 5 cm while '
                                       'stopped that means the robot is carried.',
                                       minimum=0.0, maximum=1.0)
    untrusted_hold: float = param(2.0, 's', 'Time after the last untrusted event before lines '
                                  'are used again.', minimum=0.0)
    min_valid_beams: int = param(20, '', 'Fewer valid beams reject the scan.', minimum=1)
    diagnostics_period: float = param(1.0, 's', 'Period of /diagnostics (sensor time); also '
                                      'published at every correction.', minimum=0.0)
    lines: LineParams = field(default_factory=LineParams)
    match: MatchParams = field(default_factory=MatchParams)
    seed: SeedParams = field(default_factory=SeedParams)
    improved: ImprovedParams = field(default_factory=ImprovedParams)
