# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
A simulated fleet: robots recording a bag every few days while their true parameters drift.

``robot-calib simulate fleet --out DIR [--seed N] [--duration S] [--storage mcap|sqlite3]
[--set fleet.KEY=VALUE] [--set SIM.KEY=VALUE]`` writes ``DIR/<robot>/<date>/`` (one ROS 2
bag per robot and recording day, with ``<date>.truth.json`` beside it), the folder
layout that ``robot-calib fleet`` reads, and ``DIR/fleet_truth.csv``: per bag the true
parameters and the drift injected, to score a fleet run's flags against.

Every robot is built with its own manufacturing errors (wheel radii, track
width, gyro turn-on bias), kept for all its bags; each recording adds the gyro's
day-to-day turn-on repeatability and its own driving (its own seed). Then some
robots drift (chosen by the seed): ``wear`` robots' tyres wear, both wheel radii
shrinking by ``wear_per_week`` (relative) per week; ``gyro_step`` robots' gyro
z bias jumps by ``gyro_step`` (rad/s) from their ``step_bag``-th recording on (a
knock, a firmware change). The rest are ``unchanged``: a fleet job must not flag
them. The simulator keys these draws set (:data:`DRAWN`) are the fleet's: a
``--set`` of one of them is refused, naming the ``fleet.`` keys that decide it.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
import csv
from dataclasses import dataclass
import datetime
import multiprocessing
import os
from pathlib import Path
import sys
from typing import Any, Iterable, Mapping, Optional, Union

import numpy as np
from robot_calib.core.params import from_flat, param, ParamError, to_flat
from robot_calib.sim.engine import SimError

PREFIX = 'fleet.'
TRUTH_FILE = 'fleet_truth.csv'
TRUTH_COLUMNS = ('robot', 'bag', 'date', 'recording', 'drift', 'seed', 'left_radius_error',
                 'right_radius_error', 'track_width_error', 'gyro_bias_z')
_GYRO = 'fleet.gyro_bias_sigma, fleet.gyro_repeatability, fleet.gyro_step'
DRAWN = {'wheels.left_radius_error': 'fleet.radius_error_sigma, fleet.wear_per_week',
         'wheels.right_radius_error': 'fleet.radius_error_sigma, fleet.wear_per_week',
         'wheels.track_width_error': 'fleet.track_width_error_sigma',
         'imu.gyro_bias': _GYRO, 'imu.gyro_bias_sigma': _GYRO,
         'start_time': 'fleet.start_date, fleet.interval_days'}
"""Simulator keys set per recording by :func:`plan` -> the fleet keys that decide them."""


@dataclass
class FleetParams:
    """The fleet's size, schedule and drifts (``--set fleet.KEY=VALUE``)."""

    robots: int = param(50, '', 'number of robots', minimum=1, maximum=100000)
    recordings: int = param(4, '', 'bags per robot', minimum=1, maximum=1000)
    interval_days: float = param(7.0, 'day', 'time between two recordings of a robot',
                                 minimum=0.0)
    start_date: str = param('2026-01-05', '', 'date of the first recordings (ISO 8601)')
    scenario: str = param('drive', '', 'simulator scenario of every recording')
    wear_fraction: float = param(0.2, '', 'share of robots whose tyres wear', minimum=0.0,
                                 maximum=1.0)
    wear_per_week: float = param(0.001, '1/week', 'relative wheel radius lost per week by a '
                                 'wearing robot (both wheels)', minimum=0.0, maximum=0.1)
    step_fraction: float = param(0.1, '', 'share of robots whose gyro bias steps',
                                 minimum=0.0, maximum=1.0)
    gyro_step: float = param(0.02, 'rad/s', 'gyro z bias step of a stepping robot')
    step_recording: int = param(-1, '', 'recording (0-based; negative counts from the end) '
                                'from which the gyro bias has stepped')
    radius_error_sigma: float = param(0.003, '', "spread of the robots' wheel radius "
                                      'errors (relative, per wheel)', minimum=0.0)
    track_width_error_sigma: float = param(0.005, '', "spread of the robots' track width "
                                           'errors (relative)', minimum=0.0)
    gyro_bias_sigma: float = param(0.003, 'rad/s', "spread of the robots' gyro z turn-on "
                                   'bias', minimum=0.0)
    gyro_repeatability: float = param(0.0003, 'rad/s', "day-to-day change of a gyro's "
                                      'turn-on bias (1 sigma)', minimum=0.0)


