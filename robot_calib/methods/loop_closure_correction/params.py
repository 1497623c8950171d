# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Parameters of the loop-closure correction (seed 001): the single source of their defaults.

``LoopClosureParams.mode`` selects the variant
(:mod:`robot_calib.methods.loop_closure_correction.variants`): ``seed``
(:mod:`.seed`) or ``improved`` (:mod:`.improved`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from robot_calib.core.params import param
from robot_calib.core.scan_match import ScanMatchParams


@dataclass
class KeyframeParams:
    """When keyframes are made and how their memory is bounded."""

    distance: float = param(0.5, 'm', 'distance travelled that makes a new keyframe',
                            minimum=0.01)
    angle: float = param(0.35, 'rad', 'rotation that makes a new keyframe', minimum=0.01)
    voxel: float = param(0.1, 'm', 'voxel size for thinning keyframe points', minimum=0.0)
    max_range: float = param(20.0, 'm', 'beams farther than this are not stored or matched',
                             minimum=0.1)
    cell_size: float = param(2.0, 'm', 'cell size of the spatial keyframe index', minimum=0.1)
    max_per_cell: int = param(6, '', 'keyframes kept per cell (the oldest are kept)',
                              minimum=1)
    max_keyframes: int = param(5000, '', 'keyframes kept at most (memory bound)', minimum=2)


@dataclass
class DetectionParams:
    """Loop detection: which keyframes become candidates."""

    candidates: int = param(3, '', 'Y: keyframes registered per closure attempt', minimum=1)
    base_radius: float = param(1.5, 'm', 'search radius around the current estimate',
                               minimum=0.0)
    radius_gain: float = param(3.0, '', 'radius grows by this many position sigmas',
                               minimum=0.0)
    max_radius: float = param(8.0, 'm', 'largest search radius', minimum=0.0)
    min_loop_travel: float = param(8.0, 'm', 'a keyframe is a loop candidate only when made '
                                   'at least this much driving ago', minimum=0.0)
    max_prefilter: int = param(8, '', 'nearest keyframes checked for similarity', minimum=1)
    similarity_gate: float = param(0.3, 'm', 'distance counting a point as overlapping in the '
                                   'similarity check', minimum=0.0)
    min_similarity: float = param(0.35, '', 'fewest overlapping point fraction for a '
                                  'candidate', minimum=0.0, maximum=1.0)
    similarity_yaw_steps: int = param(7, '', 'yaw hypotheses of the similarity check (over '
                                      '+- 3 heading sigmas)', minimum=1)


@dataclass
class ScoringParams:
    """Scoring of the candidates and refusal rules."""

    inlier_distance: float = param(0.1, 'm', 'a keyframe point is an inlier when the nearest '
                                   'current point is closer (seed: first preset distance)',
                                   minimum=0.0)
    outlier_weight: float = param(1.0, '', 'weight of an outlier in the score (seed: score '
                                  'falls with outliers)', minimum=0.0)
    min_score: float = param(0.2, '', 'lowest accepted score, (inliers - w outliers) / points',
                             minimum=-1.0, maximum=1.0)
    score_margin: float = param(0.1, '', 'a competing hypothesis within this score of the '
                                'best makes the closure ambiguous (improved)', minimum=0.0)
    hypothesis_tolerance: float = param(0.3, 'm', 'candidate poses closer than this (and 0.1 '
                                        'rad) are the same hypothesis', minimum=0.0)
    max_correction_sigma: float = param(4.0, '', 'largest correction in predicted sigmas '
                                        '(improved; larger is a wrong match or a kidnap)',
                                        minimum=0.0)
    min_correction_floor: float = param(0.3, 'm', 'corrections below this are always '
                                        'plausible (0.1 of it in rad for yaw)', minimum=0.0)


@dataclass
class MotionParams:
    """Dead reckoning, its uncertainty model, and the kidnap check."""

    odom_noise: float = param(0.02, 'm/m', 'position sigma growth per metre driven',
                              minimum=0.0)
    heading_noise: float = param(0.02, 'rad/rad', 'heading sigma growth per radian turned',
                                 minimum=0.0)
    heading_drift_rate: float = param(0.002, 'rad/s', 'heading sigma growth per second '
                                      '(residual gyro bias)', minimum=0.0)
    estimate_gyro_bias: bool = param(True, '', 'learn the residual gyro bias from the scan '
                                     'registrations against the last keyframe (improved)')
    bias_random_walk: float = param(2e-5, 'rad/s/sqrt(s)', 'assumed gyro bias random walk of '
                                    'the bias filter', minimum=0.0)
    initial_bias_sigma: float = param(0.005, 'rad/s', 'prior sigma of the residual gyro bias',
                                      minimum=0.0)
    scan_yaw_sigma: float = param(0.002, 'rad', 'heading noise floor of one scan registration',
                                  minimum=1e-6)
    max_gyro_bias: float = param(0.05, 'rad/s', 'largest gyro bias accepted', minimum=0.0)
    estimate_bias_drift: bool = param(True, '', 'also learn how fast the gyro bias drifts '
                                      '(rad/s^2; improved, with estimate_gyro_bias)')
    initial_bias_drift_sigma: float = param(1e-5, 'rad/s^2', 'prior sigma of the gyro bias '
                                            'drift rate', minimum=0.0)
    bias_drift_random_walk: float = param(1e-7, 'rad/s^2/sqrt(s)', 'assumed random walk of '
                                          'the bias drift rate', minimum=0.0)
    estimate_gyro_scale: bool = param(True, '', 'also learn the gyro scale error from the '
                                      'turns the registrations measure (improved, with '
                                      'estimate_gyro_bias)')
    initial_scale_sigma: float = param(0.01, '', 'prior sigma of the gyro scale error',
                                       minimum=0.0)
    max_gyro_scale: float = param(0.05, '', 'largest gyro scale error accepted', minimum=0.0)
    bias_max_rate: float = param(0.1, 'rad/s', 'the bias is learned only from scans taken '
                                 'while turning slower than this (residual scan skew)',
                                 minimum=0.0)
    kidnap_check_interval: float = param(1.0, 's', "how often a standing robot's scan is "
                                         'checked against the last keyframe', minimum=0.0)
    kidnap_min_inlier_ratio: float = param(0.15, '', 'below this inlier ratio against the '
                                           'last keyframe the scan disagrees with odometry',
                                           minimum=0.0, maximum=1.0)
    kidnap_max_offset: float = param(0.5, 'm', 'registration offset from the odometry '
                                     'prediction beyond which the scan disagrees (plus 30 % '
                                     'of the distance since the keyframe)', minimum=0.0)
    kidnap_max_yaw_offset: float = param(0.5, 'rad', 'heading offset from the prediction '
                                         'beyond which the scan disagrees (plus 30 % of the '
                                         'rotation since the keyframe)', minimum=0.0)
    kidnap_checks: int = param(3, '', 'consecutive failed checks that declare a kidnap',
                               minimum=1)
    kidnap_doubt_time: float = param(3.0, 's', 'a weak match to the last keyframe that lasts '
                                     'this long also declares a kidnap', minimum=0.0)


@dataclass
class LoopScanMatchParams(ScanMatchParams):
    """
    The registration settings loop closure uses: the shared ones, lighter by default.

    A loop-closure candidate starts from a prediction already refined by the
    similarity check's yaw search, so the kiss-icp coarse stage is skipped by
    default (``coarse: none``; set it to ``kiss_icp`` for large drifts) and the
    refinement's gate anneals over fewer iterations.
    """

    coarse: str = param('none', '', 'coarse alignment before the refinement: kiss_icp or '
                        'none', choices=('kiss_icp', 'none'))
    refine_anneal_iterations: int = param(4, '', 'iterations over which the gate shrinks '
                                          'from the wide to the narrow value', minimum=1)
    convergence_rotation: float = param(5e-5, 'rad', 'rotation update that ends the '
                                        'refinement', minimum=0.0)
    convergence_translation: float = param(2e-4, 'm', 'translation update that ends the '
                                           'refinement', minimum=0.0)


@dataclass
class LoopClosureParams:
    """Parameters of the loop-closure heading correction (seed 001)."""

    mode: str = param('improved', '', 'improved (refusals, point-to-line, bias learning) or '
                      'seed (kiss-icp, centroid heading, best score)',
                      choices=('improved', 'seed'))
    heading_source: str = param('auto', '', 'heading from the imu gyro, the odom yaw, or auto '
                                '(imu when it arrives)', choices=('auto', 'imu', 'odom'))
    distribute_correction: bool = param(True, '', 'spread each correction over the keyframes '
                                        'made since the last fix (improved)')
    min_valid_beams: int = param(30, '', 'scans with fewer valid beams are rejected', minimum=3)
    map_frame: str = param('map', '', 'frame of the corrected pose (header.frame_id of the '
                           'output): drift-corrected, it may jump at a correction (REP-105 map)')
    publish_tf: bool = param(False, '', 'broadcast the correction map_frame -> odometry frame '
                             'on /tf with every corrected pose (as a localizer does)')
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    detection: DetectionParams = field(default_factory=DetectionParams)
    scoring: ScoringParams = field(default_factory=ScoringParams)
    motion: MotionParams = field(default_factory=MotionParams)
    scan_match: LoopScanMatchParams = field(default_factory=LoopScanMatchParams)
