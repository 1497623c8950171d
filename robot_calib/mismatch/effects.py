# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The library of physical effects: parametric models, units, plausible ranges and regressors.

Each effect predicts the difference ``real - sim`` of one or more channels
as a linear combination of regressors built from the simulation (its own
value, time, the forward speed v, the yaw rate omega, the commanded
acceleration a, the gravity direction). The contract table
(docs/contract.md, "Mismatch findings") fixes the names, models and
parameters. A sensor is modelled as a whole: an effect may act on several
channels at once (a rotated IMU moves the gyro and the accelerometer alike).

IMU:

- ``gyro_bias``: real = sim + b (rad/s); ``gyro_bias_drift``: + b0 + d t
- ``gyro_scale``: real = (1 + s) sim; ``gyro_cross_axis``: real = sim + m sim_other
  (together the gyro's 3x3 scale and misalignment matrix, entry by entry)
- ``accel_bias``: real = sim + b (m/s^2); ``accel_scale``: real = (1 + s) sim
- ``centripetal_acceleration``: real a_y = sim a_y + k v omega; regressor v omega
- ``imu_mounting_rotation``: the real sensor frame is the simulated one rotated by
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``; gyro and accelerometer read ``R^T v``; first
  order ``v + v x theta``; refined exactly afterwards
- ``imu_mounting_tilt``: the same with yaw = 0 (roll and pitch only), on the
  accelerometer alone or on both sensors
- ``lever_arm``: the IMU at ``r`` from the simulated point reads
  ``a + w' x r + w x (w x r)`` (rigid body; w, w' from the simulated gyro)
- ``time_offset`` and ``drive_lag`` are judged per sensor by
  :mod:`robot_calib.mismatch.latency`, before these.

Wheel odometry and joint states:

- ``wheel_radius_scale``: real v = (1 + k) sim v; on a wheel joint velocity the
  radius itself: real rate = sim rate / (1 + k)
- ``track_width_scale``: real omega = sim omega / (1 + k); fitted as (1 + beta) sim,
  k = 1 / (1 + beta) - 1
- ``wheel_slip``: real v = sim v (1 + c a); regressor v a (c in s^2/m)
- ``steering_offset``: real steering angle = sim + offset (rad)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import itertools
from typing import Optional

import numpy as np

from robot_calib.mismatch.channels import IMU_TYPE, JOINT_STATE_TYPE, ODOM_TYPE, PairedTopic

_UID = itertools.count(1)


@dataclass(frozen=True)
class EffectSpec:
    """
    An effect of the library: parameters, units, plausible range, reporting floor, a sentence.

    ``plausible`` is the largest magnitude per parameter that a working
    low-cost sensor or robot shows; a fit beyond it is not reported as that
    effect (the real channel does not follow the simulation). ``floor`` is the
    smallest size (see :func:`effect_size`) worth naming: below it a
    simulation that leaves the effect out behaves the same for a ground
    robot, so a significant but smaller effect is listed as minor.
    """

    name: str
    params: tuple
    units: tuple
    plausible: tuple
    windowable: bool
    what: str
    floor: float = 0.0


