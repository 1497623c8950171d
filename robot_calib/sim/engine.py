# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
The simulation engine: scenario -> true trajectory -> sensors -> messages (and a bag).

Pipeline (all vectorised over whole arrays except closed-loop plan steps):

1. parameters: :class:`SimParams` defaults, then the scenario's defaults,
   then the user's overrides (``--set key=value``);
2. ``scenario.build(ctx)`` gives the world, the start pose and the plan;
3. :class:`~robot_calib.sim.robot.Plant` runs the plan at the control rate and
   integrates the true planar state at the internal rate;
4. :func:`~robot_calib.sim.robot.attitude` adds terrain attitude, tip-overs,
   body rates and the specific force;
5. :mod:`~robot_calib.sim.sensors` samples every sensor at its own rate with
   its own random stream (:data:`STREAMS`);
6. the messages are built as core samples and merged in time order.

Frames (REP-105): ``odom`` is the start pose of base_link (both wheel odometry
and ``ground_truth/odom`` start at 0, 0, 0), ``base_link`` on the axle centre,
``imu_link`` and ``laser`` from ``/tf_static``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
import shutil
from typing import Any, Iterable, Mapping, Optional, Union

import numpy as np

from robot_calib.codec import templates as C
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, wrap_angle
from robot_calib.core.jsonable import jsonable
from robot_calib.core.params import from_flat, ParamError, to_flat
from robot_calib.sim import sensors as S
from robot_calib.sim.motion import State, TipOver
from robot_calib.sim.params import SimParams, VECTOR_PARAMS
from robot_calib.sim.robot import attitude, Plant, PlantError
from robot_calib.sim.scenario import BrokenScenario, BuildContext, Scenario, SCENARIOS

STREAMS = ('scenario', 'imu', 'imu_bias', 'wheels', 'lidar', 'odom')
"""Named child random streams, spawned from ``SeedSequence(seed)`` by their index here.

Append new names only: the index fixes the stream, so existing sensors keep their noise.
"""

TOPICS = ('/tf_static', '/cmd_vel', '/ground_truth/odom', '/imu', '/joint_states', '/odom',
          '/scan')
"""Topics of a simulated recording (this order breaks ties between equal stamps)."""


class SimError(ValueError):
    """A bad simulation request: unknown scenario, unknown ``--set`` key, bad value (one line)."""


class SimResult:
    """
    An in-memory simulation.

    ``messages``: list of (topic, core sample) in time order (``/tf_static``
    carries a list of :class:`StaticTransform`; built on first access);
    ``truth``: the truth.json dict; ``true``: internal-rate true arrays (``t`` s
    from the start, ``x``, ``y``, ``z`` m in the world, ``roll``, ``pitch``,
    ``yaw`` rad (yaw unwrapped), ``v`` m/s, ``w`` rad/s, ``gyro_body`` rad/s
    (N, 3), ``accel_body`` m/s^2 (N, 3) at the IMU point in base_link axes,
    ``tipped``); ``sensors``: the per-sensor arrays (``imu_t``, ``gyro``,
    ``accel``, ``odom_t``, ``odom_x``, ``odom_y``, ``odom_yaw``, ``js_t``,
    ``js_pos``, ``js_vel``, ``scan_t``, ``ranges``, ``cmd_t``, ``cmd_v``,
    ``cmd_w``, ``gt_t``, ``gt_x``, ``gt_y``, ``gt_yaw``; times in s from the
    start, without ``start_time``); ``world``, ``params``, ``start`` (world pose).
    """

    def __init__(self, truth: dict, true: dict, sensors: dict, world: Any = None,
                 params: Optional[SimParams] = None, start: tuple = (0.0, 0.0, 0.0)):
        """Hold the results; messages are built lazily."""
        self.truth = truth
        self.true = true
        self.sensors = sensors
        self.world = world
        self.params = params
        self.start = start
        self._messages: Optional[list] = None

    @property
    def messages(self) -> list:
        """Return (topic, core sample) pairs in time order."""
        if self._messages is None:
            self._messages = build_messages(self.sensors, self.params)
        return self._messages

    def topic(self, name: str) -> list:
        """Return the samples of one topic, in time order."""
        return [s for tp, s in self.messages if tp == name]

    def inputs(self, kinds: tuple = ('imu', 'odom')) -> list:
        """
        Return (kind, sample) pairs of the topics ``/<kind>`` and the static transforms.

        In time order, as a pipeline or an estimator takes them; every transform of a
        ``/tf_static`` message is one ``('tf_static', transform)`` pair.
        """
        topics = {f'/{k}': k for k in kinds}
        out = []
        for tp, s in self.messages:
            if tp in topics:
                out.append((topics[tp], s))
            elif tp == '/tf_static':
                out += [('tf_static', x) for x in s]
        return out


