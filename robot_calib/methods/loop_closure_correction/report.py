# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
What the ``loop_closure_correction`` pipeline reports: diagnostics, summary, plot, error.

Everything here reads only the estimator's outputs: a
:class:`~robot_calib.methods.loop_closure_correction.common.ClosureReport`
and a :class:`~robot_calib.methods.loop_closure_correction.common.LoopClosureResult`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
from robot_calib.core import figures, types as T
from robot_calib.methods.loop_closure_correction.common import ClosureReport, LoopClosureResult

NAME = 'loop_closure_correction'
CLOSURES_LISTED = 500
"""Closures and corrections listed in the summary at most."""


def diagnostic(report: ClosureReport, result: LoopClosureResult,
               stamp_ns: int) -> T.DiagnosticSample:
    """Return the /diagnostics array of one closure attempt or kidnap (header ``stamp_ns``)."""
    if report.accepted:
        level, msg = 0, 'loop closure accepted'
    elif report.reason == 'kidnap_suspected':
        level, msg = 2, 'kidnap suspected: scan disagrees with odometry, map restarted'
    else:
        level, msg = 1, f'loop closure refused: {report.reason}'
    c = report.correction
    values = (
        ('reason', report.reason),
        ('keyframes_tried', ','.join(str(k) for k in report.keyframes_tried)),
        ('scores', ','.join(f'{s:.3f}' for s in report.scores)),
        ('similarities', ','.join(f'{s:.3f}' for s in report.similarities)),
        ('chosen_keyframe', str(report.chosen)),
        ('correction_x', f'{c[0]:.4f}'), ('correction_y', f'{c[1]:.4f}'),
        ('correction_yaw', f'{c[2]:.5f}'),
        ('latency_ms', f'{report.latency_ms:.2f}'),
        ('search_radius', f'{report.radius:.2f}'),
        ('min_eigenvalue', f'{report.min_eigenvalue:.4f}'),
        ('inlier_ratio', f'{report.inlier_ratio:.3f}'),
        ('gyro_bias', f'{result.gyro_bias:.6f}'),
        ('closures_accepted', str(result.counts.get('closures_accepted', 0))),
    )
    status = T.DiagnosticStatus(name=f'{NAME}: loop closure', level=level, message=msg,
                                hardware_id=NAME, values=values)
    return T.DiagnosticSample(t=report.t, statuses=(status,), stamp_ns=stamp_ns)


def summary(result: LoopClosureResult) -> dict:
    """Return closures (tried keyframes, scores, correction, time), counts and latency."""
    s = result.summary()
    reports = result.closures
    s['closures'] = [r.as_dict() for r in reports[:CLOSURES_LISTED]]
    s['closures_listed'] = min(len(reports), CLOSURES_LISTED)
    s['corrections'] = [
        {'t': r.t, 'x': float(r.correction[0]), 'y': float(r.correction[1]),
         'yaw': float(r.correction[2])} for r in reports if r.accepted][:CLOSURES_LISTED]
    s['final_pose'] = [float(v) for v in result.pose]
    s['total_heading_correction'] = float(sum(abs(r.correction[2]) for r in reports
                                              if r.accepted))
    return s


def plot(track: Sequence[tuple], result: LoopClosureResult, out_dir: str) -> list:
    """
    Draw the raw and corrected trajectories with the closures (loop_closure.png).

    ``track`` rows are (t s, x m, y m, yaw rad, raw x m, raw y m); returns the
    names of the files written in ``out_dir``.
    """
    if not track:
        return []
    tr = np.array(list(track))
    fig, ax = figures.new_figure(7, 6)
    ax.plot(tr[:, 4], tr[:, 5], color='0.6', lw=1, label='dead reckoning (raw)')
    ax.plot(tr[:, 1], tr[:, 2], color='C0', lw=1.2, label='corrected')
    acc = [r for r in result.closures if r.accepted]
    ref = [r for r in result.closures if not r.accepted]
    if acc:
        a = np.array([r.pose_after for r in acc])
        ax.plot(a[:, 0], a[:, 1], 'o', color='C2', ms=4, label=f'accepted ({len(acc)})')
    if ref:
        b = np.array([r.pose_before for r in ref])
        ax.plot(b[:, 0], b[:, 1], 'x', color='C3', ms=4, label=f'refused ({len(ref)})')
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_title(NAME)
    ax.legend(fontsize=8)
    return [figures.save(fig, Path(out_dir) / 'loop_closure.png')]


def heading_rmse(t_est: np.ndarray, yaw_est: np.ndarray, t_true: np.ndarray,
                 yaw_true: np.ndarray) -> float:
    """Return the RMS heading error (rad) of estimates against truth interpolated at ``t_est``."""
    unwrapped = np.unwrap(yaw_true)
    ref = np.interp(t_est, t_true, unwrapped)
    err = np.angle(np.exp(1j * (np.asarray(yaw_est) - ref)))
    return float(math.sqrt(np.mean(err ** 2))) if len(err) else float('nan')