SPECS = {s.name: s for s in (
    # zero-rate offsets of MEMS gyros stay within a few deg/s; 0.06 deg/s drifts 3.4 deg/min
    EffectSpec('gyro_bias', ('bias',), ('rad/s',), (0.2,), True,
               'a constant offset of the gyro', 0.001),
    # sensitivity tolerances of MEMS gyros are a few percent
    EffectSpec('gyro_scale', ('scale',), ('',), (0.1,), True,
               'a gyro scale-factor error (the rate reads too large or too small)', 0.01),
    EffectSpec('gyro_bias_drift', ('bias', 'drift'), ('rad/s', 'rad/s^2'), (0.2, 1e-3), True,
               'a gyro offset that changes linearly with time (warm-up)', 0.001),
    # below a millisecond a latency is timestamp jitter
    EffectSpec('time_offset', ('tau',), ('s',), (0.5,), False,
               'a latency between the two recordings', 0.001),
    # 5 mg; MEMS accelerometer offsets reach tens of mg
    EffectSpec('accel_bias', ('bias',), ('m/s^2',), (1.5,), True,
               'a constant offset of the accelerometer', 0.05),
    EffectSpec('centripetal_acceleration', ('gain',), ('',), (1.5,), False,
               'the centripetal acceleration v*omega in turns, missing from the simulation',
               0.1),
    # half a degree: the tolerance of a screwed-on sensor board
    EffectSpec('imu_mounting_tilt', ('roll', 'pitch'), ('rad', 'rad'), (0.35, 0.35), False,
               'the IMU is mounted tilted, so gravity leaks into a_x and a_y', 0.0087),
    # tyres differ by percent; 0.5 % is 5 mm per metre driven
    EffectSpec('wheel_radius_scale', ('scale',), ('',), (0.2,), True,
               'the wheels are larger or smaller than modelled, so odometry speed is scaled',
               0.005),
    # a skid-steer robot turns as if its track were up to twice the geometric one
    EffectSpec('track_width_scale', ('scale',), ('',), (1.0,), True,
               'the effective track width differs, so the odometry yaw rate is scaled', 0.01),
    EffectSpec('wheel_slip', ('coefficient',), ('s^2/m',), (2.0,), True,
               'the wheels slip when accelerating, so odometry speed depends on acceleration',
               0.02),
    # cross-axis sensitivities of MEMS gyros are about a percent
    EffectSpec('gyro_cross_axis', ('coefficient',), ('',), (0.1,), False,
               'an axis misalignment: rotation about another axis leaks into this gyro axis',
               0.01),
    # a scale factor is a property of the sensing element: it does not switch on and off
    EffectSpec('accel_scale', ('scale',), ('',), (0.1,), False,
               'an accelerometer scale-factor error', 0.01),
    EffectSpec('imu_mounting_rotation', ('roll', 'pitch', 'yaw'), ('rad', 'rad', 'rad'),
               (0.35, 0.35, 0.35), False,
               'the real IMU frame is rotated from the simulated one, so rates and '
               'accelerations leak between axes alike', 0.0087),
    # 2 cm at 1 rad/s adds 0.02 m/s^2, the noise of a low-cost accelerometer
    EffectSpec('lever_arm', ('x', 'y', 'z'), ('m', 'm', 'm'), (0.5, 0.5, 0.5), False,
               'the IMU is away from the point the simulation measured, so it feels '
               'centripetal and tangential acceleration when turning', 0.02),
    # beyond the contract table: two time lines that drift apart (a clock rate, a closed-loop
    # run that did not keep the simulated timeline); no constant latency explains it
    EffectSpec('timing_drift', ('tau_start', 'tau_end'), ('s', 's'), (np.inf, np.inf), False,
               'the delay between the recordings changes along the run', 0.001),
    EffectSpec('drive_lag', ('tau',), ('s',), (1.0,), False,
               'the real drive follows its command with a first-order lag', 0.005),
    EffectSpec('drive_gain', ('gain',), ('',), (0.5,), False,
               'the real speed or turn rate settles at (1 + g) times the command', 0.005),
    EffectSpec('drive_dead_time', ('tau',), ('s',), (1.0,), False,
               'the real drive starts to follow its command late (transport delay)', 0.005),
    EffectSpec('drive_rate_limit', ('limit',), ('m/s^2 or rad/s^2',), (np.inf,), False,
               'the real speed or turn rate changes no faster than a limit'),
    EffectSpec('drive_deadband', ('band',), ('m/s or rad/s',), (0.5,), False,
               'commands smaller than a band move nothing', 0.002),
    EffectSpec('turn_speed_loss', ('coefficient',), ('s/rad',), (1.5,), False,
               'the real robot slows down while it turns: v = command (1 - k |omega|)', 0.05),
    EffectSpec('steering_offset', ('offset',), ('rad',), (0.2,), True,
               'the steering encoder reads with a zero offset', 0.002),
    # beyond the contract table, named freely
    # an encoder-to-angle gain set from a wrong gear ratio can be off by a large factor
    EffectSpec('steering_scale', ('scale',), ('',), (0.95,), False,
               'the steering angle is converted from its encoder with a wrong gain', 0.01),
    # unequal wheels turn the odometry while driving straight: yaw rate error ~ speed
    EffectSpec('wheel_radius_difference', ('coefficient',), ('1/m',), (0.5,), True,
               'the left and right wheels differ in radius, so the odometry turns in '
               'proportion to the speed', 0.005),
    EffectSpec('wheel_speed_limit', ('limit', 'half_track'), ('m/s', 'm'), (np.inf, np.inf),
               False, 'the faster wheel is capped (its rim speed; on joint states its rate, '
               'rad/s): speed and turn rate, or both wheels, shrink together', 0.0),
    EffectSpec('yaw_rate_offset', ('offset',), ('rad/s',), (0.2,), True,
               'the two yaw rates differ by a constant: the bias of a gyro used as the '
               'reference, or odometry that turns while driving straight', 0.001),
)}