def rng_for(seed: int, name: str) -> np.random.Generator:
    """Return the random generator of stream ``name`` for ``seed`` (see :data:`STREAMS`)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed),
                                                        spawn_key=(STREAMS.index(name),)))


def _overrides_dict(overrides: Union[None, Mapping[str, Any], Iterable[str]]) -> dict[str, Any]:
    if overrides is None:
        return {}
    if isinstance(overrides, Mapping):
        return dict(overrides)
    out = {}
    for item in overrides:
        key, sep, value = str(item).partition('=')
        if not sep or not key.strip():
            raise SimError(f'bad --set {item!r}: expected key=value')
        out[key.strip()] = value.strip()
    return out


def get_scenario(name: str) -> Scenario:
    """Return a registered scenario; SimError when unknown or broken."""
    if name not in SCENARIOS:
        raise SimError(f'unknown scenario {name!r}; known: {", ".join(sorted(SCENARIOS))}')
    scenario = SCENARIOS[name]
    if isinstance(scenario, BrokenScenario):
        raise SimError(f'scenario {name!r} failed to load: {scenario.error}')
    return scenario


def make_params(scenario: Optional[Scenario] = None,
                overrides: Union[None, Mapping[str, Any], Iterable[str]] = None) -> SimParams:
    """Return the parameters: dataclass defaults < scenario defaults < overrides; SimError."""
    flat: dict[str, Any] = {}
    if scenario is not None:
        flat.update(scenario.defaults)
    user = _overrides_dict(overrides)
    known = set(to_flat(SimParams()))
    for key in user:
        if key not in known:
            raise SimError(f'unknown --set key {key!r}; see config/sim.yaml for the '
                           f'{len(known)} simulator parameters')
    flat.update(user)
    try:
        params = from_flat(SimParams, flat)
    except ParamError as exc:
        raise SimError(str(exc).splitlines()[0]) from None
    values = to_flat(params)
    for name, value in values.items():
        if isinstance(value, list):
            try:
                values[name] = [float(v) for v in value]
            except (TypeError, ValueError):
                raise SimError(f'parameter {name}: expected numbers, got {value!r}') from None
    params = from_flat(SimParams, values)
    for name in VECTOR_PARAMS:
        if len(values[name]) != 3:
            raise SimError(f'parameter {name}: expected 3 values (x, y, z), '
                           f'got {len(values[name])}')
    for name, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise SimError(f'parameter {name}: must be finite, got {value!r}')
        if isinstance(value, list) and not all(math.isfinite(v) for v in value):
            raise SimError(f'parameter {name}: values must be finite, got {value!r}')
    if len(params.wheels.slip_episodes) % 4:
        raise SimError('parameter wheels.slip_episodes: expected groups of 4 numbers '
                       '[t0, t1, left, right]')
    return params


def _run_plan(plant: Plant, plan: Any, total_ticks: int, tick_dt: float) -> list:
    """Execute the plan's steps on the plant; return the tip-over events (with times)."""
    tips = []
    for step in plan.steps:
        left = total_ticks - plant.ticks
        if left <= 0:
            break
        if step.event is not None:
            tip = step.event.get('tip')
            if tip is not None:
                tips.append(TipOver(**{**tip.__dict__, 't': plant.ticks * tick_dt}))
            continue
        n_full = int(round(step.duration / tick_dt))
        n = min(n_full, left)
        if step.controller is None and step.factory is None:
            if n > 0:
                values = step.values(n, tick_dt)
                if step.exact and n_full > 0:
                    values = values * (step.duration / (n_full * tick_dt))
                plant.advance(step.kind, values)
            continue
        control = step.factory() if step.factory is not None else step.controller
        for _ in range(n):
            cmd = control(plant.state())
            if cmd is None:
                break
            plant.advance(step.kind, np.asarray(cmd, dtype=float))
    left = total_ticks - plant.ticks
    if left > 0:
        plant.advance('twist', np.zeros((left, 2)))
    return tips


