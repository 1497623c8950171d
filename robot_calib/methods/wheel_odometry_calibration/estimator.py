# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Wheel odometry calibration against a scene sensor (seed 003 and an improved ML estimator).

Data model
    A *segment* is a stretch of driving between two scene-sensor (lidar) key
    frames: the wheel steps inside it and the sensor's own motion measured by
    scan matching (``sensor_motion``: x, y in m and yaw in rad, expressed in
    the sensor frame at the segment start). Wheel steps are ``(dphi_l,
    dphi_r)`` (rad) for differential drive and ``(dphi, reading)`` (traction
    wheel rotation rad, steering encoder reading rad) for a steered drive
    wheel. Kinematic models: :mod:`robot_calib.core.kinematics` (``base_link``
    midway between the driven wheels, or on the rear axle with the steered
    wheel ``wheel_base`` ahead).

Extrinsic
    The sensor pose in ``base_link`` is ``l = (lidar_x, lidar_y, lidar_yaw)``.
    A base motion ``o`` seen by the sensor is ``l^-1 (+) o (+) l`` (the
    calibration constraint ``l (+) s = o (+) l`` of Censi et al., T-RO 2013,
    eq. 4).

Seed-faithful method (seed 003, steered wheel only)
    Straight stages; per stage the scene rotation (scan match of the stage's
    first and last scan) equals the odometry rotation, which gives the stage's
    steering zero offset; the stage's offset is compared with the
    compensation the stage was driven (or, offline, integrated) with; when the
    difference is below ``seed.offset_threshold`` the stage's (scene
    displacement, odometry displacement) is cached and a counter incremented,
    else both are cleared; every stage uses the previous stage's solved offset
    as its compensation; when the counter reaches ``seed.consecutive_stages``
    the compensation in effect is the calibrated offset, and the wheel radius
    is the average over the cached stages of the radius solving ``R_ext *
    scene_displacement = odometry_displacement``. The text is silent on what
    "the offset is below a threshold" compares; here it is the stage's offset
    minus the compensation it used (the part of the offset the stage still
    sees), which is what makes the iteration converge.

Improved method (both drive types)
    Maximum-likelihood fit of all intrinsic parameters and the sensor pose over
    all segments at once (Censi et al. 2013: the closed form initialises the
    differential case), iterated outlier rejection by the Mahalanobis distance
    of each segment's residual, per-axis noise estimated from the inliers, the
    covariance from the Fisher information, an observability check of the
    information matrix and of what the drive contained, and a verdict.
"""

from __future__ import annotations

from array import array
import bisect
import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any, Callable, Iterable, Optional

import numpy as np
from robot_calib.core import kinematics as K
from robot_calib.core.geometry import wrap_angle
from robot_calib.core.kinematics import Segment
from robot_calib.core.params import param
from robot_calib.core.series import Rows
from robot_calib.methods.wheel_odometry_calibration import drive_detect
from scipy import optimize, stats

DIFF_KEYS = ('left_wheel_radius', 'right_wheel_radius', 'track_width',
             'lidar_x', 'lidar_y', 'lidar_yaw')
STEER_KEYS = ('steering_offset', 'steering_scale', 'wheel_radius', 'wheel_base',
              'lidar_x', 'lidar_y', 'lidar_yaw')
ANGLE_KEYS = ('steering_offset', 'lidar_yaw')


# ------------------------------------------------------------------------------------------
# parameters
# ------------------------------------------------------------------------------------------
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
    scan_time_offset: float = param(
        0.0, 's', 'Added to every scan stamp before it is paired with the wheel data (a '
        'negative value for a lidar whose stamps lag the measurement)', minimum=-1.0,
        maximum=1.0)
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


# ------------------------------------------------------------------------------------------
# data
# ------------------------------------------------------------------------------------------
@dataclass
class CalibResult:
    """A calibration result: estimates, standard deviations, segments used and a verdict."""

    drive_type: str
    values: dict
    stds: dict
    segments_used: int
    verdict: str
    details: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        """Return True when the verdict is 'converged'."""
        return self.verdict == 'converged'

    def to_dict(self) -> dict[str, Any]:
        """Return the flat result mapping of the contract, in contract order (SI units)."""
        out: dict[str, Any] = {'drive_type': self.drive_type}
        for key in keys_of(self.drive_type):
            out[key] = float(self.values.get(key, math.nan))
            out[key + '_std'] = float(self.stds.get(key, math.nan))
        out['segments_used'] = int(self.segments_used)
        out['verdict'] = self.verdict
        return out

    def to_yaml(self) -> str:
        """Return the result as the contract's flat YAML text, with a commented header."""
        lines = ['# wheel_odometry_calibration result (SI units: m, rad); each estimate has a',
                 '# _std twin (one standard deviation, .nan = not estimated by this mode).',
                 '# steering_offset: true wheel angle = steering_scale * reading + offset,',
                 '# counter-clockwise positive seen from above.']
        for key, value in self.to_dict().items():
            if isinstance(value, float):
                text = '.nan' if math.isnan(value) else repr(value)
            elif isinstance(value, int):
                text = str(value)
            else:
                text = _yaml_str(str(value))
            lines.append(f'{key}: {text}')
        return '\n'.join(lines) + '\n'


def _yaml_str(text: str) -> str:
    """Quote a YAML string value safely (single quotes, doubled inside)."""
    return "'" + text.replace("'", "''") + "'"


# ------------------------------------------------------------------------------------------
# models
# ------------------------------------------------------------------------------------------
def pad_steps(segments: list[Segment]) -> np.ndarray:
    """Stack segment steps into a zero-padded array (S, K, 2)."""
    kmax = max((s.steps.shape[0] for s in segments), default=1)
    out = np.zeros((len(segments), max(kmax, 1), 2))
    for i, s in enumerate(segments):
        out[i, :s.steps.shape[0]] = s.steps
    return out