def effect_size(effect: str, params: dict, duration: float) -> float:
    """
    Return the size of a fitted effect in the units of its floor.

    The largest parameter magnitude; a lever arm's length; for a drifting
    bias the largest offset it reaches over the recording (``duration``, s).
    """
    vals = {k: v for k, v in params.items() if isinstance(v, float) and np.isfinite(v)}
    if effect == 'gyro_bias_drift':
        b, d = vals.get('bias', 0.0), vals.get('drift', 0.0)
        return max(abs(b), abs(b + d * duration))
    if effect == 'lever_arm':
        return float(np.sqrt(sum(v * v for v in vals.values())))
    return max((abs(v) for v in vals.values()), default=0.0)


# Motion that separates two effects that one recording cannot tell apart.
SEPARATE = {
    frozenset(('gyro_bias', 'gyro_scale')): 'standing still for a while, or turning both ways '
    'at several rates, separates a constant offset from a rate-proportional error',
    frozenset(('gyro_bias', 'gyro_bias_drift')): 'rest periods at the start and the end of a '
    'longer recording show whether the offset changes with time',
    frozenset(('gyro_scale', 'gyro_bias_drift')): 'rest periods and turns both ways separate a '
    'drifting offset from a rate-proportional error',
    frozenset(('accel_bias', 'imu_mounting_tilt')): 'tilting the robot (a ramp, or driving '
    'over a slope) changes the gravity direction, which moves a mounting tilt but not a bias',
    frozenset(('accel_bias', 'centripetal_acceleration')): 'turns in both directions and '
    'straight driving separate a constant offset from v*omega',
    frozenset(('imu_mounting_tilt', 'centripetal_acceleration')): 'turns in both directions '
    'separate v*omega from a constant gravity leak',
    frozenset(('wheel_radius_scale', 'wheel_slip')): 'long stretches at constant speed '
    '(no acceleration) separate a radius error from slip under acceleration',
    frozenset(('gyro_scale', 'time_offset')): 'fast rate changes (sharp starts and stops of '
    'turns) separate a latency from a scale error',
    frozenset(('accel_bias', 'accel_scale')): 'poses with the axis up, down and sideways '
    'separate an offset from a scale error',
    frozenset(('yaw_rate_offset', 'wheel_radius_difference')): 'driving at several speeds '
    '(and standing still) separates a constant turn from one that grows with the speed',
    frozenset(('time_offset', 'wheel_slip')): 'accelerating from several cruising speeds, and '
    'turning while accelerating (a clock delays the turn rate too), separate a delay of the '
    'odometry from slip, which grows with speed times acceleration',
    frozenset(('drive_dead_time', 'drive_lag')): 'sharp steps of the command separate a '
    'dead time (the response keeps its shape) from a lag (the response is rounded)',
    frozenset(('time_offset', 'drive_lag')): 'sharp steps of the command separate a pure '
    'delay (the response keeps its shape) from a lag (the response is rounded)',
    frozenset(('imu_mounting_rotation', 'gyro_cross_axis')): 'strong specific force on '
    'several axes (tilting, accelerating) separates a rotated IMU, which moves the '
    'accelerometer too, from a misaligned gyro axis',
    frozenset(('imu_mounting_rotation', 'imu_mounting_tilt')): 'turning about the vertical '
    'while tilted shows a yaw misalignment that a roll/pitch tilt alone cannot',
    frozenset(('lever_arm', 'centripetal_acceleration')): 'turning in place (no forward speed) '
    'shows a lever arm but no centripetal acceleration of the path',
    frozenset(('lever_arm', 'accel_scale')): 'turns at several rates separate a lever arm '
    '(grows with the turn rate squared) from a scale error',
}
DEFAULT_SEPARATE = 'a recording with more varied motion (stops, turns both ways at several ' \
    'rates, accelerations) would separate them'