def _static_transforms(p: SimParams, t: float) -> list:
    base = p.odom.child_frame_id
    return [
        T.StaticTransform(base, p.imu.frame_id, np.array([p.imu.x, p.imu.y, p.imu.z]),
                          quat_from_rpy(p.imu.roll, p.imu.pitch, p.imu.yaw), t),
        T.StaticTransform(base, p.lidar.frame_id, np.array([p.lidar.x, p.lidar.y, p.lidar.z]),
                          quat_from_rpy(math.pi if p.lidar.upside_down else 0.0, 0.0,
                                        p.lidar.yaw), t),
    ]


def run_scenario(name: str, seed: int = 0, duration: Optional[float] = None,
                 overrides: Union[None, Mapping[str, Any], Iterable[str]] = None) -> SimResult:
    """
    Simulate scenario ``name`` in memory; raise :class:`SimError` on bad input.

    :param name: scenario name (see ``SCENARIOS``)
    :param seed: random seed (int >= 0)
    :param duration: length (s); None uses the scenario's default
    :param overrides: ``{dotted name: value}`` or ``['key=value', ...]`` parameter overrides
    """
    scenario = get_scenario(name)
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise SimError(f'bad seed {seed!r}: expected an integer >= 0') from None
    if seed < 0:
        raise SimError(f'bad seed {seed}: expected an integer >= 0')
    if duration is None:
        duration = scenario.duration
    try:
        duration = float(duration)
    except (TypeError, ValueError):
        raise SimError(f'bad duration {duration!r}: expected seconds > 0') from None
    if not math.isfinite(duration) or duration <= 0:
        raise SimError(f'bad duration {duration!r}: expected seconds > 0')
    params = make_params(scenario, overrides)
    setup = scenario.build(BuildContext(params, duration, seed, rng_for(seed, 'scenario')))
    return run_setup(setup, params, duration, seed, scenario)


def run_setup(setup: Any, params: SimParams, duration: float, seed: int = 0,
              scenario: Optional[Scenario] = None) -> SimResult:
    """Simulate a built :class:`~robot_calib.sim.scenario.Setup` (for tests and tools)."""
    p = params
    n_sub = max(1, int(round(p.rate / p.odom.cmd_vel_rate)))
    tick_dt = n_sub / p.rate
    n_fine = int(math.floor(duration * p.rate + 1e-9)) + 1
    total_ticks = int(math.ceil(n_fine / n_sub))
    try:
        plant = Plant(p, setup.start, n_sub, setup.world)
        tips = _run_plan(plant, setup.plan, total_ticks, tick_dt)
    except PlantError as exc:
        raise SimError(str(exc)) from None
    tr = plant.arrays()
    for key in list(tr):
        if not key.startswith('cmd_'):
            tr[key] = tr[key][:n_fine]
    keep = tr['cmd_t'] <= duration + 1e-9
    for key in ('cmd_t', 'cmd_v', 'cmd_w'):
        tr[key] = tr[key][keep]
    tr = attitude(tr, p, setup.world, tips)
    sens = simulate_sensors(tr, p, setup, duration, seed)
    truth = {'scenario': scenario.name if scenario else '', 'seed': seed,
             'duration': duration, 'start_time': p.start_time,
             'description': scenario.description if scenario else '',
             'start_pose': [float(v) for v in setup.start]}
    truth.update(S.truth_values(p, sens.pop('_gyro_bias')))
    truth['tip_overs'] = [{'t': tip.t, 'axis': tip.axis, 'direction': tip.direction,
                           'angle': tip.angle, 'mode': tip.mode} for tip in tips]
    for key, value in (setup.truth or {}).items():
        truth.setdefault(key, value)
    truth['frames'] = {'odom': p.odom.frame_id, 'base_link': p.odom.child_frame_id,
                       'imu': p.imu.frame_id, 'laser': p.lidar.frame_id}
    truth['params'] = to_flat(p)
    truth['topics'] = message_counts(sens)
    return SimResult(jsonable(truth), tr, sens, setup.world, p, tuple(setup.start))


def message_counts(sens: dict[str, Any]) -> dict[str, int]:
    """Return {topic: number of messages} of the sensor arrays."""
    return {'/tf_static': 1, '/cmd_vel': int(sens['cmd_t'].size),
            '/ground_truth/odom': int(sens['gt_t'].size), '/imu': int(sens['imu_t'].size),
            '/joint_states': int(sens['js_t'].size), '/odom': int(sens['odom_t'].size),
            '/scan': int(sens['scan_t'].size)}


