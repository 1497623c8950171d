# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Pose drift before and after correcting a followed simulation (docs/bench/16-follow.md).

For each pair: the real recording; ``simulate follow`` with the ideal robot;
``mismatch`` of that pair (its ``sim_params.yaml``); ``simulate follow --params``
with it; ``mismatch --corrected`` and a ``mismatch`` of the corrected pair. Prints
one table row per pair: drift (end, RMS) of the ideal and corrected simulations
against the real one, and the analyser's odometry residual RMSE before and after.

Pairs:

- ``sim``: a ``simulate drive`` run whose robot has drive dynamics (forward lag
  0.35 s, turn lag 0.25 s, turn speed loss 1.0 s/rad) besides the scenario's
  sensor and wheel errors, as the "real" recording; also corrected with the TRUE
  drive parameters ("oracle"), which bounds what the drive parameters can do;
- ``simclean``: the same without the wheel errors (the drive dynamics only);
- ``mrclam1``, ``mrclam2``: 300 s of the UTIAS MRCLAM run 6 robots 1 and 2
  (``../shared/data/mrclam``, skipped when absent): the recorded velocity
  commands as ``/cmd_vel`` (geometry_msgs/Twist) and the Vicon poses as
  ``/odom`` (nav_msgs/Odometry at 50 Hz: pose, and the body twist from a
  central difference of the 0.1 s-smoothed track), converted by
  :func:`mrclam_bag` (this script's own small converter).

Usage: ``PYTHONPATH=$PWD python benchmarks/follow_drift.py [--pairs sim,mrclam1] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / 'shared' / 'data' / 'mrclam'
SIM_DRIVE = {'drive.linear_time_constant': 0.35, 'drive.angular_time_constant': 0.25,
             'drive.turn_speed_loss': 1.0}
NO_WHEEL_ERRORS = {'wheels.left_radius_error': 0, 'wheels.right_radius_error': 0,
                   'wheels.track_width_error': 0}


def cli(*args: str) -> float:
    """Run ``robot-calib`` in-process; return the wall time (s); exit on failure."""
    from robot_calib.cli import main
    t = time.perf_counter()
    code = main([str(a) for a in args])
    if code != 0:
        sys.exit(f'robot-calib {" ".join(map(str, args))} failed ({code})')
    return time.perf_counter() - t


def _load(path: Path) -> np.ndarray:
    rows = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith('#')]
    return np.array(rows, float)


def mrclam_bag(robot: int, out: Path, start: float = 0.0, length: float = 300.0) -> None:
    """Write ``length`` s of MRCLAM robot ``robot`` as a bag with /cmd_vel and /odom."""
    from robot_calib.core import types as T
    from robot_calib.io.bags import BagWriter
    cmd = _load(DATA / f'Robot{robot}_Odometry.dat')
    gt = _load(DATA / f'Robot{robot}_Groundtruth.dat')
    t0 = max(cmd[0, 0], gt[0, 0]) + start
    t1 = t0 + length
    cmd = cmd[(cmd[:, 0] >= t0) & (cmd[:, 0] <= t1)]
    gt = gt[np.concatenate(([True], np.diff(gt[:, 0]) > 0))]
    tg = np.arange(t0, t1, 0.02)
    x, y = np.interp(tg, gt[:, 0], gt[:, 1]), np.interp(tg, gt[:, 0], gt[:, 2])
    yaw = np.interp(tg, gt[:, 0], np.unwrap(gt[:, 3]))
    k = np.ones(11) / 11.0  # 0.2 s centred mean: zero phase
    xs, ys, yws = (np.convolve(np.pad(a, 5, mode='edge'), k, mode='valid') for a in (x, y, yaw))
    dx, dy, dyaw = (np.gradient(a, 0.02) for a in (xs, ys, yws))
    v = np.cos(yws) * dx + np.sin(yws) * dy
    with BagWriter(out) as w:
        msgs = [(float(t), '/cmd_vel', T.TwistSample(float(t), float(a), 0.0, float(b)))
                for t, a, b in cmd]
        msgs += [(float(t), '/odom', T.OdomSample(float(t), float(a), float(b),
                                                  float((c + np.pi) % (2 * np.pi) - np.pi),
                                                  float(vv), 0.0, float(ww)))
                 for t, a, b, c, vv, ww in zip(tg, x, y, yaw, v, dyaw)]
        for t, topic, s in sorted(msgs, key=lambda m: (m[0], m[1])):
            w.write(topic, s, int(round(t * 1e9)))