@dataclass(frozen=True)
class Recording:
    """One bag to simulate: robot, day, drift, seed and simulator overrides (start time too)."""

    robot: str
    day: str
    index: int
    drift: str
    seed: int
    overrides: tuple[tuple[str, Any], ...]

    def truth_row(self) -> dict[str, Any]:
        """Return this recording's row of ``fleet_truth.csv``."""
        values = dict(self.overrides)
        return {'robot': self.robot, 'bag': f'{self.robot}/{self.day}', 'date': self.day,
                'recording': self.index, 'drift': self.drift, 'seed': self.seed,
                'left_radius_error': values['wheels.left_radius_error'],
                'right_radius_error': values['wheels.right_radius_error'],
                'track_width_error': values['wheels.track_width_error'],
                'gyro_bias_z': float(values['imu.gyro_bias'].split(',')[2])}


def split_overrides(overrides: Union[None, Mapping[str, Any], Iterable[str]]
                    ) -> tuple[FleetParams, dict[str, str]]:
    """Return the fleet parameters (``fleet.`` keys) and the simulator overrides (the rest)."""
    if isinstance(overrides, Mapping):
        items = [f'{k}={v}' for k, v in overrides.items()]
    else:
        items = list(overrides or ())
    fleet: dict[str, str] = {}
    sim: dict[str, str] = {}
    for item in items:
        key, sep, value = str(item).partition('=')
        if not sep or not key.strip():
            raise SimError(f'bad --set {item!r}: expected key=value')
        key = key.strip()
        if key.startswith(PREFIX):
            name = key[len(PREFIX):]
            if name not in to_flat(FleetParams()):
                raise SimError(f'unknown --set key {key!r}; fleet keys: '
                               f'{", ".join(PREFIX + k for k in to_flat(FleetParams()))}')
            fleet[name] = value.strip()
        elif key in DRAWN:
            raise SimError(f'--set {key} cannot be given to a fleet: it is drawn per robot and '
                           f'recording (and written to {TRUTH_FILE}); set {DRAWN[key]} instead')
        else:
            sim[key] = value.strip()
    try:
        params = from_flat(FleetParams, fleet)
        datetime.date.fromisoformat(params.start_date)
    except (ParamError, ValueError) as exc:
        raise SimError(str(exc).splitlines()[0]) from None
    return params, sim