def simulate_sensors(tr: dict, p: SimParams, setup: Any, duration: float,
                     seed: int) -> dict[str, Any]:
    """Return every sensor's arrays (see :class:`SimResult`)."""
    out: dict[str, Any] = {}
    bias = S.true_gyro_bias(p, rng_for(seed, 'imu_bias'))
    out['_gyro_bias'] = bias
    t = S.sample_times(p.imu.rate, duration)
    gyro, accel, extra = S.imu(tr, p, t, rng_for(seed, 'imu'), bias)
    out.update({'imu_t': t, 'gyro': gyro, 'accel': accel,
                'imu_gyro_bias': extra['gyro_bias'], 'imu_accel_bias': extra['accel_bias']})
    t = S.sample_times(p.odom.joint_states_rate, duration)
    pos, vel = S.encoders(tr, p, t, rng_for(seed, 'wheels'))
    out.update({'js_t': t, 'js_pos': pos, 'js_vel': vel})
    t = S.sample_times(p.odom.rate, duration)
    opos, _ = S.encoders(tr, p, t, rng_for(seed, 'odom'), latency=p.latency.odom)
    odom = S.wheel_odometry(p, t, opos)
    out.update({'odom_t': t, **{f'odom_{k}': v for k, v in odom.items()}})
    t = S.sample_times(p.lidar.rate, duration)
    out['scan_t'] = t
    out['ranges'] = S.lidar(tr, p, setup.world, t, rng_for(seed, 'lidar'))
    t = S.sample_times(p.odom.ground_truth_rate, duration)
    x0, y0, yaw0 = (float(v) for v in setup.start)
    c, s = math.cos(yaw0), math.sin(yaw0)
    gx, gy = S.interp(tr, 'x', t) - x0, S.interp(tr, 'y', t) - y0
    out.update({'gt_t': t, 'gt_x': c * gx + s * gy, 'gt_y': -s * gx + c * gy,
                'gt_yaw': S.interp(tr, 'yaw', t) - yaw0, 'gt_z': S.interp(tr, 'z', t),
                'gt_roll': S.interp(tr, 'roll', t), 'gt_pitch': S.interp(tr, 'pitch', t),
                'gt_v': S.interp(tr, 'v', t), 'gt_w': S.interp(tr, 'w', t)})
    out.update({'cmd_t': tr['cmd_t'], 'cmd_v': tr['cmd_v'], 'cmd_w': tr['cmd_w']})
    return out


def build_messages(sens: dict[str, Any], p: SimParams) -> list:
    """Return (topic, core sample) in time order from the sensor arrays."""
    t0 = p.start_time
    per: list[tuple[np.ndarray, list]] = []
    tf = [(t0, _static_transforms(p, t0))]
    per.append((np.array([t0]), [s for _, s in tf]))
    per.append((sens['cmd_t'] + t0, [T.TwistSample(t + t0, v, 0.0, w) for t, v, w in
                                     zip(sens['cmd_t'].tolist(), sens['cmd_v'].tolist(),
                                         sens['cmd_w'].tolist())]))
    base, odom_frame = p.odom.child_frame_id, p.odom.frame_id
    gt_yaw = wrap_angle(sens['gt_yaw'])
    per.append((sens['gt_t'] + t0, [
        T.OdomSample(t + t0, x, y, yaw, v, 0.0, w, odom_frame, base, z=z, roll=r, pitch=pi)
        for t, x, y, yaw, v, w, z, r, pi in zip(
            sens['gt_t'].tolist(), sens['gt_x'].tolist(), sens['gt_y'].tolist(),
            np.atleast_1d(gt_yaw).tolist(), sens['gt_v'].tolist(), sens['gt_w'].tolist(),
            sens['gt_z'].tolist(), sens['gt_roll'].tolist(), sens['gt_pitch'].tolist())]))
    q = p.imu
    gcov = np.eye(3) * (q.gyro_noise ** 2 * q.rate) if q.gyro_noise > 0 else None
    acov = np.eye(3) * (q.accel_noise ** 2 * q.rate) if q.accel_noise > 0 else None
    frame = q.frame_id
    per.append((sens['imu_t'] + t0, [
        T.ImuSample(t + t0, g, a, frame, None, None, gcov, acov)
        for t, g, a in zip(sens['imu_t'].tolist(), sens['gyro'], sens['accel'])]))
    if p.robot.drive_type == 'steered_wheel':
        names = (p.odom.steering_joint, p.odom.traction_joint)
    else:
        names = (p.odom.left_joint, p.odom.right_joint)
    per.append((sens['js_t'] + t0, [
        T.JointStateSample(t + t0, names, pos, vel)
        for t, pos, vel in zip(sens['js_t'].tolist(), sens['js_pos'], sens['js_vel'])]))
    oyaw = np.atleast_1d(wrap_angle(sens['odom_yaw']))
    per.append((sens['odom_t'] + t0, [
        T.OdomSample(t + t0, x, y, yaw, vx, 0.0, wz, odom_frame, base)
        for t, x, y, yaw, vx, wz in zip(sens['odom_t'].tolist(), sens['odom_x'].tolist(),
                                        sens['odom_y'].tolist(), oyaw.tolist(),
                                        sens['odom_vx'].tolist(), sens['odom_wz'].tolist())]))
    amin, inc, tinc = S.lidar_geometry(p)
    li = p.lidar
    scan_time = 1.0 / li.rate
    per.append((sens['scan_t'] + t0, [
        T.ScanSample(t + t0, amin, inc, r, li.range_min, li.range_max, li.frame_id, None, tinc,
                     scan_time)
        for t, r in zip(sens['scan_t'].tolist(), sens['ranges'])]))
    times = np.concatenate([tt for tt, _ in per])
    order = np.concatenate([np.full(len(tt), i) for i, (tt, _) in enumerate(per)])
    samples = [s for _, ss in per for s in ss]
    topics = [TOPICS[i] for i in order.tolist()]
    idx = np.lexsort((order, np.round(times * 1e9)))
    return [(topics[i], samples[i]) for i in idx.tolist()]


