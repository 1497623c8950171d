# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The simulated motion as regressors of the effects: speed, yaw rate, commanded acceleration."""

from __future__ import annotations

import numpy as np

from robot_calib.mismatch import latency as L
from robot_calib.mismatch import timing
from robot_calib.mismatch.channels import IMU_TYPE, ODOM_TYPE, PairedTopic, Recording, TWIST_TYPES
from robot_calib.mismatch.locate import moving_average


def _interp_within(t_src: np.ndarray, x: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Return ``x`` at ``t_dst``; NaN more than 0.5 s outside its finite samples."""
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return np.full(t_dst.size, np.nan)
    y = np.interp(t_dst, t_src[ok], x[ok])
    y[(t_dst < t_src[ok][0] - 0.5) | (t_dst > t_src[ok][-1] + 0.5)] = np.nan
    return y


def command_slope(t_cmd: np.ndarray, v_cmd: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """
    Return the commanded acceleration (m/s^2) at ``t_dst``: the slope of the command's interval.

    The derivative of the linear interpolant of the commanded speed, as the
    speeds themselves are read: central differences interpolated again would
    spread each acceleration over two command periods, and a slip fitted to
    that smoothed regressor comes out too large (errors in the regressor).
    NaN outside the commands (beyond half a second).
    """
    ok = np.isfinite(v_cmd)
    t, v = t_cmd[ok], v_cmd[ok]
    if t.size < 2:
        return np.full(t_dst.size, np.nan)
    dt = np.diff(t)
    slope = np.where(dt > 0, np.diff(v) / np.where(dt > 0, dt, 1.0), 0.0)
    out = slope[np.clip(np.searchsorted(t, t_dst, side='right') - 1, 0, slope.size - 1)]
    out[(t_dst < t[0] - 0.5) | (t_dst > t[-1] + 0.5)] = np.nan
    return out


def motion_regressors(sim: Recording, real: Recording, pt: PairedTopic, t0: float, notes: list,
                      tau: float = 0.0, lag: float = 0.0) -> dict:
    """
    Return sim regressors on the topic's times: v (m/s), omega (rad/s), acmd (m/s^2).

    ``tau``: the topic's delay (s); the regressors taken from other topics are
    read that much earlier, as the topic's own simulated channels are once
    aligned (a late clock stamps the slip under acceleration late too).
    ``lag``: the drive's first-order lag (s), applied to them alike.
    """

    def late(x: np.ndarray) -> np.ndarray:
        return L.lag_response(timing.filled(x), pt.dt, lag) if lag > 0 else x

    aux: dict = {}
    ta = pt.t + t0 - tau
    odoms = [tp for tp in sim.values() if tp.msgtype == ODOM_TYPE and len(tp) > 2]
    odoms.sort(key=lambda tp: ('truth' not in tp.name, tp.name))
    if odoms:
        o = odoms[0]
        for key, f in (('v', 'twist.twist.linear.x'), ('omega', 'twist.twist.angular.z')):
            if f in o.fields:
                aux[key] = late(_interp_within(o.t, o.fields[f], ta))
    if pt.msgtype == IMU_TYPE and 'angular_velocity.z' in pt.sim:
        aux['omega'] = np.nan_to_num(pt.sim_reg['angular_velocity.z'])
    cmds = [tp for rec in (sim, real) for tp in rec.values()
            if tp.msgtype in TWIST_TYPES and len(tp) > 2]
    if cmds:
        aux['acmd'] = late(command_slope(cmds[0].t, cmds[0].fields['linear.x'], ta))
    elif pt.msgtype == ODOM_TYPE and 'twist.twist.linear.x' in pt.sim:
        v = np.nan_to_num(pt.sim['twist.twist.linear.x'])
        w = max(1, int(round(0.2 / max(pt.dt, 1e-9))))
        aux['acmd'] = np.gradient(moving_average(v, w), pt.t)
        notes.append(f'{pt.name}: no velocity-command topic; the commanded acceleration for '
                     'wheel slip is taken from the simulated speed')
    return {k: np.nan_to_num(v) for k, v in aux.items()}