def odom_rmse(findings: dict) -> dict:
    """Return {channel: RMSE real - sim} of the odometry twist channels."""
    return {ch: c['rmse'] for ch, c in findings.get('channels', {}).items() if 'twist' in ch}


def _twist(path: Path, topic: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return forward speed and yaw rate of an odometry topic at times ``t`` (bag seconds)."""
    from robot_calib.mismatch.channels import read_bag
    tp = read_bag(path)[topic]
    return (np.interp(t, tp.t, tp.fields['twist.twist.linear.x']),
            np.interp(t, tp.t, tp.fields['twist.twist.angular.z']))


def _lag(u: np.ndarray, tau: float, dt: float) -> np.ndarray:
    from scipy.signal import lfilter
    if tau <= 0:
        return u
    a = np.exp(-dt / tau)
    return lfilter([1 - a], [1, -a], u)


def independent_fit(sim: Path, real: Path, fraction: float = 0.5) -> dict:
    """
    Fit real = f(sim) on the first ``fraction`` of the run: lags per axis, turn speed loss.

    Grid over the turn-rate lag with its gain by least squares, then over the
    forward lag with its gain and the turn speed loss k by linear least squares:
    ``v_real = (1 + g) lag(v_sim) (1 - k |omega_model|)``. Independent of the analyser.
    """
    from robot_calib.mismatch.channels import read_bag
    tr = read_bag(real)['/odom']
    dt = 0.02
    t = np.arange(tr.t[0], tr.t[0] + fraction * (tr.t[-1] - tr.t[0]), dt)
    vs, ws = _twist(sim, '/odom', t)
    vr, wr = _twist(real, '/odom', t)
    taus = np.arange(0.0, 1.01, 0.02)
    best_w = None
    for tau in taus:
        a = _lag(ws, tau, dt)
        gain = float(np.dot(a, wr) / max(np.dot(a, a), 1e-12))
        c = float(np.mean((gain * a - wr) ** 2))
        if best_w is None or c < best_w[0]:
            best_w = (c, float(tau), gain)
    _, tau_w, gain_w = best_w
    wm = np.abs(gain_w * _lag(ws, tau_w, dt))
    best = None
    for tau in taus:
        a = _lag(vs, tau, dt)
        x = np.column_stack((a, -a * wm))  # v_real = (1 + g) a - (1 + g) k a |omega|
        coef = np.linalg.lstsq(x, vr, rcond=None)[0]
        c = float(np.mean((x @ coef - vr) ** 2))
        if best is None or c < best[0]:
            best = (c, float(tau), float(coef[0]), float(coef[1] / coef[0]))
    return {'tau_v': best[1], 'gain_v': best[2] - 1.0, 'k': best[3], 'tau_w': tau_w,
            'gain_w': gain_w - 1.0}


def fitted_findings(fit: dict, sim: Path, real: Path) -> dict:
    """Return a findings dict (contract schema) of an independent fit."""
    ch_v, ch_w = '/odom.twist.twist.linear.x', '/odom.twist.twist.angular.z'
    rows = [('drive_lag', ch_v, {'tau': fit['tau_v']}),
            ('drive_lag', ch_w, {'tau': fit['tau_w']}),
            ('turn_speed_loss', ch_v, {'coefficient': fit['k']}),
            ('drive_gain', ch_v, {'gain': fit['gain_v']}),
            ('drive_gain', ch_w, {'gain': fit['gain_w']})]
    return {'verdict': 'mismatch', 'inputs': {'sim': str(sim), 'real': str(real)},
            'findings': [{'channel': c, 'effect': e, 'parameters': p, 'window': None,
                          'confidence': 1.0, 'explanation': 'independent fit (benchmark)'}
                         for e, c, p in rows]}


def run_pair(name: str, real: Path, work: Path, oracle: dict | None) -> dict:
    """Follow, analyse, correct, analyse again; return the measurements."""
    out: dict = {'pair': name}
    sim, corr = work / f'{name}_sim', work / f'{name}_corr'
    out['follow_s'] = cli('simulate', 'follow', real, '--out', sim)
    out['mismatch_s'] = cli('mismatch', '--sim', sim, '--real', real, '--out',
                            work / f'{name}_m1')
    m1 = json.loads((work / f'{name}_m1' / 'findings.json').read_text())
    out['findings'] = [(f['effect'], f['channel'], f['parameters']) for f in m1['findings']]
    cli('simulate', 'follow', real, '--out', corr, '--params',
        work / f'{name}_m1' / 'sim_params.yaml')
    cli('mismatch', '--sim', sim, '--real', real, '--out', work / f'{name}_m2', '--corrected',
        corr)
    m2 = json.loads((work / f'{name}_m2' / 'findings.json').read_text())
    cli('mismatch', '--sim', corr, '--real', real, '--out', work / f'{name}_m3')
    m3 = json.loads((work / f'{name}_m3' / 'findings.json').read_text())
    out['trajectory'] = m2.get('trajectory')
    out['rmse_before'], out['rmse_after'] = odom_rmse(m1), odom_rmse(m3)
    from robot_calib.mismatch import export
    fit = independent_fit(sim, real)
    out['fit'] = fit
    fdir = work / f'{name}_fit'
    fdir.mkdir(exist_ok=True)
    export.write(fdir, fitted_findings(fit, sim, real), str(sim))
    fitted = work / f'{name}_fitted'
    cli('simulate', 'follow', real, '--out', fitted, '--params', fdir / 'sim_params.yaml')
    cli('mismatch', '--sim', sim, '--real', real, '--out', work / f'{name}_m5',
        '--corrected', fitted)
    m5 = json.loads((work / f'{name}_m5' / 'findings.json').read_text())
    out['fitted'] = m5.get('trajectory', {}).get('corrected_drift')
    if oracle:
        orc = work / f'{name}_oracle'
        cli('simulate', 'follow', real, '--out', orc,
            *[a for k, v in oracle.items() for a in ('--set', f'{k}={v}')])
        cli('mismatch', '--sim', sim, '--real', real, '--out', work / f'{name}_m4',
            '--corrected', orc)
        m4 = json.loads((work / f'{name}_m4' / 'findings.json').read_text())
        out['oracle'] = m4.get('trajectory', {}).get('corrected_drift')
    return out


def main() -> None:
    """Run the pairs and print the table rows."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--pairs', default='simclean,sim,mrclam1,mrclam2')
    ap.add_argument('--keep', default=None, help='keep the bags and reports in this folder')
    ap.add_argument('--duration', type=float, default=120.0, help='simulated pair length (s)')
    args = ap.parse_args()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='follow_drift_'))
    work.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for name in args.pairs.split(','):
            real = work / f'{name}_real'
            oracle = None
            if name in ('sim', 'simclean'):
                wheels = {} if name == 'sim' else NO_WHEEL_ERRORS
                sets = [a for k, v in {**SIM_DRIVE, **wheels}.items()
                        for a in ('--set', f'{k}={v}')]
                cli('simulate', 'drive', '--out', real, '--duration', args.duration, '--seed', 3,
                    *sets)
                oracle = SIM_DRIVE
            elif name.startswith('mrclam'):
                if not DATA.is_dir():
                    print(f'skip {name}: {DATA} absent')
                    continue
                mrclam_bag(int(name[-1]), real)
            results.append(run_pair(name, real, work, oracle))
            print(json.dumps(results[-1], indent=1, default=float), flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    print('| pair | real path (m) | ideal sim: end / RMS drift (m) | analyser-corrected: end / '
          'RMS (m) | fit-corrected: end / RMS (m) | oracle: end / RMS (m) '
          '| odom RMSE before -> after (analyser-corrected) |')
    print('|---|---|---|---|---|---|---|')
    for r in results:
        tr = r['trajectory'] or {}
        s, c, o = tr.get('sim_drift') or {}, tr.get('corrected_drift') or {}, r.get('oracle')
        fd = r.get('fitted') or {}
        rm = '; '.join(f'{ch.split(".", 1)[1]} {r["rmse_before"][ch]:.4f} -> '
                       f'{r["rmse_after"].get(ch, float("nan")):.4f}' for ch in r['rmse_before'])
        print(f'| {r["pair"]} | {tr.get("real_path_m", float("nan")):.1f} '
              f'| {s.get("end_m", np.nan):.2f} / {s.get("rms_m", np.nan):.2f} '
              f'| {c.get("end_m", np.nan):.2f} / {c.get("rms_m", np.nan):.2f} '
              f'| {fd.get("end_m", np.nan):.2f} / {fd.get("rms_m", np.nan):.2f} '
              f'| ' + (f'{o["end_m"]:.2f} / {o["rms_m"]:.2f}' if o else '-') + f' | {rm} |')


if __name__ == '__main__':
    main()