def truth_path(out: Union[str, os.PathLike]) -> Path:
    """Return ``<out>.truth.json`` next to the bag folder ``out``."""
    path = Path(out)
    return path.with_name(path.name + '.truth.json')


def check_storage(storage: str) -> None:
    """Raise SimError unless ``storage`` is a bag storage the simulator writes."""
    if storage not in ('mcap', 'sqlite3'):
        raise SimError(f'unknown storage {storage!r}; expected mcap or sqlite3')


def simulate(scenario: str, out: Union[str, os.PathLike], seed: int = 0,
             duration: Optional[float] = None,
             overrides: Union[None, Mapping[str, Any], Iterable[str]] = None,
             storage: str = 'mcap', compress: bool = False) -> dict:
    """
    Simulate and write the ROS 2 bag folder ``out`` and ``<out>.truth.json``; return the truth.

    ``compress`` zstd-compresses the mcap chunks (about 5x smaller, slower).
    Raises :class:`SimError` (one line) for an unknown scenario, a bad
    override, an existing or unwritable output.
    """
    from robot_calib.io.bags import BagError, BagWriter
    check_storage(storage)
    result = run_scenario(scenario, seed, duration, overrides)
    tpath = truth_path(out)
    try:
        kwargs = {'compress': True} if compress else {}
        with BagWriter(out, storage, **kwargs) as writer:
            write_bag(writer, result)
    except BagError as exc:
        raise SimError(str(exc)) from None
    tmp = tpath.with_name('.' + tpath.name + '.partial')
    try:
        tmp.write_text(json.dumps(result.truth, indent=1, sort_keys=False) + '\n')
        os.replace(tmp, tpath)
    except BaseException:  # a full disk, an interrupt: neither half of the pair is left
        tmp.unlink(missing_ok=True)
        if Path(out).is_dir():
            shutil.rmtree(out, ignore_errors=True)  # the bag just written (never one before)
        raise
    return result.truth


def write_messages(writer: Any, messages: list) -> None:
    """Write (topic, sample) pairs with a BagWriter, one by one (the reference path)."""
    for topic, sample in messages:
        writer.write(topic, sample)


