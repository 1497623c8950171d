# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Lidar cases of the concealed-effect suite: the simulator's lidar effects, with their truth.

Each seeded case simulates one scenario twice along the same motion (the
scenario built from the same seed): the "sim" run with the defaults, the
"real" run with its own sensor noise (another seed for the sensor streams)
and, unless the case is a clean pair, one concealed lidar effect set through
the simulator's parameters (``lidar.yaw_error``, ``x_error``/``y_error``,
``time_offset``, ``range_scale``, ``range_bias``, ``noise_growth``,
``dropout_beyond`` with ``dropout_beyond_rate``; with ``--incidence`` only
``dropout_incidence`` 0.8-1.3 rad with ``dropout_incidence_rate`` 5-20 %) at a random size from the
ranges of issue 40 (mounting yaw 0.5-2 deg, offset 3-10 cm, latency 20-80
ms, range scale 0.5-2 %, bias 1-5 cm, dropouts of 5-20 % beyond a range;
noise growth 0.2-1 % of the range; an uncorrected 0.1 s sweep, ``motion_distortion``,
against a deskewed simulation), signs random. The truth is the
simulator's ``truth['lidar_effects']`` (real minus sim). The analyser's lidar
part (:func:`robot_calib.mismatch.lidar.analyse_lidar`) gets each run's
``/scan`` and ``/odom``.