def base_motion(drive_type: str, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """
    Return the base_link motion (S, 3) of padded steps (S, K, 2) for parameters ``x``.

    ``x`` is in :func:`keys_of` order; padding steps (zeros) add nothing.
    """
    if drive_type == 'differential':
        ds, dth = K.diff_arc(steps[..., 0], steps[..., 1], x[0], x[1], x[2])
    else:
        ds, dth = K.steered_arc(steps[..., 0], steps[..., 1], x[2], x[3], x[0], x[1])
    return K.integrate_steps(K.arc_pose(ds, dth))


def predict(drive_type: str, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Return the predicted sensor motion (S, 3) (the last three entries of ``x`` are the pose)."""
    return K.sensor_motion(base_motion(drive_type, x, steps), x[-3:])


def residuals(drive_type: str, x: np.ndarray, steps: np.ndarray,
              measured: np.ndarray) -> np.ndarray:
    """Return predicted minus measured sensor motion (S, 3), yaw wrapped (m, m, rad)."""
    r = predict(drive_type, x, steps) - measured
    r[:, 2] = wrap_angle(r[:, 2])
    return r


# ------------------------------------------------------------------------------------------
# Censi et al. closed form (differential drive)
# ------------------------------------------------------------------------------------------
def censi_closed_form(segments: list[Segment]) -> Optional[np.ndarray]:
    """
    Return Censi's closed-form estimate ``[r_l, r_r, b, lx, ly, lyaw]``, or None.

    Each segment's wheel rotations are summed (the method assumes constant
    wheel speeds inside a segment). Step 1: ``theta_sm = J21 phi_l + J22
    phi_r`` by linear least squares (Censi 2013, eq. 11). Step 2: with ``o_t =
    b c`` linear in the axle ``b``, the translation constraint ``(I - R(o_th))
    l_t + R(l_th) s_t - b c = 0`` is linear in ``x = [b, lx, ly, cos l_th,
    sin l_th]``; minimise ``x' M x`` subject to ``cos^2 + sin^2 = 1`` with a
    Lagrange multiplier: ``det(M + lambda W) = 0`` is quadratic in lambda
    (eq. 22-24).
    """
    if len(segments) < 3:
        return None
    phi = np.array([s.steps.sum(axis=0) for s in segments])
    sm = np.array([s.sensor_motion for s in segments])
    a = phi.T @ phi
    if np.linalg.cond(a) > 1e8:
        return None
    j21, j22 = np.linalg.solve(a, phi.T @ sm[:, 2])  # Censi 2013, eq. 11
    o_th = j21 * phi[:, 0] + j22 * phi[:, 1]
    small = np.abs(o_th) < 1e-12
    safe = np.where(small, 1.0, o_th)
    t1 = np.where(small, 1.0, np.sin(safe) / safe)
    t2 = np.where(small, 0.0, (1.0 - np.cos(safe)) / safe)
    v = 0.5 * (-j21 * phi[:, 0] + j22 * phi[:, 1])  # base travel per unit axle
    cx, cy = v * t1, v * t2
    c, s = np.cos(o_th), np.sin(o_th)
    rows = np.zeros((2 * len(segments), 5))
    rows[0::2] = np.column_stack((-cx, 1 - c, s, sm[:, 0], -sm[:, 1]))
    rows[1::2] = np.column_stack((-cy, -s, 1 - c, sm[:, 1], sm[:, 0]))
    m = rows.T @ rows
    w = np.diag([0.0, 0.0, 0.0, 1.0, 1.0])
    # det(M + lambda W) is a quadratic in lambda: sample it at three points.
    lam = np.array([-1.0, 0.0, 1.0]) * max(1.0, float(np.trace(m)))
    dets = [np.linalg.det(m + li * w) for li in lam]
    coef = np.polyfit(lam, dets, 2)
    best, best_err = None, math.inf
    for root in np.roots(coef):
        if abs(root.imag) > 1e-9 * max(1.0, abs(root.real)):
            continue
        z = m + root.real * w
        _, _, vt = np.linalg.svd(z)
        xv = vt[-1]
        norm = math.hypot(xv[3], xv[4])
        if norm < 1e-12:
            continue
        xv = xv / norm * (1.0 if xv[0] >= 0 else -1.0)
        err = float(xv @ m @ xv)
        if err < best_err:
            best, best_err = xv, err
    if best is None or best[0] <= 0:
        return None
    b = best[0]
    return np.array([-j21 * b, j22 * b, b, best[1], best[2], math.atan2(best[4], best[3])])


def censi_calibrate(segments: list[Segment], outlier_iterations: int = 4,
                    outlier_fraction: float = 0.01) -> Optional[dict]:
    """
    Return Censi's closed form with the authors' outlier trimming and their uncertainty.

    Each iteration solves, then drops the segments above the ``1 -
    outlier_fraction`` quantile of |theta| or xy disagreement. The noise of the
    scan matcher is the per-axis standard deviation of the residuals and the
    covariance the inverse Fisher information at the estimate (Censi 2013,
    Sec. VI). Returns ``{'x', 'cov', 'sigma', 'used'}`` or None.
    """
    segs = list(segments)
    x = None
    history = []
    for _ in range(outlier_iterations + 1):
        x_new = censi_closed_form(segs)
        if x_new is None:
            break
        x = x_new
        history.append(segs)
        steps = pad_steps(segs)
        meas = np.array([s.sensor_motion for s in segs])
        r = residuals('differential', x, steps, meas)
        exy = np.hypot(r[:, 0], r[:, 1])
        eth = np.abs(r[:, 2])
        idx = min(int(round((1.0 - outlier_fraction) * len(segs))), len(segs) - 1)
        keep = (exy <= np.sort(exy)[idx]) & (eth <= np.sort(eth)[idx])
        segs = [s for s, k in zip(segs, keep) if k]
    if x is None:
        return None
    used = history[-1]
    steps = pad_steps(used)
    meas = np.array([s.sensor_motion for s in used])
    r = residuals('differential', x, steps, meas)
    sigma = np.maximum(r.std(axis=0), 1e-9)
    jac = _jacobian('differential', x, steps) / sigma[None, :, None]
    info = jac.reshape(-1, x.size).T @ jac.reshape(-1, x.size)
    cov = _safe_inv(info)
    return {'x': x, 'cov': cov, 'sigma': sigma, 'used': len(used)}


def _jacobian(drive_type: str, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Return d predict / d x (S, 3, P) by central differences."""
    cols = []
    for i in range(x.size):
        h = 1e-6 * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        d = predict(drive_type, xp, steps) - predict(drive_type, xm, steps)
        d[:, 2] = wrap_angle(d[:, 2])
        cols.append(d / (2 * h))
    return np.stack(cols, axis=-1)


def _safe_inv(info: np.ndarray) -> np.ndarray:
    """Invert an information matrix; infinite variances where it is singular."""
    try:
        cov = np.linalg.inv(info)
        if np.all(np.isfinite(cov)) and np.all(np.diag(cov) >= 0):
            return cov
    except np.linalg.LinAlgError:
        pass
    cov = np.linalg.pinv(info)
    w = np.linalg.eigvalsh(info)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        cov = cov + np.diag(np.where(np.diag(info) <= 0, np.inf, 0.0))
    return cov


# ------------------------------------------------------------------------------------------
# improved joint ML estimator
# ------------------------------------------------------------------------------------------
def _prior_sigma(keys: tuple, nominal: dict, sp: SolverParams) -> np.ndarray:
    out = []
    for k in keys:
        if k in ANGLE_KEYS:
            out.append(sp.prior_angle_sigma)
        elif k in ('lidar_x', 'lidar_y'):
            out.append(sp.prior_lidar_sigma)
        else:
            out.append(sp.prior_rel_sigma * max(abs(nominal[k]), 1e-6))
    return np.array(out)


def _init_lidar_yaw(drive_type: str, x: np.ndarray, steps: np.ndarray,
                    meas: np.ndarray) -> float:
    """Return the yaw aligning base translations with sensor translations (rad)."""
    base = base_motion(drive_type, x, steps)
    ok = (np.hypot(meas[:, 0], meas[:, 1]) > 1e-3) & (np.abs(base[:, 2]) < 0.1)
    if ok.sum() < 2:
        return float(x[-1])
    b, s = base[ok, :2], meas[ok, :2]
    # base ~= R(yaw) s  ->  yaw = atan2(sum s x b, sum s . b)
    cross = np.sum(s[:, 0] * b[:, 1] - s[:, 1] * b[:, 0])
    dot = np.sum(s[:, 0] * b[:, 0] + s[:, 1] * b[:, 1])
    return math.atan2(cross, dot)


def _init_steered(x: np.ndarray, steps: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """
    Return a global initial guess of the steered-wheel intrinsics from rotations and travel.

    The rotation of a segment, ``sum r dphi sin(scale reading + offset) / L``,
    does not depend on the sensor pose: a grid over (scale, offset) with the
    best ``r / L`` in closed form for each picks the basin; the travel of
    nearly straight segments then gives ``r`` (the lever arm cancels when the
    segment hardly turns).
    """
    x = x.copy()
    dphi, reading = steps[..., 0], steps[..., 1]
    rot = meas[:, 2]
    best = (math.inf, x[0], x[1], x[2] / x[3])
    scales = x[1] * np.geomspace(0.1, 10.0, 41)
    offsets = x[0] + np.linspace(-0.3, 0.3, 31)
    for sc in scales:
        ang = sc * reading[None] + offsets[:, None, None]
        g = np.sum(dphi[None] * np.sin(ang), axis=2)  # (O, S)
        rho = np.sum(g * rot[None], axis=1) / np.maximum(np.sum(g * g, axis=1), 1e-30)
        cost = np.sum((rho[:, None] * g - rot[None]) ** 2, axis=1)
        i = int(np.argmin(cost))
        if cost[i] < best[0] and rho[i] > 0:
            best = (float(cost[i]), float(offsets[i]), float(sc), float(rho[i]))
    _, x[0], x[1], rho = best
    ang = x[1] * reading + x[0]
    fwd = np.sum(dphi * np.cos(ang), axis=1)
    dist = np.hypot(meas[:, 0], meas[:, 1])
    ok = (np.abs(rot) < 0.05) & (np.abs(fwd) > 1e-9)
    if ok.sum() >= 2:
        r = float(np.sum(dist[ok] * np.abs(fwd[ok])) / np.sum(fwd[ok] ** 2))
        if r > 0:
            x[2] = r
    x[3] = x[2] / rho
    return x


def joint_fit(drive_type: str, segments: list[Segment], nominal: dict,
              sp: Optional[SolverParams] = None, x0: Optional[np.ndarray] = None) -> dict:
    """
    Fit all parameters of a drive type over all segments (ML with outlier rejection).

    Minimises ``sum_k |(predict_k(x) - sm_k) / sigma|^2 + |(x - x_nom) / sigma_prior|^2``
    (Censi 2013, eq. 9, plus a weak prior that only matters along directions
    the drive leaves unobservable). ``sigma`` (per axis x, y, yaw) is
    re-estimated from the inliers each iteration; a segment is an outlier when
    its squared Mahalanobis distance exceeds the chi-square (3 dof) quantile
    of ``outlier_sigma``. Returns ``x`` (in :func:`keys_of` order), ``cov``,
    ``sigma``, ``inliers`` (bool per segment), ``residuals`` and ``info``.
    """
    sp = sp or SolverParams()
    keys = keys_of(drive_type)
    x_nom = np.array([nominal[k] for k in keys], dtype=float)
    psig = _prior_sigma(keys, nominal, sp)
    steps = pad_steps(segments)
    meas = np.array([s.sensor_motion for s in segments]).reshape(-1, 3)
    if x0 is None:
        x0 = x_nom.copy()
        if drive_type == 'differential':
            cf = censi_closed_form(segments)
            if cf is not None and np.all(np.isfinite(cf)) and np.all(cf[:3] > 0):
                x0 = cf
        else:
            x0 = _init_steered(x0, steps, meas)
        if drive_type != 'differential' or x0 is x_nom:
            x0[-1] = _init_lidar_yaw(drive_type, x0, steps, meas)
    x = np.asarray(x0, dtype=float).copy()
    inl = np.ones(len(segments), bool)
    r0 = residuals(drive_type, x, steps, meas)
    sigma = _robust_sigma(r0)
    gate = stats.chi2.ppf(stats.chi2.cdf(sp.outlier_sigma ** 2, 1), 3)
    scale = np.where(np.abs(x_nom) > 1e-9, np.abs(x_nom), 1.0)
    for it in range(sp.outlier_iterations + 1):
        s_in, m_in = steps[inl], meas[inl]

        def fun(z, s_in=s_in, m_in=m_in, sig=sigma):
            xx = z * scale
            r = residuals(drive_type, xx, s_in, m_in) / sig
            return np.concatenate((r.ravel(), (xx - x_nom) / psig))

        sol = optimize.least_squares(fun, x / scale, method='lm', x_scale='jac',
                                     xtol=1e-12, ftol=1e-12, max_nfev=200 * x.size)
        x = sol.x * scale
        r = residuals(drive_type, x, steps, meas)
        sigma = _robust_sigma(r[inl]) if it < sp.outlier_iterations else sigma
        d2 = np.sum((r / sigma) ** 2, axis=1)
        new = d2 <= gate
        if new.sum() < max(3, x.size):
            new = inl
        if it == sp.outlier_iterations or (it >= 2 and np.array_equal(new, inl)):
            inl = new
            break
        inl = new
    r = residuals(drive_type, x, steps, meas)
    if inl.sum() >= 2:
        sigma = np.maximum(r[inl].std(axis=0) * np.sqrt(inl.sum() / max(inl.sum() - 1, 1)),
                           1e-9)
    jac = _jacobian(drive_type, x, steps[inl]) / sigma[None, :, None]
    jflat = jac.reshape(-1, x.size)
    info_data = jflat.T @ jflat
    info = info_data + np.diag(1.0 / psig ** 2)
    cov = _safe_inv(info)
    return {'x': x, 'cov': cov, 'sigma': sigma, 'inliers': inl, 'residuals': r,
            'info': info, 'info_data': info_data, 'prior_sigma': psig, 'keys': keys}


def _robust_sigma(r: np.ndarray) -> np.ndarray:
    """Return per-column robust standard deviations (1.4826 MAD), floored."""
    if r.shape[0] == 0:
        return np.ones(3)
    med = np.median(r, axis=0)
    mad = 1.4826 * np.median(np.abs(r - med), axis=0)
    return np.maximum(mad, np.array([1e-6, 1e-6, 1e-7]))


# ------------------------------------------------------------------------------------------
# observability and verdict
# ------------------------------------------------------------------------------------------
def drive_content(segments: list[Segment], sp: SolverParams) -> dict:
    """Count straight, left-turn and right-turn segments from the measured sensor motion."""
    if not segments:
        return {'segments': 0, 'straight': 0, 'left': 0, 'right': 0, 'still': 0}
    m = np.array([s.sensor_motion for s in segments])
    dist = np.hypot(m[:, 0], m[:, 1])
    moving = dist >= sp.min_motion
    return {'segments': len(segments),
            'straight': int(np.sum(moving & (np.abs(m[:, 2]) < sp.straight_rotation))),
            'left': int(np.sum(m[:, 2] > sp.turn_rotation)),
            'right': int(np.sum(m[:, 2] < -sp.turn_rotation)),
            'still': int(np.sum(~moving & (np.abs(m[:, 2]) < sp.turn_rotation)))}


_ADVICE = {
    'left_wheel_radius': 'drive more straight segments',
    'right_wheel_radius': 'drive more straight segments',
    'wheel_radius': 'drive more straight segments',
    'track_width': 'turn both ways',
    'wheel_base': 'turn both ways with larger steering angles',
    'steering_scale': 'turn both ways with larger steering angles',
    'steering_offset': 'drive more straight segments',
    'lidar_x': 'turn on the spot or in tight curves both ways',
    'lidar_y': 'turn on the spot or in tight curves both ways',
    'lidar_yaw': 'drive more straight segments',
}


def verdict_of(drive_type: str, values: dict, stds: dict, content: dict, n_used: int,
               n_outliers: int, sp: SolverParams, extra: Iterable[str] = ()) -> str:
    """
    Return 'converged' or a sentence saying what the drive lacked.

    Checks the drive's content (segments, straight segments, turns each way),
    the outlier fraction and every parameter's standard deviation against its
    tolerance (the observability check on the information matrix).
    """
    problems = list(extra)
    if content['segments'] == 0:
        problems.append('too little data: no usable segments (need wheel data and matching '
                        'scans)')
        text = '; '.join(dict.fromkeys(problems))
        return text[0].upper() + text[1:]
    if n_used < sp.min_segments:
        problems.append(f'too little data ({n_used} usable segments, need {sp.min_segments})')
    if content['straight'] < sp.min_straight_segments and content['left'] + content['right'] \
            >= content['segments'] - content['still']:
        problems.append(f'drive more straight segments (have {content["straight"]}, need '
                        f'{sp.min_straight_segments})')
    if content['left'] < sp.min_turn_segments or content['right'] < sp.min_turn_segments:
        problems.append(f'turn both ways (left turns {content["left"]}, right turns '
                        f'{content["right"]}, need {sp.min_turn_segments} each)')
    total = n_used + n_outliers
    if total and n_outliers > sp.max_outlier_fraction * total:
        problems.append(f'{n_outliers} of {total} segments disagree with the model (wheel slip '
                        'or failed scan matches): drive slower on a grippy floor')
    weak = []
    for k in keys_of(drive_type):
        s = stds.get(k, math.nan)
        v = values.get(k, math.nan)
        if k in ANGLE_KEYS:
            bad = not s <= sp.max_angle_std
        elif k in ('lidar_x', 'lidar_y'):
            bad = not s <= sp.max_lidar_std
        else:
            bad = not s <= sp.max_rel_std * max(abs(v), 1e-9)
        if bad:
            weak.append(k)
    if weak:
        advice = sorted({_ADVICE[k] for k in weak})
        problems.append(f'poorly determined: {", ".join(weak)} ({"; ".join(advice)})')
    if not problems:
        return 'converged'
    text = '; '.join(dict.fromkeys(problems))
    return text[0].upper() + text[1:]


def calibrate(drive_type: str, segments: list[Segment], params: WheelCalibParams,
              extra_problems: Iterable[str] = (), x0: Optional[np.ndarray] = None) -> CalibResult:
    """
    Run the improved joint estimator and return a result with stds and a verdict.

    ``x0`` (in :func:`keys_of` order) warm-starts the fit (streaming updates);
    None starts from the global initialisation.
    """
    sp = params.solver
    nominal = params.nominal()
    keys = keys_of(drive_type)
    content = drive_content(segments, sp)
    if len(segments) < 3:
        values = {k: nominal[k] for k in keys}
        stds = {k: math.nan for k in keys}
        verdict = verdict_of(drive_type, values, stds, content, len(segments), 0, sp,
                             extra_problems)
        if verdict == 'converged':
            verdict = 'Too little data'
        return CalibResult(drive_type, values, stds, 0, verdict, {'content': content})
    fit = joint_fit(drive_type, segments, nominal, sp, x0=x0)
    x, cov = fit['x'], fit['cov']
    values = {k: float(v) for k, v in zip(keys, x)}
    values['lidar_yaw'] = wrap_angle(values['lidar_yaw'])
    with np.errstate(invalid='ignore'):
        std = np.sqrt(np.diag(cov))
    stds = {k: float(v) for k, v in zip(keys, std)}
    n_in = int(fit['inliers'].sum())
    n_out = len(segments) - n_in
    inl_segs = [s for s, k in zip(segments, fit['inliers']) if k]
    verdict = verdict_of(drive_type, values, stds, drive_content(inl_segs, sp), n_in, n_out,
                         sp, extra_problems)
    details = {'content': content, 'outliers': n_out, 'sigma': fit['sigma'].tolist(),
               'x': x.tolist(),
               'covariance': cov.tolist(), 'keys': list(keys),
               'information_eigenvalues': np.linalg.eigvalsh(fit['info_data']).tolist()}
    return CalibResult(drive_type, values, stds, n_in, verdict, details)


# ------------------------------------------------------------------------------------------
# seed 003: steered-wheel stages with the gate / counter logic
# ------------------------------------------------------------------------------------------
@dataclass
class StageRecord:
    """What the seed logic did with one stage."""

    index: int
    compensation: float
    offset: float
    residual: float
    accepted: bool
    counter: int
    radius: float
    t1: float = math.nan


class SeedSteeredCalibrator:
    """
    Seed 003 (steered drive wheel): stage-by-stage zero offset, then the wheel radius.

    Feed straight stages with :meth:`update` (streaming) or all at once with
    :meth:`run`. The wheel base and steering scale are taken as nominal (the
    seed does not estimate them); the extrinsic ``R_ext`` is the nominal lidar
    yaw.
    """

    def __init__(self, params: Optional[WheelCalibParams] = None):
        """Start with the nominal offset as the first compensation."""
        self.params = params or WheelCalibParams(drive_type='steered_wheel', mode='seed')
        self.compensation = self.params.steering_offset
        self.counter = 0
        self.candidates: list[tuple[np.ndarray, np.ndarray]] = []
        self.records: list[StageRecord] = []
        self.offset: Optional[float] = None
        self.radius: Optional[float] = None
        self.stages_needed: Optional[int] = None
        self._final: tuple = ([], [])

    def stage_offset(self, seg: Segment) -> float:
        """
        Solve "scene rotation = odometry rotation" for the stage's zero offset (rad).

        ``sum_j r dphi_j sin(scale reading_j + c) / L = scene_rotation``
        (kinematics of :mod:`robot_calib.core.kinematics`) solved for ``c`` by
        Newton's method from the constant-reading closed form.
        """
        p = self.params
        dphi, reading = seg.steps[:, 0], seg.steps[:, 1]
        travel = p.wheel_radius * float(np.sum(dphi))
        scene = float(seg.sensor_motion[2])
        if abs(travel) < 1e-9:
            return math.nan
        s = np.clip(p.wheel_base * scene / travel, -1.0, 1.0)
        mean_reading = float(np.sum(dphi * reading) / np.sum(dphi))
        c = math.asin(s) - p.steering_scale * mean_reading  # seed 003: scene = odometry rotation
        for _ in range(20):
            ang = p.steering_scale * reading + c
            f = p.wheel_radius * np.sum(dphi * np.sin(ang)) / p.wheel_base - scene
            df = p.wheel_radius * np.sum(dphi * np.cos(ang)) / p.wheel_base
            if abs(df) < 1e-12:
                break
            step = f / df
            c -= step
            if abs(step) < 1e-12:
                break
        return float(c)

    def update(self, seg: Segment) -> StageRecord:
        """Process one straight stage; return what the gate and counter did."""
        p = self.params
        comp = self.compensation
        off = self.stage_offset(seg)
        resid = off - comp if math.isfinite(off) else math.inf
        accepted = abs(resid) < p.seed.offset_threshold
        radius = math.nan
        if accepted:
            d_odo = K.integrate_steps(
                K.arc_pose(*K.steered_arc(seg.steps[None, :, 0], seg.steps[None, :, 1],
                                          p.wheel_radius, p.wheel_base, comp,
                                          p.steering_scale)))[0] / p.wheel_radius
            c, s = math.cos(p.lidar_yaw), math.sin(p.lidar_yaw)
            d_scene = np.array([c * seg.sensor_motion[0] - s * seg.sensor_motion[1],
                                s * seg.sensor_motion[0] + c * seg.sensor_motion[1]])
            self.candidates.append((d_scene, d_odo[:2]))
            self.counter += 1
            # seed 003: R_ext * scene_displacement = odometry_displacement (radius r)
            g = d_odo[:2]
            radius = float(d_scene @ g / max(g @ g, 1e-12))
        else:
            self.candidates.clear()
            self.counter = 0
        rec = StageRecord(len(self.records), comp, off, resid, accepted, self.counter, radius,
                          float(seg.t1))
        self.records.append(rec)
        if self.offset is None and self.counter >= p.seed.consecutive_stages:
            self.offset = comp
            radii = [float(ds @ g / max(g @ g, 1e-12)) for ds, g in self.candidates]
            self.radius = float(np.mean(radii))
            self.stages_needed = len(self.records)
            self._final = (radii, [r.offset for r in self.records[-len(radii):]])
        if math.isfinite(off):
            self.compensation = off  # next stage compensates with this stage's offset
        return rec

    def run(self, stages: Iterable[Segment]) -> CalibResult:
        """Process all stages (stops updating once converged) and return the result."""
        for seg in stages:
            if self.offset is not None:
                break
            self.update(seg)
        return self.result()

    def result(self, extra_problems: Iterable[str] = ()) -> CalibResult:
        """Return the seed result so far (nominal values where the seed has none)."""
        p = self.params
        nominal = p.nominal()
        values = {k: nominal[k] for k in STEER_KEYS}
        stds = {k: math.nan for k in STEER_KEYS}
        problems = list(extra_problems)
        if self.offset is not None:
            values['steering_offset'] = self.offset
            values['wheel_radius'] = self.radius
            radii, offs = self._final
            n = len(radii)
            if n > 1:
                stds['wheel_radius'] = float(np.std(radii, ddof=1) / math.sqrt(n))
                # the offset is one stage's solution (the compensation in effect): its
                # spread over the consistent stages, not divided by sqrt(n)
                stds['steering_offset'] = float(np.std(offs, ddof=1))
            verdict = 'converged' if not problems else '; '.join(problems)
        else:
            n_stages = len(self.records)
            if n_stages == 0:
                problems.append('drive more straight segments (no straight stage found)')
            else:
                problems.append(
                    f'drive more straight segments ({n_stages} stages, {self.counter} '
                    f'consecutive consistent, need {p.seed.consecutive_stages})')
            verdict = '; '.join(problems)
            verdict = verdict[0].upper() + verdict[1:]
        used = len(self._final[0]) if self.offset is not None else 0
        details = {'stages': [dataclasses.asdict(r) for r in self.records],
                   'stages_needed': self.stages_needed}
        return CalibResult('steered_wheel', values, stds, used, verdict, details)


def censi_result(segments: list[Segment], params: WheelCalibParams,
                 extra_problems: Iterable[str] = ()) -> CalibResult:
    """
    Return the Censi-faithful differential result (``mode: seed`` for differential drive).

    Seed 003 covers the steered wheel only; for differential drive the
    published baseline (Censi et al. 2013 closed form with the authors' outlier
    trimming and Fisher-information uncertainty) is the reference mode.
    """
    sp = params.solver
    content = drive_content(segments, sp)
    out = censi_calibrate(segments) if len(segments) >= 3 else None
    if out is None:
        nominal = params.nominal()
        values = {k: nominal[k] for k in DIFF_KEYS}
        stds = {k: math.nan for k in DIFF_KEYS}
        verdict = verdict_of('differential', values, stds, content, len(segments), 0, sp,
                             list(extra_problems) + ['the closed form has no solution'])
        return CalibResult('differential', values, stds, 0, verdict, {'content': content})
    values = {k: float(v) for k, v in zip(DIFF_KEYS, out['x'])}
    with np.errstate(invalid='ignore'):
        stds = {k: float(v) for k, v in zip(DIFF_KEYS, np.sqrt(np.diag(out['cov'])))}
    n_out = len(segments) - out['used']
    verdict = verdict_of('differential', values, stds, content, out['used'], 0, sp,
                         extra_problems)
    return CalibResult('differential', values, stds, out['used'], verdict,
                       {'content': content, 'outliers': n_out, 'sigma': out['sigma'].tolist()})


def solve(params: WheelCalibParams, segments: list[Segment],
          stages: Optional[list[Segment]] = None,
          extra_problems: Iterable[str] = ()) -> CalibResult:
    """Return the result of the configured mode: the seed stages or the joint estimator."""
    if params.mode == 'seed':
        if params.drive_type != 'steered_wheel':
            return censi_result(segments, params, extra_problems)
        return SeedSteeredCalibrator(params).run(stages or [])
    return calibrate(params.drive_type, segments, params, extra_problems)


MatchFn = Callable[[Any, Any, np.ndarray], Optional[tuple[np.ndarray, dict]]]


def _interp_pose(times: list, poses: list, t: float) -> np.ndarray:
    """Return the pose linearly interpolated at ``t`` from samples (times s, poses [3])."""
    i = min(max(bisect.bisect_left(times, t), 1), len(times) - 1)
    t0, t1 = times[i - 1], times[i]
    w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
    return poses[i - 1] + w * (poses[i] - poses[i - 1])


def _scan_end(scan: Any) -> float:
    """Return the time (s) of the last beam a scan measured."""
    return scan.time_span()[1]


# ------------------------------------------------------------------------------------------
# streaming front end: wheel data + scans -> segments (and seed stages) -> result
# ------------------------------------------------------------------------------------------
def default_matcher(source: np.ndarray, target: Any, guess: np.ndarray) -> Optional[tuple]:
    """
    Register ``source`` points to a prepared ``target`` (robot_calib.core.scan_match).

    Returns ``(pose, info)`` (pose of the source frame in the target frame, m,
    m, rad) or None when the match failed or is degenerate.
    """
    from robot_calib.core import scan_match
    res = scan_match.register(source, target, guess)
    if not res.ok:
        return None
    return np.asarray(res.pose, dtype=float), {'rmse': float(res.rmse),
                                               'min_eigenvalue': float(res.min_eigenvalue)}


def prepare_target(points: np.ndarray) -> Any:
    """Prepare key-frame points as a registration target (scan_match.PreparedScan)."""
    from robot_calib.core import scan_match
    return scan_match.PreparedScan(points)


@dataclass
class _KeyFrame:
    t: float
    points: np.ndarray
    target: Any
    odom: np.ndarray
    scan: Any = None


class WheelCalibrator:
    """
    Cut a calibration drive into segments between key-frame scans and calibrate.

    Feed samples with :meth:`update` (streaming: wheel data as ``JointStateSample``
    or ``OdomSample``, scans as ``ScanSample``) or a whole recording with
    :meth:`run`; :meth:`solve` returns the :class:`CalibResult` of the
    configured mode. Wheel data: joint positions (rad) of the named joints; a
    traction or wheel position that jumps by about 2 pi is unwrapped (using
    the joint velocity when present), a steering reading is wrapped to (-pi,
    pi]. With ``odom`` only, the nominal geometry inverts the odometry into
    virtual wheel rotations (so the nominal parameters must be those the
    odometry source uses). A key frame closes a segment after
    ``keyframe.distance`` or ``keyframe.angle`` of nominal odometry motion; its
    scan is registered against the previous key frame's scan, guessed from the
    nominal odometry. In ``steered_wheel`` drives consecutive straight
    segments also form the seed's stages, whose first and last scans are
    matched directly (seed 003).
    """

    def __init__(self, params: Optional[WheelCalibParams] = None, matcher: Optional[Any] = None,
                 prepare: Optional[Any] = None, max_range: float = 30.0):
        """Create an empty calibrator (``matcher``/``prepare`` replace the scan registration)."""
        self.params = params or WheelCalibParams()
        p = self.params
        self.nominal = p.nominal()
        self.sensor_pose = np.array([p.lidar_x, p.lidar_y, p.lidar_yaw], dtype=float)
        self.matcher = matcher or default_matcher
        self.prepare = prepare or prepare_target
        self.max_range = max_range
        self.joint_names = drive_detect.JointNames(p.left_wheel_joint, p.right_wheel_joint,
                                                   p.traction_joint, p.steering_joint)
        self._joints: Optional[tuple[str, str]] = None
        self._seen_names: tuple = ()
        self.drive_problem = ''
        """Why the drive type is not known, or contradicts the joints ('' when fine)."""
        self.configured_drive = p.drive_type
        self.drive_source = 'configured' if p.drive_type != 'auto' else 'undecided'
        self._pending: list[Any] = []
        self.counts = {'wheel_samples': 0, 'scans': 0, 'match_attempts': 0, 'match_failed': 0,
                       'wheel_gaps': 0, 'encoder_unwraps': 0, 'stages': 0,
                       'stage_match_failed': 0, 'scans_without_wheel_data': 0,
                       'missing_joints': 0}
        self._set_drive(p.drive_type if p.drive_type != 'auto' else drive_detect.DIFFERENTIAL)

    def _set_drive(self, drive: str) -> None:
        """(Re)start the calibration for ``drive``: wheel data and segments so far are dropped."""
        self.drive = drive
        self.params = dataclasses.replace(self.params, drive_type=drive)
        self.x_nom = np.array([self.nominal[k] for k in keys_of(drive)], dtype=float)
        self.segments: list[Segment] = []
        self.seed = SeedSteeredCalibrator(self.params) if drive == 'steered_wheel' else None
        self._stage: list[Segment] = []
        self._stage_start: Optional[_KeyFrame] = None
        self._warm: Optional[np.ndarray] = None
        self._reset_wheels()
        self._use_joints = False
        self._odom_prev: Optional[Any] = None

    # -- wheel input ----------------------------------------------------------------------
    def set_sensor_pose(self, x: float, y: float, yaw: float) -> None:
        """Set the nominal sensor pose in base_link (m, m, rad), e.g. from /tf_static."""
        self.sensor_pose = np.array([x, y, yaw], dtype=float)
        self.nominal.update(lidar_x=float(x), lidar_y=float(y), lidar_yaw=float(yaw))
        self.params = dataclasses.replace(self.params, lidar_x=float(x), lidar_y=float(y),
                                          lidar_yaw=float(yaw))
        self.x_nom[-3:] = self.sensor_pose
        if self.seed is not None and not self.seed.records:
            self.seed.params = self.params

    def _step_pose(self, da: float, b0: float, b1: float) -> np.ndarray:
        """Return the nominal base motion of one wheel step."""
        x = self.x_nom
        if self.drive == 'differential':
            ds, dth = K.diff_arc(da, b1 - b0, x[0], x[1], x[2])
        else:
            ds, dth = K.steered_arc(da, 0.5 * (b0 + b1), x[2], x[3], x[0], x[1])
        return K.arc_pose(ds, dth)

    def add_wheel(self, t: float, a: float, b: float, va: float = math.nan,
                  vb: float = math.nan) -> None:
        """
        Add one wheel sample: differential (phi_l, phi_r) or steered (traction, reading).

        :param t: time (s)
        :param a: left wheel / traction joint position (rad)
        :param b: right wheel position / steering reading (rad)
        :param va: velocity of ``a`` (rad/s, NaN when unknown), used to unwrap
        :param vb: velocity of ``b`` (rad/s, NaN when unknown)
        """
        if self.drive == 'steered_wheel':
            b = wrap_angle(b)
        if self._last_raw is None:
            self._t.append(t)
            self._a.append(a)
            self._b.append(b)
            self._pose.append(np.zeros(3))
            self._last_raw = (t, a, b)
            self.counts['wheel_samples'] += 1
            return
        t0, a0, b0 = self._last_raw
        da = self._unwrap(a - a0, va, t - t0)
        db = self._unwrap(b - b0, vb, t - t0) if self.drive == 'differential' else 0.0
        self._last_raw = (t, a, b)
        na = self._a[-1] + da
        nb = self._b[-1] + db if self.drive == 'differential' else b
        step = self._step_pose(da, self._b[-1], nb)
        self._pose.append(K.compose(self._pose[-1], step))
        self._t.append(t)
        self._a.append(na)
        self._b.append(nb)
        self.counts['wheel_samples'] += 1
        self._drain()

    def _unwrap(self, d: float, v: float, dt: float) -> float:
        two_pi = 2 * math.pi
        if math.isfinite(v):
            k = round((d - v * dt) / two_pi)
        else:
            k = round(d / two_pi) if abs(d) > math.pi else 0
        if k:
            self.counts['encoder_unwraps'] += 1
        return d - k * two_pi

    def add_joint_state(self, js: Any) -> bool:
        """Add a ``JointStateSample``; return False when the drive's joints are absent."""
        if tuple(js.names) != self._seen_names:
            self._on_joint_names(tuple(js.names))
        if self._joints is None:
            self.counts['missing_joints'] += 1
            return False
        (a, va), (b, vb) = js.get(self._joints[0]), js.get(self._joints[1])
        if not (math.isfinite(a) and math.isfinite(b)):
            self.counts['missing_joints'] += 1
            return False
        if not self._use_joints:
            self._use_joints = True
            self._reset_wheels()
        self.add_wheel(js.t, a, b, va, vb)
        return True

    @property
    def drive_joints(self) -> tuple[str, ...]:
        """Return the two joints in use: (left, right) or (traction, steering); () for none."""
        return self._joints or ()

    def _on_joint_names(self, names: tuple) -> None:
        """
        Tell the drive (``auto``) or check it (configured) from a new set of joint names.

        ``auto`` decides once, at the first names that tell exactly one drive
        (odometry integrated before under the assumed drive is dropped). A
        configured drive whose joints are absent while the joints of the other
        drive are present is recorded in :attr:`drive_problem`: the result is
        then never ``converged``.
        """
        self._seen_names = names
        found, why = drive_detect.detect(names, self.joint_names)
        if self._joints is not None:
            return
        if self.configured_drive == 'auto':
            if found is None:
                self.drive_problem = (f'drive type not told by joint_states ({why}): set '
                                      'drive_type and the joint names')
                return
            if found.drive_type != self.drive or self.counts['wheel_samples']:
                self._set_drive(found.drive_type)
            self._joints, self.drive_source, self.drive_problem = found.joints, found.how, ''
            return
        joints = self.joint_names.configured(self.drive)
        if all(j in names for j in joints):
            self._joints, self.drive_problem = joints, ''
        elif found is not None and found.drive_type != self.drive:
            self.drive_problem = (f'joint_states carry {found.joints[0]} and {found.joints[1]}: '
                                  f'the robot looks {found.drive_type}, but drive_type is '
                                  f'{self.drive} (set drive_type: {found.drive_type}, or auto)')

    def _reset_wheels(self) -> None:
        # the whole drive is kept for the final re-deskew: compact storage (8 bytes a value)
        self._t, self._a, self._b = array('d'), array('d'), array('d')
        self._pose = Rows(3)
        self._last_raw: Optional[tuple] = None
        self._kf: Optional[_KeyFrame] = None
        self._stage, self._stage_start = [], None

    def add_odom(self, od: Any) -> bool:
        """Add an ``OdomSample`` as virtual wheel rotations; False when joints are used instead."""
        if self._use_joints:
            return False
        prev = self._odom_prev
        self._odom_prev = od
        if prev is None:
            self.add_wheel(od.t, 0.0, 0.0 if self.drive == 'differential' else
                           (0.0 - self.nominal['steering_offset'])
                           / self.nominal['steering_scale'])
            return True
        rel = K.compose(K.inverse(np.array([prev.x, prev.y, prev.yaw])),
                        np.array([od.x, od.y, od.yaw]))
        dth = wrap_angle(rel[2])
        chord = math.hypot(rel[0], rel[1])
        arc = 1.0 if abs(dth) < 1e-9 else (dth / 2) / math.sin(dth / 2)
        ds = math.copysign(chord, rel[0]) * arc
        n = self.nominal
        if self.drive == 'differential':
            dl = (ds - n['track_width'] * dth / 2) / n['left_wheel_radius']
            dr = (ds + n['track_width'] * dth / 2) / n['right_wheel_radius']
            self.add_wheel(od.t, self._a[-1] + dl, self._b[-1] + dr)
        else:
            lat = n['wheel_base'] * dth
            dw = math.copysign(math.hypot(ds, lat), ds if ds != 0 else 1.0)
            if abs(dw) < 1e-12:
                reading = self._b[-1]
            else:
                alpha = math.atan2(lat / dw, ds / dw)
                reading = (alpha - n['steering_offset']) / n['steering_scale']
            self.add_wheel(od.t, self._a[-1] + dw / n['wheel_radius'], reading)
        return True

    # -- scans ----------------------------------------------------------------------------
    def add_scan(self, scan: Any) -> None:
        """Add a ``ScanSample`` (processed once wheel data covers its time)."""
        self.counts['scans'] += 1
        if self.params.scan_time_offset:
            scan = dataclasses.replace(scan, t=scan.t + self.params.scan_time_offset)
        self._pending.append(scan)
        if len(self._pending) > 200:
            self._pending.pop(0)
            self.counts['scans_without_wheel_data'] += 1
        self._drain()

    def _drain(self) -> None:
        while self._pending and self._t and _scan_end(self._pending[0]) <= self._t[-1]:
            scan = self._pending.pop(0)
            if scan.t < self._t[0]:
                self.counts['scans_without_wheel_data'] += 1
                continue
            self._on_scan(scan)

    def _odom_at(self, t: float) -> tuple[np.ndarray, int]:
        """Return the nominal odometry pose interpolated at ``t`` and the sample index after."""
        i = bisect.bisect_left(self._t, t)
        if i == 0:
            return self._pose[0].copy(), 0
        if i >= len(self._t):
            return self._pose[-1].copy(), len(self._t) - 1
        t0, t1 = self._t[i - 1], self._t[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        p0, p1 = self._pose[i - 1], self._pose[i]
        return p0 + w * (p1 - p0), i

    def _wheel_at(self, t: float) -> tuple[float, float]:
        i = min(max(bisect.bisect_left(self._t, t), 1), len(self._t) - 1)
        t0, t1 = self._t[i - 1], self._t[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        a = self._a[i - 1] + w * (self._a[i] - self._a[i - 1])
        b = self._b[i - 1] + w * (self._b[i] - self._b[i - 1])
        return a, b

    def _steps(self, t0: float, t1: float) -> Optional[np.ndarray]:
        """Return the wheel steps between t0 and t1 (None over a data gap)."""
        i0, i1 = bisect.bisect_right(self._t, t0), bisect.bisect_left(self._t, t1)
        times = np.concatenate(([t0], self._t[i0:i1], [t1]))
        if np.max(np.diff(times)) > self.params.keyframe.max_wheel_gap:
            return None
        a0, b0 = self._wheel_at(t0)
        a1, b1 = self._wheel_at(t1)
        aa = np.concatenate(([a0], self._a[i0:i1], [a1]))
        bb = np.concatenate(([b0], self._b[i0:i1], [b1]))
        if self.drive == 'differential':
            return np.column_stack((np.diff(aa), np.diff(bb)))
        return np.column_stack((np.diff(aa), 0.5 * (bb[1:] + bb[:-1])))

    def _deskewed_points(self, scan: Any, pose_list: Optional[list] = None,
                         sensor_pose: Optional[np.ndarray] = None) -> np.ndarray:
        """
        Return the scan's points (m) in its frame at the stamp, motion-compensated.

        A rotating lidar measures beam i at ``t + i * time_increment``; the
        wheel odometry (nominal, or ``pose_list`` integrated with calibrated
        parameters) moves each point into the sensor frame at the stamp
        (without this, turns bias the scan-matched rotation).
        """
        pose_list = self._pose if pose_list is None else pose_list
        sensor_pose = self.sensor_pose if sensor_pose is None else sensor_pose
        idx, r, ang = scan.beams(self.max_range)
        pts = np.column_stack((r * np.cos(ang), r * np.sin(ang)))
        if scan.time_increment == 0 or len(self._t) < 2 or not len(idx):
            return pts
        first, last = scan.time_span()
        lo = max(bisect.bisect_left(self._t, first) - 1, 0)
        hi = bisect.bisect_right(self._t, last) + 1
        tt = np.asarray(self._t[lo:hi])
        poses = np.asarray(pose_list[lo:hi])
        ti = scan.t + scan.beam_times(idx)
        at = np.column_stack([np.interp(ti, tt, poses[:, j]) for j in range(3)])
        a0 = np.array([np.interp(scan.t, tt, poses[:, j]) for j in range(3)])
        rel = K.compose(np.broadcast_to(K.inverse(a0), at.shape), at)
        srel = K.sensor_motion(rel, sensor_pose)
        c, s = np.cos(srel[:, 2]), np.sin(srel[:, 2])
        return np.column_stack((srel[:, 0] + c * pts[:, 0] - s * pts[:, 1],
                                srel[:, 1] + s * pts[:, 0] + c * pts[:, 1]))

    def _on_scan(self, scan: Any) -> None:
        odom, _ = self._odom_at(scan.t)
        if self._kf is None:
            self._kf = _KeyFrame(scan.t, self._deskewed_points(scan), None, odom, scan)
            return
        kp = self.params.keyframe
        kf = self._kf
        rel = K.compose(K.inverse(kf.odom), odom)
        dist, ang = math.hypot(rel[0], rel[1]), abs(rel[2])
        moving = dist > 1e-3 or ang > 1e-3
        if not (dist >= kp.distance or ang >= kp.angle or
                (scan.t - kf.t >= kp.max_time and moving)):
            if scan.t - kf.t >= kp.max_time:
                self._kf = _KeyFrame(scan.t, self._deskewed_points(scan), None, odom, scan)
            return
        pts = self._deskewed_points(scan)
        steps = self._steps(kf.t, scan.t)
        new_kf = _KeyFrame(scan.t, pts, None, odom, scan)
        if steps is None:
            self.counts['wheel_gaps'] += 1
            self._close_stage()
            self._kf = new_kf
            return
        guess = K.sensor_motion(rel, self.sensor_pose)
        if kf.target is None:
            kf.target = self.prepare(kf.points)
        self.counts['match_attempts'] += 1
        m = self.matcher(pts, kf.target, guess)
        self._kf = new_kf
        if m is None:
            self.counts['match_failed'] += 1
            self._close_stage()
            return
        seg = Segment(kf.t, scan.t, steps, np.asarray(m[0], dtype=float),
                      {**m[1], 'scans': (kf.scan, scan)})
        self.segments.append(seg)
        if self.seed is not None:
            self._stage_add(seg, kf, new_kf)

    # -- seed stages ----------------------------------------------------------------------
    def _is_straight(self, seg: Segment) -> bool:
        n = self.nominal
        ang = n['steering_scale'] * seg.steps[:, 1] + n['steering_offset']
        moving = abs(np.sum(seg.steps[:, 0])) * n['wheel_radius'] > 1e-3
        return moving and bool(np.max(np.abs(ang)) < self.params.seed.straight_steering)

    def _stage_add(self, seg: Segment, start: _KeyFrame, end: _KeyFrame) -> None:
        if not self._is_straight(seg):
            self._close_stage()
            return
        if not self._stage:
            self._stage_start = start
        self._stage.append(seg)
        self._stage_end = end
        length = self.nominal['wheel_radius'] * abs(sum(float(np.sum(s.steps[:, 0]))
                                                        for s in self._stage))
        if length >= self.params.seed.max_stage_length:
            self._close_stage()

    def _close_stage(self) -> None:
        stage, start = self._stage, self._stage_start
        self._stage, self._stage_start = [], None
        if not stage or start is None:
            return
        length = self.nominal['wheel_radius'] * abs(sum(float(np.sum(s.steps[:, 0]))
                                                        for s in stage))
        if length < self.params.seed.min_stage_length:
            return
        guess = np.zeros(3)
        for s in stage:
            guess = K.compose(guess, s.sensor_motion)
        if start.target is None:
            start.target = self.prepare(start.points)
        m = self.matcher(self._stage_end.points, start.target, guess)
        if m is None:
            self.counts['stage_match_failed'] += 1
            return
        steps = np.concatenate([s.steps for s in stage])
        self.counts['stages'] += 1
        self.seed.update(Segment(stage[0].t0, stage[-1].t1, steps,
                                 np.asarray(m[0], dtype=float)))

    # -- API ------------------------------------------------------------------------------
    def update(self, sample: Any) -> None:
        """Add one core sample (JointStateSample, OdomSample or ScanSample)."""
        name = type(sample).__name__
        if name == 'JointStateSample':
            self.add_joint_state(sample)
        elif name == 'OdomSample':
            self.add_odom(sample)
        elif name == 'ScanSample':
            self.add_scan(sample)

    def problems(self) -> list[str]:
        """Return what the input lacked so far (no wheel data, failed matches...)."""
        c = self.counts
        out = [self.drive_problem] if self.drive_problem else []
        if self.configured_drive == 'auto' and self._joints is None and not out:
            out.append("drive type unknown: no joint_states named a drive's joints, and "
                       'odometry alone cannot tell a steered wheel from a differential drive '
                       '(set drive_type)')
        if c['wheel_samples'] < 2:
            out.append('no wheel data (need odom or joint_states with the named joints)')
        if c['scans'] == 0:
            out.append('no scans')
        if c['match_attempts'] and c['match_failed'] > 0.25 * c['match_attempts']:
            out.append(f'scans failed to match in {c["match_failed"]} of '
                       f'{c["match_attempts"]} segments (featureless surroundings or fast '
                       'motion)')
        return out

    def _redeskew(self, x: np.ndarray) -> Optional[list[Segment]]:
        """
        Return the segments re-matched with scans deskewed by the calibrated odometry.

        The first pass deskews with the nominal geometry; a wrong track width or
        radius left in the deskew biases the matched motion (measured: 0.03 deg
        of lidar yaw in simulation). Returns None when no scan needs deskewing.
        """
        segs = [s for s in self.segments if 'scans' in s.info]
        if not segs or not any(s.info['scans'][1].time_increment != 0 for s in segs):
            return None
        a, b = np.asarray(self._a), np.asarray(self._b)
        if self.drive == 'differential':
            steps = np.column_stack((np.diff(a), np.diff(b)))
        else:
            steps = np.column_stack((np.diff(a), 0.5 * (b[1:] + b[:-1])))
        if self.drive == 'differential':
            ds, dth = K.diff_arc(steps[:, 0], steps[:, 1], x[0], x[1], x[2])
        else:
            ds, dth = K.steered_arc(steps[:, 0], steps[:, 1], x[2], x[3], x[0], x[1])
        arcs = K.arc_pose(ds, dth)
        poses = [np.zeros(3)]
        for st in arcs:
            poses.append(K.compose(poses[-1], st))
        lp = np.asarray(x[-3:], dtype=float)
        out = []
        cache: dict = {}

        def points(scan):
            key = id(scan)
            if key not in cache:
                cache[key] = self._deskewed_points(scan, poses, lp)
            return cache[key]
        for seg in segs:
            s0, s1 = seg.info['scans']
            o0 = _interp_pose(self._t, poses, s0.t)
            o1 = _interp_pose(self._t, poses, s1.t)
            guess = K.sensor_motion(K.compose(K.inverse(o0), o1), lp)
            m = self.matcher(points(s1), self.prepare(points(s0)), guess)
            if m is None:
                continue
            out.append(Segment(seg.t0, seg.t1, seg.steps, np.asarray(m[0], dtype=float),
                               {**m[1], 'scans': seg.info['scans']}))
        return out

    def solve(self, final: bool = False) -> CalibResult:
        """Return the result of the configured mode from the data so far."""
        if final:
            self._close_stage()
        extra = self.problems()
        if self.params.mode == 'seed' and self.seed is not None:
            res = self.seed.result(extra)
        elif self.params.mode == 'seed':
            res = censi_result(self.segments, self.params, extra)
        else:
            warm = None if final else self._warm
            res = calibrate(self.drive, self.segments, self.params, extra, x0=warm)
            if 'x' in res.details and np.all(np.isfinite(res.details['x'])):
                self._warm = np.asarray(res.details['x'])
                if final and self.params.redeskew:
                    segs = self._redeskew(self._warm)
                    if segs is not None and len(segs) >= 3:
                        res = calibrate(self.drive, segs, self.params, extra, x0=self._warm)
                        res.details['redeskewed'] = True
        res.details['counts'] = dict(self.counts)
        if self.seed is not None:
            res.details['seed_stages_needed'] = self.seed.stages_needed
        return res

    def run(self, samples: Iterable[Any]) -> CalibResult:
        """Process a whole recording (time-ordered core samples) and return the result."""
        for s in samples:
            self.update(s)
        return self.solve(final=True)