def encoded_streams(result: SimResult) -> list[tuple[str, str, np.ndarray, list]]:
    """
    Return per topic (topic, msgtype, receive times ns, CDR bytes) of a result (fast path).

    Every topic but ``/tf_static`` is encoded by :func:`robot_calib.codec.templates.encode_stream`
    from the arrays; a topic whose template cannot be patched falls back to rosbags.
    """
    from robot_calib import codec
    sens, p = result.sensors, result.params
    t0 = p.start_time
    out = []
    samples: dict[str, list] = {}

    def first(topic: str) -> Any:
        if topic not in samples:
            samples[topic] = [s for tp, s in build_messages(_head(sens), p) if tp == topic]
        return samples[topic][0]

    def add(topic: str, times: np.ndarray, patches_fn) -> None:
        ns, sn = C.stamps(times + t0)
        sample = first(topic)
        msgtype, msg = codec.to_msg(sample)
        try:
            data = C.encode_stream(msgtype, msg, patches_fn(sn))
        except C.TemplateError:
            data = [codec.serialize(s)[1] for tp, s in result.messages if tp == topic]
        out.append((topic, msgtype, ns, data))

    tf = _static_transforms(p, t0)
    ns = np.array([int(round(t0 * 1e9))], dtype=np.int64)
    out.append(('/tf_static', 'tf2_msgs/msg/TFMessage', ns, [codec.serialize(tf)[1]]))
    zeros = np.zeros((sens['cmd_t'].size, 1))
    add('/cmd_vel', sens['cmd_t'], lambda sn: [
        ('linear', 'xyz', np.column_stack((sens['cmd_v'], zeros, zeros))),
        ('angular', 'xyz', np.column_stack((zeros, zeros, sens['cmd_w'])))])
    n = sens['gt_t'].size
    zeros = np.zeros(n)
    add('/ground_truth/odom', sens['gt_t'], lambda sn: [
        ('header.stamp', 'stamp', sn),
        ('pose.pose.position', 'xyz', np.column_stack((sens['gt_x'], sens['gt_y'],
                                                       sens['gt_z']))),
        ('pose.pose.orientation', 'xyzw', C.quat_xyzw(sens['gt_roll'], sens['gt_pitch'],
                                                      np.atleast_1d(wrap_angle(sens['gt_yaw'])))),
        ('twist.twist.linear', 'xyz', np.column_stack((sens['gt_v'], zeros, zeros))),
        ('twist.twist.angular', 'xyz', np.column_stack((zeros, zeros, sens['gt_w'])))])
    add('/imu', sens['imu_t'], lambda sn: [
        ('header.stamp', 'stamp', sn), ('angular_velocity', 'xyz', sens['gyro']),
        ('linear_acceleration', 'xyz', sens['accel'])])
    add('/joint_states', sens['js_t'], lambda sn: [
        ('header.stamp', 'stamp', sn), ('position', 'f8', sens['js_pos']),
        ('velocity', 'f8', sens['js_vel'])])
    n = sens['odom_t'].size
    zeros = np.zeros(n)
    add('/odom', sens['odom_t'], lambda sn: [
        ('header.stamp', 'stamp', sn),
        ('pose.pose.position', 'xyz', np.column_stack((sens['odom_x'], sens['odom_y'], zeros))),
        ('pose.pose.orientation', 'xyzw',
         C.quat_xyzw(zeros, zeros, np.atleast_1d(wrap_angle(sens['odom_yaw'])))),
        ('twist.twist.linear', 'xyz', np.column_stack((sens['odom_vx'], zeros, zeros))),
        ('twist.twist.angular', 'xyz', np.column_stack((zeros, zeros, sens['odom_wz'])))])
    add('/scan', sens['scan_t'], lambda sn: [
        ('header.stamp', 'stamp', sn), ('ranges', 'f4', sens['ranges'])])
    return out


def _head(sens: dict[str, Any]) -> dict[str, Any]:
    """Return the sensor arrays cut to their first sample (to build template messages)."""
    return {k: (v[:1] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.size else v)
            for k, v in sens.items()}


def write_bag(writer: Any, result: SimResult) -> None:
    """Write a result into an open BagWriter, all topics merged in time order (fast path)."""
    streams = encoded_streams(result)
    times = np.concatenate([ns for _, _, ns, _ in streams])
    order = np.concatenate([np.full(ns.size, i) for i, (_, _, ns, _) in enumerate(streams)])
    rows = np.concatenate([np.arange(ns.size) for _, _, ns, _ in streams])
    idx = np.lexsort((order, times))
    for i in idx.tolist():
        topic, msgtype, ns, data = streams[order[i]]
        j = rows[i]
        writer.write_raw(topic, msgtype, data[j], int(ns[j]))


def state_at(result: SimResult, t: float) -> State:
    """Return the true world-frame state of a result at time ``t`` (s from the start)."""
    tr = result.true
    return State(t, float(np.interp(t, tr['t'], tr['x'])), float(np.interp(t, tr['t'], tr['y'])),
                 float(np.interp(t, tr['t'], tr['yaw'])), float(np.interp(t, tr['t'], tr['v'])),
                 float(np.interp(t, tr['t'], tr['w'])), result.world)