Scored as the IMU and odometry cases are: an effect is found when the
analyser names it with every parameter within 25 % of the truth and names no
other lidar effect; a clean pair passes with no lidar finding. Refusals are
counted apart (listed in ``not_judged`` for the effect's channel) and still
count as not found.
"""

from __future__ import annotations

import math

import numpy as np

from robot_calib.sim import engine
from robot_calib.sim.scenario import BuildContext

SCENARIOS = ('drive', 'diff_segments', 'vacuum', 'agv_segments')
EFFECTS = ('lidar_mounting_yaw', 'lidar_mounting_offset', 'lidar_time_offset', 'range_scale',
           'range_bias', 'range_noise_growth', 'dropout_rate', 'scan_distortion')


def _mag(rng: np.random.Generator, lo: float, hi: float, signed: bool = True) -> float:
    x = float(rng.uniform(lo, hi))
    return x * float(rng.choice([-1.0, 1.0])) if signed else x


def draw_effect(rng: np.random.Generator, name: str) -> tuple[list, dict]:
    """Return (simulator overrides, expected parameters) of one concealed lidar effect."""
    if name == 'lidar_mounting_yaw':
        v = math.radians(_mag(rng, 0.5, 2.0))
        return [f'lidar.yaw_error={v}'], {'yaw': v}
    if name == 'lidar_mounting_offset':
        d, a = rng.uniform(0.03, 0.10), rng.uniform(-math.pi, math.pi)
        x, y = d * math.cos(a), d * math.sin(a)
        return [f'lidar.x_error={x}', f'lidar.y_error={y}'], {'x': x, 'y': y}
    if name == 'lidar_time_offset':
        v = _mag(rng, 0.02, 0.08, signed=False)
        return [f'lidar.time_offset={v}'], {'tau': v}
    if name == 'range_scale':
        v = _mag(rng, 0.005, 0.02)
        return [f'lidar.range_scale={v}'], {'scale': v}
    if name == 'range_bias':
        v = _mag(rng, 0.01, 0.05)
        return [f'lidar.range_bias={v}'], {'bias': v}
    if name == 'range_noise_growth':
        v = _mag(rng, 0.002, 0.01, signed=False)
        return [f'lidar.noise_growth={v}'], {'s1': v}
    if name == 'dropout_rate':
        rate, beyond = _mag(rng, 0.05, 0.2, signed=False), _mag(rng, 2.0, 5.0, signed=False)
        return ([f'lidar.dropout_beyond={beyond}', f'lidar.dropout_beyond_rate={rate}'],
                {'rate': rate, 'beyond': beyond})
    if name == 'dropout_incidence':  # the analyser names it dropout_rate (by incidence)
        rate, inc = _mag(rng, 0.05, 0.2, signed=False), _mag(rng, 0.8, 1.3, signed=False)
        return ([f'lidar.dropout_incidence={inc}', f'lidar.dropout_incidence_rate={rate}'],
                {'rate': rate, 'incidence': inc})
    if name == 'scan_distortion':
        # the simulation deskews (as Gazebo's ray sensor); the real scanner does not
        return ['lidar.motion_distortion=true'], {'sweep_time': 0.1}
    raise ValueError(f'unknown lidar effect {name}')


def make_case(seed: int, clean_share: float = 0.25, effects: tuple = EFFECTS) -> dict:
    """
    Return one case: scenario, duration, seeds, effect (or None), overrides, truth.

    ``effects``: the effects drawn from (``EFFECTS``, or ``('dropout_incidence',)``:
    grazing dropouts, named ``dropout_rate`` with ``drawn`` kept).
    """
    rng = np.random.default_rng(seed)
    scenario = str(rng.choice(SCENARIOS))
    duration = float(rng.uniform(120.0, 180.0))
    drawn = None if rng.random() < clean_share else str(rng.choice(effects))
    sets, want = draw_effect(rng, drawn) if drawn else ([], {})
    effect = 'dropout_rate' if drawn == 'dropout_incidence' else drawn
    return {'seed': seed, 'scenario': scenario, 'duration': duration, 'effect': effect,
            'drawn': drawn, 'sets': sets, 'expected': want, 'sim_seed': 2 * seed + 1000,
            'real_seed': 2 * seed + 1001}


def _run(scenario: str, scenario_seed: int, sensor_seed: int, duration: float,
         sets: list) -> engine.SimResult:
    """Simulate ``scenario`` built from ``scenario_seed`` with sensor noise from another seed."""
    sc = engine.get_scenario(scenario)
    p = engine.make_params(sc, sets)
    setup = sc.build(BuildContext(p, duration, scenario_seed,
                                  engine.rng_for(scenario_seed, 'scenario')))
    return engine.run_setup(setup, p, duration, sensor_seed, sc)


def _scans_odom(res: engine.SimResult) -> tuple[list, tuple]:
    s, t0 = res.sensors, res.params.start_time
    return res.topic('/scan'), (s['odom_t'] + t0, s['odom_vx'], s['odom_wz'])


def truth_difference(sim: engine.SimResult, real: engine.SimResult, effect: str) -> dict:
    """Return the real-minus-sim truth of ``effect`` from the simulator's ``lidar_effects``."""
    a, b = sim.truth['lidar_effects'], real.truth['lidar_effects']
    if effect == 'dropout_rate' and b[effect]['incidence'] > 0:
        return {'rate': b[effect]['incidence_rate'], 'incidence': b[effect]['incidence']}
    if effect == 'dropout_rate':
        return {'rate': b[effect]['beyond_rate'], 'beyond': b[effect]['beyond']}
    if effect == 'scan_distortion':
        return {'sweep_time': b[effect]['sweep_time'] - a[effect]['sweep_time']}
    if effect == 'range_noise_growth':
        return {'s1': b[effect]['s1'] - a[effect]['s1']}
    return {k: b[effect][k] - a[effect][k] for k in b[effect]
            if isinstance(b[effect][k], (int, float)) and not isinstance(b[effect][k], bool)
            and k not in ('nominal', 'true')}


def score(case: dict, res: dict) -> dict:
    """Return ``found``, ``refused``, ``other`` (lidar effects named besides) for one case."""
    named = res['findings']
    eff = case['effect']
    if eff is None:
        return {'found': not named, 'refused': False, 'other': [f['effect'] for f in named]}
    hit = [f for f in named if f['effect'] == eff]
    other = [f['effect'] for f in named if f['effect'] != eff]
    ok = bool(hit)
    if ok:
        got, want = hit[0]['parameters'], case['truth']
        if eff == 'lidar_mounting_offset':  # a displacement: its length is the size
            err = math.hypot(got['x'] - want['x'], got['y'] - want['y'])
            ok = err <= 0.25 * math.hypot(want['x'], want['y'])
        for k, x in want.items():
            if abs(x) > 1e-12 and eff != 'lidar_mounting_offset':
                ok &= abs(got.get(k, math.nan) - x) <= 0.25 * abs(x)
    chan = {'lidar_mounting_yaw': 'mounting', 'lidar_mounting_offset': 'mounting',
            'lidar_time_offset': 'stamp', 'scan_distortion': 'sweep'}.get(eff, 'ranges')
    refused = not hit and any(chan in j['channel'] or eff in j['reason']
                              for j in res['not_judged'])
    return {'found': ok and not other, 'refused': refused, 'other': other}


def run_case(case: dict, prm=None) -> dict:
    """Simulate and analyse one case; return the case with ``result``, ``score`` and CPU s."""
    import time

    from robot_calib.mismatch import lidar as L
    base = ['lidar.motion_distortion=false'] if case['effect'] == 'scan_distortion' else []
    sim = _run(case['scenario'], case['sim_seed'], case['sim_seed'], case['duration'], base)
    real = _run(case['scenario'], case['sim_seed'], case['real_seed'], case['duration'],
                case['sets'])
    if case['effect']:
        case['truth'] = truth_difference(sim, real, case['effect'])
    ss, so = _scans_odom(sim)
    rs, ro = _scans_odom(real)
    c0 = time.process_time()
    res = L.analyse_lidar({'/scan': ss}, {'/scan': rs}, so, ro, prm)
    case['cpu'] = time.process_time() - c0
    case['result'] = res
    case['score'] = score(case, res)
    return case


def describe(res: dict) -> str:
    """Return the findings of a lidar analysis as one short line."""
    out = []
    for f in res['findings']:
        vals = ', '.join(f'{k} {v:.4g}' for k, v in f['parameters'].items())
        out.append(f'{f["effect"]} {vals}')
    return '; '.join(out) or 'none'


def section(cases: list) -> list:
    """Return the markdown lines of the lidar suite: per-effect counts and every case."""
    eff = [c for c in cases if c['effect']]
    clean = [c for c in cases if not c['effect']]
    n_ok = sum(c['score']['found'] for c in eff)
    n_ref = sum(c['score']['refused'] for c in eff)
    lines = ['| effect | cases | found within 25 % | not observable (refused) |',
             '|---|---|---|---|']
    for name in EFFECTS:
        cs = [c for c in eff if c['effect'] == name]
        if cs:
            lines.append(f'| {name} | {len(cs)} | {sum(c["score"]["found"] for c in cs)} | '
                         f'{sum(c["score"]["refused"] for c in cs)} |')
    lines.append(f'| clean pairs (no lidar finding) | {len(clean)} | '
                 f'{sum(c["score"]["found"] for c in clean)} | |')
    lines += ['', f'Found within 25 %: {n_ok} of {len(eff)} '
              f'({100 * n_ok / max(len(eff), 1):.0f} %; refused {n_ref}); clean pairs without '
              f'a lidar finding: {sum(c["score"]["found"] for c in clean)} of {len(clean)}.', '',
              '| seed | scenario (s) | effect | truth | named | ok | CPU s |',
              '|---|---|---|---|---|---|---|']
    for c in cases:
        truth = ', '.join(f'{k} {v:.4g}' for k, v in (c.get('truth') or {}).items()) or '-'
        ok = 'yes' if c['score']['found'] else (
            'not observable (refused)' if c['score']['refused'] else '**no**')
        lines.append(f'| {c["seed"]} | {c["scenario"]} ({c["duration"]:.0f}) | '
                     f'{c["effect"] or "clean"} | {truth} | {describe(c["result"])} | {ok} | '
                     f'{c["cpu"]:.1f} |')
    return lines


if __name__ == '__main__':
    import argparse
    import sys
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--seeds', type=int, nargs=2, default=(300, 340),
                    help='first and one past the last seed')
    ap.add_argument('--clean', action='store_true', help='clean pairs only (no effect)')
    ap.add_argument('--incidence', action='store_true',
                    help='grazing dropouts (dropout_incidence) as the only drawn effect')
    a = ap.parse_args()
    done = []
    for sd in range(*a.seeds):
        done.append(run_case(make_case(sd, 1.0 if a.clean else 0.25,
                                       ('dropout_incidence',) if a.incidence else EFFECTS)))
        print(section(done[-1:])[-1], file=sys.stderr, flush=True)
    print('\n'.join(section(done)))