def separating_motion(a: str, b: str) -> str:
    """Return the motion that would tell effects ``a`` and ``b`` apart."""
    return SEPARATE.get(frozenset((a, b)), DEFAULT_SEPARATE)


@dataclass
class Term:
    """
    A candidate effect on a paired topic: its regressor columns per channel (field).

    ``cols[field]`` is an (n, p) array; the contribution to ``real - sim`` is
    ``cols @ beta`` inside ``window`` (sample indices [i0, i1), None: everywhere).
    ``group`` makes terms exclusive (one per group); ``nonlinear`` marks terms
    refined with their exact model afterwards (``time_offset``, ``imu_mounting_tilt``).
    """

    effect: str
    topic: str
    cols: dict
    group: str
    channel: str
    windowable: bool = True
    window: Optional[tuple] = None
    meta: dict = field(default_factory=dict)
    uid: int = field(default_factory=lambda: next(_UID))

    @property
    def p(self) -> int:
        """Return the number of linear coefficients."""
        return next(iter(self.cols.values())).shape[1]

    def with_window(self, window: Optional[tuple]) -> 'Term':
        """Return a copy acting only inside ``window`` (sample indices)."""
        return replace(self, window=window)

    def with_cols(self, cols: dict, group: str) -> 'Term':
        """Return a new term of the same effect on other regressor columns (its own ``uid``)."""
        return replace(self, cols=cols, group=group, uid=next(_UID))


def _col(x: np.ndarray) -> np.ndarray:
    return np.nan_to_num(np.asarray(x, float)).reshape(-1, 1)


def _informative(x: np.ndarray, sigma: float) -> bool:
    """Return True when a regressor varies beyond the channel noise and is not a constant."""
    ok = np.isfinite(x)
    if ok.sum() < 10:
        return False
    xs = x[ok]
    rms = float(np.sqrt(np.mean(xs ** 2)))
    sd = float(np.std(xs))
    return rms > 0 and sd > max(1e-12, 0.02 * sigma) and sd > 0.05 * rms


def shifted(pt: PairedTopic, f: str, tau: float) -> np.ndarray:
    """
    Return the simulated channel ``f`` delayed by ``tau`` s: sim(t - tau), NaN outside.

    For a noisy simulation (see :func:`~robot_calib.mismatch.channels.regressor_signal`)
    a shift shorter than one sample is taken to first order from the
    leave-one-out signal and derivative, so a sample's own noise never enters.
    """
    from robot_calib.mismatch.channels import loo_derivative
    if pt.sim_noisy.get(f) and abs(tau) < pt.dt:
        d = pt.sim_loo_rate.get(f)
        if d is None:
            d = loo_derivative(pt.sim[f], pt.dt)
            pt.sim_loo_rate[f] = d
        return pt.sim_reg[f] - tau * d
    if pt.sim_src is not None and f in pt.sim_src[1]:
        ts, x = pt.sim_src[0], pt.sim_src[1][f]  # the whole simulated channel
    else:
        ts, x = pt.t, pt.sim[f]
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return np.full(pt.t.size, np.nan)
    tt = ts[ok]
    y = np.interp(pt.t - tau, tt, x[ok])
    eps = 1e-9 * max(pt.dt, 1e-9)
    y[(pt.t - tau < tt[0] - eps) | (pt.t - tau > tt[-1] + eps)] = np.nan
    return y


