# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Reports of the ``odometry_fusion`` pipeline, made from the filter's result only.

:func:`diagnostic_status` is the ``/diagnostics`` status (NIS, noise
adaptation, bias estimates, rejections, re-initialisations, lidar check),
:func:`summary` the method's part of ``summary.json`` and :func:`plot` the
trajectory and NIS plots.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
from robot_calib.core import figures, types as T
from robot_calib.methods.odometry_fusion.common import FusionResult
from robot_calib.methods.odometry_fusion.delay import delay_found
from robot_calib.methods.odometry_fusion.params import FusionParams


RECENT = 3.0
"""A filter warning this recent (s of filter time) sets the diagnostic level to WARN."""

DEG = math.pi / 180.0
"""One degree in rad: the factor between deg/s and rad/s."""

UNITS_BAND = 1.3
"""A yaw-rate scale within this factor of pi/180, 180/pi or -1 names a units or axis mistake."""


def diagnostic_status(r: FusionResult, params: FusionParams,
                      input_counts: Mapping[str, Mapping[str, int]]) -> T.DiagnosticStatus:
    """
    Return the diagnostic status of the filter: level, message and key-values.

    :param r: the filter's result
    :param params: the node's parameters
    :param input_counts: the pipeline's counters per input (read, rejected...)
    """
    values = [('mode', params.mode), ('imu_extrinsic', r.imu_extrinsic),
              ('accel_units', r.accel_units)]
    level, msg = 0, 'ok'
    nis = r.nis
    if nis is not None:
        frac = nis.in_band_fraction
        wfrac = nis.window_in_band_fraction
        values += [('nis_last', f'{nis.last:.3f}'), ('nis_avg', f'{nis.average:.3f}'),
                   ('nis_band_low', f'{nis.band[0]:.3f}'),
                   ('nis_band_high', f'{nis.band[1]:.3f}'),
                   ('nis_in_band_fraction', f'{math.nan if frac is None else frac:.3f}'),
                   ('nis_window_in_band_fraction',
                    f'{math.nan if wfrac is None else wfrac:.3f}')]
        values += [(k, f'{v:.6g}') for k, v in r.estimates.items()]
        if r.yaw_rate_fit is not None:
            values.append(('yaw_rate_fit', r.yaw_rate_fit['status']))
            advice = delay_advice(r.yaw_rate_fit, applied_delay(r, params))
            if advice:
                level, msg = 1, advice
        values.append(('imu_stale', str(r.imu_stale)))
        wrong_units = units_advice(r.yaw_rate_fit)
        if math.isfinite(nis.average) and nis.average > nis.band[1]:
            # innovations larger than the filter expects: it is over-confident. (Below the
            # band it is cautious, which time-correlated wheel noise makes it on healthy
            # drives half the time: no warning.)
            level, msg = 1, 'NIS above its 95% band: the filter is over-confident'
        if r.imu_stale:
            level, msg = 1, 'IMU stale: wheel odometry only'
    else:
        wrong_units = ''
    for k, v in sorted(r.counts.items()):
        values.append((k, str(v)))
    for key, c in sorted(input_counts.items()):
        if c.get('rejected'):
            values.append((f'{key}_rejected', str(c['rejected'])))
    if math.isfinite(r.lidar_accuracy):
        values += [('lidar_accuracy', f'{r.lidar_accuracy:.4f}'),
                   ('lidar_accuracy_valid', str(r.lidar_valid))]
        if not r.lidar_valid:
            level, msg = max(level, 1), 'lidar distance check failed (accuracy < 0.95)'
    if r.counts.get('reinitialisations'):
        msg = msg if level else f'ok ({r.counts["reinitialisations"]} re-initialisations)'
    if r.warnings:
        values.append(('last_warning', r.warnings[-1][1]))
        t_warn, text = r.warnings[-1]
        if r.t is not None and r.t - t_warn <= RECENT:
            # a re-initialisation or wheel data rejected just now outranks the NIS
            level, msg = 1, text
    if wrong_units:  # the fused heading means nothing: above every other message
        level, msg = 2, wrong_units
    return T.DiagnosticStatus('odometry_fusion: filter', level, msg, 'odometry_fusion',
                              tuple(values))