def plan(params: FleetParams, seed: int, sim_overrides: Mapping[str, str]) -> list[Recording]:
    """Return every recording of the fleet, robot by robot (deterministic in ``seed``)."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(7,)))
    n = params.robots
    order = rng.permutation(n)
    n_wear = int(round(params.wear_fraction * n))
    n_step = min(int(round(params.step_fraction * n)), n - n_wear)
    drift = {int(i): 'wear' for i in order[:n_wear]}
    drift.update({int(i): 'gyro_step' for i in order[n_wear:n_wear + n_step]})
    start = datetime.datetime.combine(datetime.date.fromisoformat(params.start_date),
                                      datetime.time(9, 0), datetime.timezone.utc)
    step_at = params.step_recording % params.recordings
    out = []
    for r in range(n):
        kind = drift.get(r, 'unchanged')
        left, right, track = rng.normal(0.0, [params.radius_error_sigma] * 2
                                        + [params.track_width_error_sigma])
        bias = rng.normal(0.0, params.gyro_bias_sigma)
        for k in range(params.recordings):
            when = start + datetime.timedelta(days=k * params.interval_days, minutes=r)
            weeks = k * params.interval_days / 7.0
            wear = 1.0 - params.wear_per_week * weeks if kind == 'wear' else 1.0
            z = bias + rng.normal(0.0, params.gyro_repeatability)
            if kind == 'gyro_step' and k >= step_at:
                z += params.gyro_step
            values = {**sim_overrides,
                      'wheels.left_radius_error': (1.0 + left) * wear - 1.0,
                      'wheels.right_radius_error': (1.0 + right) * wear - 1.0,
                      'wheels.track_width_error': float(track),
                      'imu.gyro_bias': f'0,0,{z:.9g}', 'imu.gyro_bias_sigma': 0.0,
                      'start_time': when.timestamp()}
            # every bag of a fleet has its own seed (k < 1009 recordings)
            out.append(Recording(f'robot{r:03d}', when.date().isoformat(), k, kind,
                                 int(seed) * 1_000_003 + r * 1009 + k,
                                 tuple(values.items())))
    return out


def _simulate_one(args: tuple[str, Path, Recording, Optional[float], str]) -> None:
    from robot_calib.sim.engine import simulate
    scenario, out, rec, duration, storage = args
    folder = out / rec.robot
    folder.mkdir(parents=True, exist_ok=True)
    simulate(scenario, folder / rec.day, seed=rec.seed, duration=duration,
             overrides=dict(rec.overrides), storage=storage)


def simulate_fleet(out: Union[str, os.PathLike], seed: int = 0, duration: Optional[float] = None,
                   overrides: Union[None, Mapping[str, Any], Iterable[str]] = None,
                   workers: Optional[int] = None, progress: Optional[bool] = None,
                   storage: str = 'mcap') -> list[dict[str, Any]]:
    """
    Write the fleet into ``out`` (which must not exist); return the rows of its truth table.

    :param duration: seconds per bag (default: the scenario's)
    :param overrides: ``fleet.KEY=VALUE`` (see :class:`FleetParams`) and simulator keys applied
        to every bag
    :param workers: processes simulating bags (default: the CPU count)
    :param storage: storage of every bag: 'mcap' or 'sqlite3'
    """
    out = Path(out)
    params, sim_overrides = split_overrides(overrides)
    if out.exists():
        raise SimError(f'output {out} exists; remove it or choose another')
    recordings = plan(params, seed, sim_overrides)
    _check_first(params.scenario, recordings[0], duration, storage)
    out.mkdir(parents=True)
    jobs = [(params.scenario, out, rec, duration, storage) for rec in recordings]
    workers = min(len(jobs), (os.cpu_count() or 1) if workers is None else max(1, workers))
    bar = _bar(len(jobs), progress)
    try:
        if workers <= 1:
            done: Iterable[None] = map(_simulate_one, jobs)
            for _ in done:
                _tick(bar)
        else:
            context = multiprocessing.get_context('spawn')
            with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
                for _ in pool.map(_simulate_one, jobs, chunksize=1):
                    _tick(bar)
    finally:
        if bar is not None:
            bar.close()
    rows = [rec.truth_row() for rec in recordings]
    with open(out / f'.{TRUTH_FILE}.tmp', 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=TRUTH_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(out / f'.{TRUTH_FILE}.tmp', out / TRUTH_FILE)
    return rows


def _check_first(scenario: str, rec: Recording, duration: Optional[float],
                 storage: str) -> None:
    """Raise SimError now, not in a worker, when the scenario, an override or storage is wrong."""
    from robot_calib.sim.engine import check_storage, get_scenario, make_params
    check_storage(storage)
    make_params(get_scenario(scenario), dict(rec.overrides))
    if duration is not None and not duration > 0:
        raise SimError(f'bad duration {duration}: expected seconds > 0')


def _bar(total: int, progress: Optional[bool]) -> Any:
    if not (sys.stderr.isatty() if progress is None else progress):
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit='bag', file=sys.stderr, desc='simulate fleet',
                dynamic_ncols=True)


def _tick(bar: Any) -> None:
    if bar is not None:
        bar.update(1)


def read_truth(folder: Union[str, os.PathLike]) -> list[dict[str, str]]:
    """Return the rows of a simulated fleet's ``fleet_truth.csv``."""
    with open(Path(folder) / TRUTH_FILE, newline='') as f:
        return list(csv.DictReader(f))