def tilt_rotate(ax: np.ndarray, ay: np.ndarray, az: np.ndarray, roll: float,
                pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the specific force seen by an IMU mounted with ``roll``, ``pitch`` (rad).

    a_sensor = Rx(roll)^T Ry(pitch)^T a_base (REP-103, sensor orientation in
    base = Ry(pitch) Rx(roll)); level gravity (0, 0, g) becomes
    (-g sin(pitch), g cos(pitch) sin(roll), g cos(pitch) cos(roll)).
    """
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    x1 = cp * ax - sp * az           # Ry(pitch)^T
    z1 = sp * ax + cp * az
    y2 = cr * ay + sr * z1           # Rx(roll)^T
    z2 = -sr * ay + cr * z1
    return x1, y2, z2


def rotate(v: tuple, roll: float, pitch: float, yaw: float) -> tuple:
    """
    Return the components of vectors ``v`` (x, y, z arrays) in a frame rotated by roll, pitch, yaw.

    The real sensor's orientation in the simulated sensor's frame is
    ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (REP-103); a vector reads ``R^T v`` in it.
    To first order ``R^T v = v + v x theta`` with ``theta = (roll, pitch, yaw)``.
    """
    vx, vy, vz = v
    cy, sy = np.cos(yaw), np.sin(yaw)
    x0 = cy * vx + sy * vy           # Rz(yaw)^T
    y0 = -sy * vx + cy * vy
    x1, y2, z2 = tilt_rotate(x0, y0, vz, roll, pitch)
    return x1, y2, z2


def _cross_cols(v: tuple, fields: tuple) -> dict:
    """Return the first-order columns of ``v x theta`` (theta = roll, pitch, yaw) per field."""
    vx, vy, vz = v
    z = np.zeros_like(vx)
    return {fields[0]: np.column_stack((z, -vz, vy)), fields[1]: np.column_stack((vz, z, -vx)),
            fields[2]: np.column_stack((-vy, vx, z))}


def _imu_gyro_terms(pt: PairedTopic, gyro: list, sigma: dict, terms: list, cannot: list) -> list:
    sim = pt.sim_reg
    t = pt.t
    ones = np.ones((t.size, 1))
    moving = [f for f in gyro if _informative(sim[f], sigma[f])]
    for f in gyro:
        ch = f'{pt.name}.{f}'
        terms.append(Term('gyro_bias', pt.name, {f: ones}, f'offset:{f}', ch))
        terms.append(Term('gyro_bias_drift', pt.name,
                          {f: np.column_stack((np.ones_like(t), t))}, f'offset:{f}', ch))
        if f in moving:
            terms.append(Term('gyro_scale', pt.name, {f: _col(sim[f])}, f'scale:{f}', ch))
        for g in moving:
            if g != f:
                terms.append(Term('gyro_cross_axis', pt.name, {f: _col(sim[g])},
                                  f'cross:{f}:{g}', ch, windowable=False,
                                  meta={'source': f'{pt.name}.{g}'}))
    if gyro and not moving:
        cannot.append(f'{pt.name}: the simulated run does not rotate, so gyro scale and '
                      'axis misalignment cannot be judged')
    return moving


def matched(pt: PairedTopic, f: str, x: np.ndarray) -> np.ndarray:
    """
    Return a regressor for field ``f`` passed through that field's smoothing kernel, if any.

    A simulated channel derived from ground truth is the truth seen through a
    known kernel, and the real channel is compared through the same one
    (``pt.kernels[f]``: FIR weights on the topic's grid). A regressor built from
    other signals (the lever arm from the gyro, v*omega from odometry) must be
    seen through it too, or its fitted coefficient shrinks with the bandwidth
    it loses.
    """
    k = (getattr(pt, 'kernels', None) or {}).get(f)
    if k is None or np.size(k) < 2:
        return x
    k = np.asarray(k, float)
    x2 = np.atleast_2d(x.T).T
    out = np.empty_like(x2, dtype=float)
    for j in range(x2.shape[1]):
        out[:, j] = np.convolve(np.nan_to_num(x2[:, j]), k[::-1], mode='same')
    return out.reshape(x.shape)


def _lever_arm_term(pt: PairedTopic, acc: tuple, gyro: tuple, sigma: dict) -> Optional[Term]:
    """Return the lever-arm term: a = a_sim + w' x r + w x (w x r), columns per observable axis."""
    from robot_calib.mismatch.channels import loo_derivative
    w = [np.nan_to_num(pt.sim_reg[f]) for f in gyro]
    wd = [loo_derivative(pt.sim[f], pt.dt) if pt.sim_noisy.get(f)
          else np.gradient(np.nan_to_num(pt.sim[f]), pt.dt) for f in gyro]
    W, Wd = np.column_stack(w), np.column_stack(wd)
    cols = []
    for e in np.eye(3):
        cols.append(np.cross(Wd, e) + np.cross(W, np.cross(W, e)))
    keep = []
    for j in range(3):
        energy = sum(float(np.mean(cols[j][:, i] ** 2)) / sigma[acc[i]] ** 2 for i in range(3))
        if energy * pt.t.size > 100.0:  # the axis moves the residual well beyond noise
            keep.append(j)
    if not keep:
        return None
    colmap = {acc[i]: matched(pt, acc[i], np.column_stack([cols[j][:, i] for j in keep]))
              for i in range(3)}
    return Term('lever_arm', pt.name, colmap, 'lever', f'{pt.name}.{acc[0]}',
                windowable=False, meta={'axes': tuple(keep)})


def _imu_terms(pt: PairedTopic, fields: list, sigma: dict, aux: dict, terms: list,
               cannot: list) -> None:
    gyro = [f for f in fields if f.startswith('angular_velocity.')]
    acc = [f for f in fields if f.startswith('linear_acceleration.')]
    sim = pt.sim_reg
    ones = np.ones((pt.t.size, 1))
    moving = _imu_gyro_terms(pt, gyro, sigma, terms, cannot)
    for f in acc:
        ch = f'{pt.name}.{f}'
        terms.append(Term('accel_bias', pt.name, {f: ones}, f'offset:{f}', ch))
        if _informative(sim[f], sigma[f]):
            terms.append(Term('accel_scale', pt.name, {f: _col(sim[f])}, f'scale:{f}', ch,
                              windowable=False))
    fy = 'linear_acceleration.y'
    if fy in acc:
        v, om = aux.get('v'), aux.get('omega')
        if v is not None and om is not None and _informative(v * om, sigma[fy]):
            terms.append(Term('centripetal_acceleration', pt.name,
                              {fy: matched(pt, fy, _col(v * om))},
                              'centripetal', f'{pt.name}.{fy}', windowable=False))
        elif v is not None and om is not None:
            cannot.append(f'{pt.name}: the run has no turns while moving, so a missing '
                          'centripetal acceleration cannot be judged')
        else:
            cannot.append(f'{pt.name}: no simulated odometry speed, so a missing centripetal '
                          'acceleration cannot be judged')
    fa = tuple(f'linear_acceleration.{a}' for a in 'xyz')
    fg = tuple(f'angular_velocity.{a}' for a in 'xyz')
    if not all(f in acc for f in fa):
        return
    a3 = tuple(np.nan_to_num(sim[f]) for f in fa)
    tilt = _cross_cols(a3, fa)
    terms.append(Term('imu_mounting_tilt', pt.name, {f: c[:, :2] for f, c in tilt.items()},
                      'tilt', f'{pt.name}.{fy}', windowable=False))
    if all(f in gyro for f in fg) and moving:
        rot = dict(tilt)
        rot.update(_cross_cols(tuple(np.nan_to_num(sim[f]) for f in fg), fg))
        # a tilted IMU (roll, pitch) also turns the rates into other gyro axes
        terms.append(Term('imu_mounting_tilt', pt.name, {f: c[:, :2] for f, c in rot.items()},
                          'tilt', f'{pt.name}.{fy}', windowable=False, meta={'gyro': True}))
        terms.append(Term('imu_mounting_rotation', pt.name, rot, 'tilt', f'{pt.name}.{fy}',
                          windowable=False))
        lever = _lever_arm_term(pt, fa, fg, sigma)
        if lever is not None:
            terms.append(lever)
        else:
            cannot.append(f'{pt.name}: the run hardly turns, so a lever arm (the IMU away from '
                          'the simulated point) cannot be judged')


def _odom_terms(pt: PairedTopic, fields: list, sigma: dict, aux: dict, terms: list,
                cannot: list) -> None:
    sim = pt.sim_reg
    fv, fw = 'twist.twist.linear.x', 'twist.twist.angular.z'
    if fv in fields:
        ch = f'{pt.name}.{fv}'
        if _informative(sim[fv], sigma[fv]):
            terms.append(Term('wheel_radius_scale', pt.name, {fv: _col(sim[fv])},
                              f'scale:{fv}', ch))
            a = aux.get('acmd')
            if a is not None and _informative(sim[fv] * a, sigma[fv]):
                terms.append(Term('wheel_slip', pt.name, {fv: _col(sim[fv] * a)}, 'slip', ch))
            else:
                cannot.append(f'{pt.name}: no commanded acceleration, so wheel slip cannot be '
                              'judged')
        else:
            cannot.append(f'{pt.name}: the simulated run does not drive, so wheel radius and '
                          'slip cannot be judged')
    if fw in fields:
        terms.append(Term('yaw_rate_offset', pt.name, {fw: np.ones((pt.t.size, 1))},
                          f'offset:{fw}', f'{pt.name}.{fw}'))
        v = aux.get('v')
        if v is not None and _informative(v, sigma[fw]):
            terms.append(Term('wheel_radius_difference', pt.name, {fw: _col(v)},
                              f'radius_difference:{fw}', f'{pt.name}.{fw}'))
        if _informative(sim[fw], sigma[fw]):
            terms.append(Term('track_width_scale', pt.name, {fw: _col(sim[fw])},
                              f'scale:{fw}', f'{pt.name}.{fw}'))
        else:
            cannot.append(f'{pt.name}: the simulated run does not turn, so the track width '
                          'cannot be judged')


def _joint_terms(pt: PairedTopic, fields: list, sigma: dict, terms: list,
                 cannot: list) -> None:
    """Steering zero offsets (steering joint positions) and per-wheel radii (wheel velocities)."""
    sim = pt.sim_reg
    ones = np.ones((pt.t.size, 1))
    for f in fields:
        kind, _, joint = f.partition('.')
        ch = f'{pt.name}.{f}'
        if kind == 'position' and 'steer' in joint:
            terms.append(Term('steering_offset', pt.name, {f: ones}, f'offset:{f}', ch))
            if _informative(sim[f], sigma[f]):
                terms.append(Term('steering_scale', pt.name, {f: _col(sim[f])}, f'scale:{f}',
                                  ch, windowable=False))
        elif kind == 'velocity' and 'steer' not in joint:
            if _informative(sim[f], sigma[f]):
                terms.append(Term('wheel_radius_scale', pt.name, {f: _col(sim[f])},
                                  f'scale:{f}', ch, meta={'joint_velocity': True}))
            else:
                cannot.append(f'{ch}: the wheel does not turn in the simulated run, so its '
                              'radius cannot be judged')


def candidates(pt: PairedTopic, sigma: dict, aux: dict) -> tuple[list, list]:
    """
    Build the candidate terms for one paired topic (its delay is judged separately).

    :param pt: the paired topic
    :param sigma: noise standard deviation per field (channel units)
    :param aux: regressors on ``pt.t`` from the simulation: ``v`` forward speed
        (m/s), ``omega`` yaw rate (rad/s), ``acmd`` commanded acceleration (m/s^2);
        missing ones absent or NaN
    :returns: (terms, sentences on what cannot be judged)
    """
    terms: list = []
    cannot: list = []
    fields = [f for f in pt.sim if f in sigma]
    if pt.msgtype == IMU_TYPE:
        _imu_terms(pt, fields, sigma, aux, terms, cannot)
    elif pt.msgtype == ODOM_TYPE:
        _odom_terms(pt, fields, sigma, aux, terms, cannot)
    elif pt.msgtype == JOINT_STATE_TYPE:
        _joint_terms(pt, fields, sigma, terms, cannot)
    return terms, cannot


def to_params(term: Term, beta: np.ndarray, cov: np.ndarray) -> tuple[dict, dict]:
    """
    Return the effect's parameters and their standard deviations in the table's units.

    :param term: the term
    :param beta: its fitted linear coefficients
    :param cov: their covariance
    """
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    e = term.effect
    if 'theta' in term.meta:
        vals = np.asarray(term.meta['theta'], float) + np.asarray(beta, float)
        names = SPECS[e].params
        return ({k: float(v) for k, v in zip(names, vals)},
                {k: float(s) for k, s in zip(names, sd)})
    if e == 'gyro_bias_drift':
        return ({'bias': float(beta[0]), 'drift': float(beta[1])},
                {'bias': float(sd[0]), 'drift': float(sd[1])})
    if e in ('imu_mounting_tilt', 'imu_mounting_rotation'):
        names = SPECS[e].params
        return ({k: float(v) for k, v in zip(names, beta)},
                {k: float(v) for k, v in zip(names, sd)})
    if e == 'lever_arm':
        vals, sds = {k: float('nan') for k in 'xyz'}, {k: float('nan') for k in 'xyz'}
        for j, axis in enumerate(term.meta['axes']):
            vals['xyz'[axis]], sds['xyz'[axis]] = float(beta[j]), float(sd[j])
        return vals, sds
    if e == 'track_width_scale' or term.meta.get('joint_velocity'):
        b = float(beta[0])
        k = 1.0 / (1.0 + b) - 1.0
        return {'scale': k}, {'scale': float(sd[0] / (1.0 + b) ** 2)}
    name = SPECS[e].params[0]
    return {name: float(beta[0])}, {name: float(sd[0])}