def summary(r: FusionResult, params: FusionParams, covariances_ignored: int) -> dict[str, Any]:
    """
    Return estimates, adaptation state, NIS consistency, warnings and counters.

    :param covariances_ignored: message covariances the pipeline found unusable
    """
    out: dict[str, Any] = {
        'mode': params.mode,
        'imu_extrinsic': r.imu_extrinsic,
        'accel_units': r.accel_units,
        'filter_counts': dict(r.counts),
        'message_covariances_ignored': covariances_ignored,
        'warnings': [f'{t:.3f}: {m}' for t, m in r.warnings[-50:]],
        'path_length': r.path_length,
    }
    out['estimates'] = dict(r.estimates)
    if r.yaw_rate_fit is not None:
        out['yaw_rate_calibration'] = dict(r.yaw_rate_fit)
        for advice in (units_advice(r.yaw_rate_fit),
                       delay_advice(r.yaw_rate_fit, applied_delay(r, params))):
            if advice:
                out['warnings'].append(f'end: {advice}')
    if r.nis is not None:
        out['nis'] = {
            'updates': r.nis.updates,
            'mean': r.nis.mean,
            'window': r.nis.window,
            'in_band_fraction': r.nis.in_band_fraction,
            'window_in_band_fraction': r.nis.window_in_band_fraction,
        }
    out['lidar_accuracy'] = {'accuracy': r.lidar_accuracy, 'valid': r.lidar_valid}
    return out


def applied_delay(r: FusionResult, params: FusionParams) -> float:
    """Return the odometry delay (s) the filter applies: configured, or found and applied."""
    return float(r.estimates.get('odometry_delay_applied', params.odometry_delay))


def units_advice(fit: Optional[dict]) -> str:
    """
    Return what a yaw-rate scale near pi/180 or 180/pi (or near -1) says about the inputs.

    The odometry's yaw rate over the gyro's is a skid-steer or track-width
    factor, 0.5-1.5 on real drives (the Husky's 0.82); near pi/180 the gyro reads
    deg/s, near 180/pi the odometry does, near -1 the IMU's z axis points down in
    base_link. Empty when the fit has nothing or says none of these.
    """
    if not fit or fit.get('status') not in ('ok', 'uncertain'):
        return ''
    k = fit.get('yaw_rate_scale')
    if k is None or not math.isfinite(k):
        return ''
    band = (1.0 / UNITS_BAND, UNITS_BAND)
    said = f'the wheel odometry turns {k:.4g} times as fast as the gyro (yaw-rate fit): '
    if band[0] <= k / DEG <= band[1]:
        return said + ('the gyro reads deg/s, not rad/s (REP-103): fix the driver; the fused '
                       'heading means nothing until then')
    if band[0] <= k * DEG <= band[1]:
        return said + ('the odometry yaw rate reads deg/s, not rad/s (REP-103): fix the '
                       'driver; the fused heading means nothing until then')
    if band[0] <= -k <= band[1]:
        return said + ('the IMU z axis points down in base_link: give its mounting (imu_rpy '
                       'or /tf_static)')
    return ''


def delay_advice(fit: dict, configured: float) -> str:
    """
    Return advice when the yaw-rate fit finds another odometry delay than ``configured`` (s).

    See :func:`.delay.delay_found`; empty when there is nothing to say.
    """
    d = delay_found(fit, configured)
    if d is None:
        return ''
    sd = fit['odometry_delay_std']
    if d < 0.0:
        return (f'the IMU lags the wheel odometry by {-d:.2f} +- {sd:.2f} s (yaw-rate fit); '
                f'odometry_delay cannot take that out: set it to 0 and check the IMU stamps')
    return (f'the wheel odometry lags the IMU by {d:.2f} +- {sd:.2f} s (yaw-rate fit, '
            f'odometry_delay is {configured:.2f}); set odometry_delay: {d:.2f} to use it at '
            'the time it describes')


def plot(r: FusionResult, params: FusionParams, trajectory: list, out_dir: str) -> list[str]:
    """
    Draw the fused trajectory and the NIS history (PNG) into ``out_dir``; return the names.

    :param trajectory: (t s, x m, y m, yaw rad) of the published estimates
    """
    if not trajectory:
        return []
    tr = np.array(trajectory)
    names = []
    fig, ax = figures.new_figure(6, 6)
    ax.plot(tr[:, 1], tr[:, 2], lw=1)
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_title(f'odometry_fusion ({params.mode}) trajectory')
    names.append(figures.save(fig, Path(out_dir) / 'odometry_fusion_trajectory.png', dpi=100))
    nis = r.nis
    if nis is not None and nis.updates:
        fig, ax = figures.new_figure(7, 3)
        ax.plot(np.arange(0, nis.updates, nis.history_stride)[:len(nis.history)],
                nis.history, lw=0.5)
        figures.log_y(ax)
        ax.set_xlabel('odometry update')
        ax.set_ylabel('NIS')
        names.append(figures.save(fig, Path(out_dir) / 'odometry_fusion_nis.png', dpi=100))
    return names
