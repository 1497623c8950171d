# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Follow a real recording: drive the simulated robot with its velocity commands.

``robot-calib simulate follow REAL_BAG --out SIM_BAG`` makes the simulation half
of a sim-vs-real pair from a real recording alone:

1. the command topic: ``cmd_vel`` by name among the ``geometry_msgs/Twist`` and
   ``TwistStamped`` topics, else the only such topic (``--cmd-topic`` names
   another); no command topic is an error;
2. the clock: the simulation starts at the recording's first message (header
   stamps, or receive times of unstamped commands) and ends at its last
   (``start_time`` is set from it; the control tick is ``follow.control_rate``,
   not ``odom.cmd_vel_rate``); the robot starts at rest at (0, 0, 0) in ``odom``;
3. the commands drive :class:`~robot_calib.sim.robot.Plant` (the simulator's
   robot: drive dynamics ``drive.*``, wheel errors, actuator lag), each held
   until the next one, and zero after ``follow.cmd_timeout`` s without one
   (as a base controller's command timeout does);
4. the sensors are sampled at the real messages' own stamps, under the real
   topic names and frame ids: every ``nav_msgs/Odometry`` topic gets the wheel
   odometry (or the true motion when its name says ground truth: ``truth``,
   ``ground_truth``, ``mocap``, ``vicon``, ``optitrack``, ``vrpn``, ``gt``),
   every ``sensor_msgs/Imu`` topic the IMU, every ``sensor_msgs/JointState``
   topic the wheel joints (a steering joint there makes the robot a steered
   wheel unless ``robot.drive_type`` is given); a kind the recording lacks is
   written under the simulator's default name and rate;
5. ``/ground_truth/odom``, ``/tf_static`` (the IMU mounting) and the commands
   themselves (same topic and type) complete the bag; ``<out>.truth.json``
   holds the parameters, the seed, the command topic and the topic map.

Parameters: ``--params FILE`` (a simulator parameter YAML: ``sim_params.yaml`` of
``robot-calib mismatch``, ``config/sim.yaml``, or flat ``group.name: value``
keys) and then ``--set key=value``; both take the keys of
:class:`~robot_calib.sim.params.SimParams` and :class:`FollowParams`
(``follow.*``).
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Union

import numpy as np

from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, wrap_angle
from robot_calib.core.jsonable import jsonable
from robot_calib.core.params import from_flat, param, ParamError, to_flat
from robot_calib.sim import sensors as S
from robot_calib.sim.engine import (check_storage, make_params, rng_for, SimError,
                                    truth_path)
from robot_calib.sim.robot import attitude, Plant, PlantError

TRUTH_WORDS = ('truth', 'ground_truth', 'groundtruth', 'mocap', 'vicon', 'optitrack', 'vrpn',
               'gt')
"""Words of an odometry topic name that mark it as ground truth (matched per name part)."""

MAX_SAMPLES = 5e6
"""Most internal-rate samples of one run (about 1.2 GB of arrays; 83 min at 1 kHz)."""

DEFAULT_TOPICS = {'odom': '/odom', 'imu': '/imu', 'joint_states': '/joint_states'}


@dataclass
class FollowParams:
    """How the recording's commands drive the simulated robot (``follow.*`` keys)."""

    cmd_timeout: float = param(0.5, 's', 'a command older than this is replaced by a stop '
                               '(ros2_control diff_drive_controller: cmd_vel_timeout 0.5 s); '
                               'raised to 3 median command intervals for sparse commands',
                               minimum=0.0)
    control_rate: float = param(100.0, 'Hz', 'rate at which the robot samples the commands '
                                '(the simulator control tick)', minimum=1.0)


def load_params_file(path: Union[str, os.PathLike]) -> dict[str, Any]:
    """
    Return ``{dotted key: value}`` of a simulator parameter YAML; ValueError when unreadable.

    Accepts the nested form (``sim:`` or top-level groups, as ``config/sim.yaml`` and
    ``sim_params.yaml``) and flat dotted keys.
    """
    import yaml
    p = Path(path)
    if not p.is_file():
        raise ValueError(f'parameter file not found: {p}')
    try:
        data = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ValueError(f'cannot parse {p}: {" ".join(str(exc).split())}') from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f'{p}: expected a mapping of simulator parameters')
    if 'sim' in data:  # sim_params.yaml: the parameters under sim:, beside source: and notes
        data = data['sim'] or {}
        if not isinstance(data, dict):
            raise ValueError(f'{p}: expected a mapping under sim:')
    flat: dict[str, Any] = {}

    def walk(prefix: str, node: Mapping) -> None:
        for key, value in node.items():
            name = f'{prefix}{key}'
            if isinstance(value, dict):
                walk(name + '.', value)
            else:
                flat[name] = value
    walk('', data)
    return flat


def _split(values: dict[str, Any]) -> tuple[dict[str, Any], FollowParams]:
    """Return the simulator keys and the :class:`FollowParams` of merged overrides."""
    own = {k[len('follow.'):]: v for k, v in values.items() if k.startswith('follow.')}
    rest = {k: v for k, v in values.items() if not k.startswith('follow.')}
    try:
        fp = from_flat(FollowParams, own)
    except ParamError as exc:
        raise SimError(str(exc).splitlines()[0]) from None
    return rest, fp


def _is_truth(topic: str) -> bool:
    parts = [p for p in topic.lower().replace('-', '_').split('/') if p]
    words = set()
    for part in parts:
        words.add(part)
        words.update(part.split('_'))
    return any(w in words for w in TRUTH_WORDS) or any('ground_truth' in p for p in parts)


def command_topic(topics: Mapping[str, tuple], wanted: Optional[str] = None) -> str:
    """
    Return the velocity-command topic of a bag's ``{topic: (type, count)}``; SimError if none.

    :param topics: the bag's topics
    :param wanted: a topic the user named (``--cmd-topic``)
    """
    from robot_calib import codec
    twist_types = {row.msgtype for row in codec.ROWS if codec.accepts('cmd_vel', row.msgtype)}
    twists = sorted(t for t, (tp, n) in topics.items() if tp in twist_types and n > 0)
    if wanted:
        name = '/' + wanted.lstrip('/')
        if name not in topics:
            raise SimError(f'command topic {name} is not in the bag; its velocity topics: '
                           f'{", ".join(twists) or "none"}')
        if name not in twists:
            raise SimError(f'command topic {name} is a {topics[name][0]}, not a '
                           'geometry_msgs/Twist or TwistStamped with messages')
        return name
    if not twists:
        raise SimError('the bag has no velocity commands (no geometry_msgs/Twist or '
                       'TwistStamped topic with messages); follow needs them')
    named = [t for t in twists if t.rsplit('/', 1)[-1] == 'cmd_vel']
    if len(named) == 1:
        return named[0]
    if len(twists) == 1:
        return twists[0]
    pool = named or twists
    raise SimError(f'several velocity topics ({", ".join(pool)}); name the command topic '
                   'with --cmd-topic')


class _Real:
    """What follow reads from the real bag: commands, per-topic stamps and frame ids."""

    def __init__(self) -> None:
        self.cmd: list = []
        self.cmd_type = ''
        self.stamps: dict[str, list] = {}
        self.types: dict[str, str] = {}
        self.frames: dict[str, tuple] = {}
        self.joints: dict[str, tuple] = {}


def read_real(path: Union[str, os.PathLike], cmd_topic: Optional[str]) -> tuple[str, _Real]:
    """Return the command topic and what follow needs of the real bag (SimError on bad input)."""
    from robot_calib import codec
    from robot_calib.io import bags
    p = Path(path)
    if not p.exists():
        raise SimError(f'real bag not found: {p}')
    imu_t, odom_t, js_t = (codec.KINDS[k].msgtype for k in ('imu', 'odom', 'joint_states'))
    try:
        topics = bags.list_topics([p])
        try:
            cmd = command_topic(topics, cmd_topic)
        except SimError as exc:
            raise SimError(f'{p.name}: {exc}') from None
        sensors = {t: tp for t, (tp, n) in topics.items() if tp in (imu_t, odom_t, js_t)}
        real = _Real()
        real.cmd_type = topics[cmd][0]
        real.types = dict(sensors)
        for msg in bags.read_messages([p], topics=[cmd, *sensors]):
            for s in msg.samples:
                if msg.topic == cmd:
                    real.cmd.append(s)
                    continue
                real.stamps.setdefault(msg.topic, []).append(float(s.t))
                if msg.topic not in real.frames:
                    if isinstance(s, T.OdomSample):
                        real.frames[msg.topic] = (s.frame_id, s.child_frame_id)
                    elif isinstance(s, T.ImuSample):
                        real.frames[msg.topic] = (s.frame_id,)
                if isinstance(s, T.JointStateSample) and msg.topic not in real.joints:
                    real.joints[msg.topic] = tuple(s.names)
    except bags.BagError as exc:
        raise SimError(str(exc)) from None
    if not real.cmd:
        raise SimError(f'the command topic {cmd} has no readable message')
    return cmd, real


def _times(stamps: Iterable[float], t0: float, duration: float) -> np.ndarray:
    """Return sorted unique sample times (s from t0) within the run."""
    t = np.unique(np.asarray(list(stamps), float) - t0)
    return t[(t >= 0.0) & (t <= duration + 1e-9)]


def _commands(real: _Real, t0: float, ticks: int, tick_dt: float,
              fp: FollowParams) -> tuple[np.ndarray, float]:
    """Return the held command (v, omega) at each control tick (K, 2) and the timeout used."""
    ct = np.array([s.t for s in real.cmd], float) - t0
    order = np.argsort(ct, kind='stable')
    ct = ct[order]
    vw = np.array([[s.vx, s.wz] for s in real.cmd], float)[order]
    vw = np.where(np.isfinite(vw), vw, 0.0)
    gaps = np.diff(ct)
    gaps = gaps[gaps > 0]
    timeout = fp.cmd_timeout
    if gaps.size:
        timeout = max(timeout, 3.0 * float(np.median(gaps)))
    tt = np.arange(ticks) * tick_dt
    idx = np.searchsorted(ct, tt + 1e-9, side='right') - 1
    out = np.zeros((ticks, 2))
    ok = idx >= 0
    out[ok] = vw[idx[ok]]
    stale = ok & (tt - ct[np.maximum(idx, 0)] > timeout)
    out[stale | ~ok] = 0.0
    return out, timeout


def _joint_names(p: Any, real_names: Optional[tuple]) -> tuple:
    """Return the two joint names: the real bag's left/right (steering/traction) ones if any."""
    steered = p.robot.drive_type == 'steered_wheel'
    default = (p.odom.steering_joint, p.odom.traction_joint) if steered else \
        (p.odom.left_joint, p.odom.right_joint)
    if not real_names:
        return default
    low = [n.lower() for n in real_names]
    keys = (('steer',), ('tract', 'drive', 'wheel')) if steered else (('left',), ('right',))
    pick = []
    for words in keys:
        hit = [n for n, lo in zip(real_names, low) if any(w in lo for w in words)
               and n not in pick]
        pick.append(hit[0] if hit else None)
    if None in pick:
        return default
    return tuple(pick)


def run_follow(real_bag: Union[str, os.PathLike], seed: int = 0,
               overrides: Optional[dict[str, Any]] = None,
               cmd_topic: Optional[str] = None) -> tuple[list, dict]:
    """
    Simulate the robot following a real bag's commands; return (messages, truth).

    ``messages`` are ``(topic, core sample)`` in time order; ``truth`` is the
    ``truth.json`` dict. Raises :class:`SimError` (one line) on bad input.
    """
    values, fp = _split(dict(overrides or {}))
    cmd, real = read_real(real_bag, cmd_topic)
    times = [s.t for s in real.cmd] + [t for ts in real.stamps.values() for t in ts]
    t0, t1 = float(min(times)), float(max(times))
    duration = t1 - t0
    if duration <= 0:
        raise SimError(f'the recording {real_bag} spans no time (one instant); nothing to follow')
    steering = any('steer' in n.lower() for names in real.joints.values() for n in names)
    if steering and 'robot.drive_type' not in values:
        values['robot.drive_type'] = 'steered_wheel'  # the recording has a steering joint
    values['start_time'] = t0  # the recording's clock, whatever a parameter file says
    values['odom.cmd_vel_rate'] = fp.control_rate
    p = make_params(None, values)
    if duration * p.rate > MAX_SAMPLES:
        raise SimError(f'the recording spans {duration:.0f} s (stamps from {t0:.3f} to {t1:.3f}'
                       f'), {duration * p.rate:.3g} samples at the internal rate of {p.rate:g} '
                       f'Hz (at most {MAX_SAMPLES:.0e}): a stamp may be unset or on another '
                       'clock; else lower the rate (--set rate=200) or cut the recording')
    n_sub = max(1, int(round(p.rate / p.odom.cmd_vel_rate)))
    tick_dt = n_sub / p.rate
    n_fine = int(math.floor(duration * p.rate + 1e-9)) + 1
    ticks = int(math.ceil(n_fine / n_sub))
    commands, timeout = _commands(real, t0, ticks, tick_dt, fp)
    try:
        plant = Plant(p, (0.0, 0.0, 0.0), n_sub, None)
        plant.advance('twist', commands)
    except PlantError as exc:
        raise SimError(str(exc)) from None
    tr = plant.arrays()
    for key in list(tr):
        if not key.startswith('cmd_'):
            tr[key] = tr[key][:n_fine]
    tr = attitude(tr, p, None, [])
    messages, topic_map = _sensor_messages(tr, p, real, t0, duration, seed)
    base = next((f[1] for tp, f in real.frames.items() if len(f) == 2
                 and not _is_truth(tp)), p.odom.child_frame_id)
    stamped = real.cmd_type.endswith('TwistStamped')
    messages += [(cmd, T.StampedTwistSample(s.t, s.vx, s.vy, s.wz, frame_id=base) if stamped
                  else s) for s in real.cmd if t0 <= s.t <= t1]
    imu_frame = next((f[0] for f in real.frames.values() if len(f) == 1), p.imu.frame_id)
    tf = [T.StaticTransform(base, imu_frame, np.array([p.imu.x, p.imu.y, p.imu.z]),
                            quat_from_rpy(p.imu.roll, p.imu.pitch, p.imu.yaw), t0)]
    messages.append(('/tf_static', tf))
    order = sorted(range(len(messages)), key=lambda i: (_t(messages[i][1]), i))
    messages = [messages[i] for i in order]
    bias = S.true_gyro_bias(p, rng_for(seed, 'imu_bias'))
    truth: dict[str, Any] = {'scenario': 'follow', 'seed': int(seed), 'duration': duration,
                             'start_time': t0, 'source': str(real_bag),
                             'command_topic': cmd, 'command_type': real.cmd_type,
                             'commands': len(real.cmd), 'command_timeout': timeout,
                             'description': 'the simulated robot driven by the velocity '
                                            f'commands of {Path(real_bag).name}',
                             'start_pose': [0.0, 0.0, 0.0]}
    truth.update(S.truth_values(p, bias))
    truth['frames'] = {'odom': p.odom.frame_id, 'base_link': base, 'imu': imu_frame}
    truth['params'] = to_flat(p)
    truth['params'].update({f'follow.{k}': v for k, v in to_flat(fp).items()})
    truth['topic_map'] = topic_map
    counts: dict[str, int] = {}
    for tp, _ in messages:
        counts[tp] = counts.get(tp, 0) + 1
    truth['topics'] = counts
    return messages, jsonable(truth)


def _t(sample: Any) -> float:
    if isinstance(sample, list):
        return float(sample[0].t) if sample else 0.0
    return float(sample.t)


def _sensor_messages(tr: dict, p: Any, real: _Real, t0: float, duration: float,
                     seed: int) -> tuple[list, dict]:
    """Return the sensor messages at the real stamps, and {topic: what it carries}."""
    from robot_calib import codec
    kinds = {codec.KINDS[k].msgtype: k for k in ('imu', 'odom', 'joint_states')}
    by_kind: dict[str, list] = {'imu': [], 'odom': [], 'joint_states': []}
    for topic, tp in sorted(real.types.items()):
        by_kind[kinds[tp]].append(topic)
    rates = {'imu': p.imu.rate, 'odom': p.odom.rate, 'joint_states': p.odom.joint_states_rate}
    out: list = []
    topic_map: dict[str, str] = {}
    bias = S.true_gyro_bias(p, rng_for(seed, 'imu_bias'))
    truth_written = False
    for kind in ('imu', 'odom', 'joint_states'):
        topics = by_kind[kind] or [DEFAULT_TOPICS[kind]]
        for topic in topics:
            stamps = real.stamps.get(topic)
            t = _times(stamps, t0, duration) if stamps else S.sample_times(rates[kind], duration)
            if t.size < 2:
                t = S.sample_times(rates[kind], duration)
            if kind == 'imu':
                gyro, accel, _ = S.imu(tr, p, t, rng_for(seed, 'imu'), bias)
                frame = real.frames.get(topic, (p.imu.frame_id,))[0]
                out += [(topic, T.ImuSample(ti + t0, g, a, frame))
                        for ti, g, a in zip(t.tolist(), gyro, accel)]
                topic_map[topic] = 'imu'
            elif kind == 'joint_states':
                pos, vel = S.encoders(tr, p, t, rng_for(seed, 'wheels'))
                names = _joint_names(p, real.joints.get(topic))
                out += [(topic, T.JointStateSample(ti + t0, names, ps, vs))
                        for ti, ps, vs in zip(t.tolist(), pos, vel)]
                topic_map[topic] = 'joint_states'
            else:
                frames = real.frames.get(topic, (p.odom.frame_id, p.odom.child_frame_id))
                if _is_truth(topic):
                    out += _truth_odom(tr, topic, t, t0, frames)
                    topic_map[topic] = 'ground_truth'
                    truth_written = truth_written or topic == '/ground_truth/odom'
                    continue
                opos, _ = S.encoders(tr, p, t, rng_for(seed, 'odom'), latency=p.latency.odom)
                odom = S.wheel_odometry(p, t, opos)
                yaw = np.atleast_1d(wrap_angle(odom['yaw']))
                out += [(topic, T.OdomSample(ti + t0, x, y, yw, vx, 0.0, wz, *frames))
                        for ti, x, y, yw, vx, wz in zip(t.tolist(), odom['x'].tolist(),
                                                        odom['y'].tolist(), yaw.tolist(),
                                                        odom['vx'].tolist(),
                                                        odom['wz'].tolist())]
                topic_map[topic] = 'odom'
    if not truth_written and '/ground_truth/odom' not in real.types:
        t = S.sample_times(p.odom.ground_truth_rate, duration)
        out += _truth_odom(tr, '/ground_truth/odom', t, t0,
                           (p.odom.frame_id, p.odom.child_frame_id))
        topic_map['/ground_truth/odom'] = 'ground_truth'
    return out, topic_map


def _truth_odom(tr: dict, topic: str, t: np.ndarray, t0: float, frames: tuple) -> list:
    """Return the true pose and twist at times ``t`` (s from t0) as odometry messages."""
    x, y = S.interp(tr, 'x', t), S.interp(tr, 'y', t)
    yaw = np.atleast_1d(wrap_angle(S.interp(tr, 'yaw', t)))
    v, w = S.interp(tr, 'v', t), S.interp(tr, 'w', t)
    z, roll, pitch = S.interp(tr, 'z', t), S.interp(tr, 'roll', t), S.interp(tr, 'pitch', t)
    return [(topic, T.OdomSample(ti + t0, xi, yi, yi_, vi, 0.0, wi, frames[0], frames[1],
                                 z=zi, roll=ri, pitch=pi))
            for ti, xi, yi, yi_, vi, wi, zi, ri, pi in zip(
                t.tolist(), x.tolist(), y.tolist(), yaw.tolist(), v.tolist(), w.tolist(),
                z.tolist(), roll.tolist(), pitch.tolist())]


def follow(real_bag: Union[str, os.PathLike], out: Union[str, os.PathLike], seed: int = 0,
           overrides: Optional[dict[str, Any]] = None, params_file: Optional[str] = None,
           cmd_topic: Optional[str] = None, storage: str = 'mcap') -> dict:
    """
    Write the bag of the simulated robot following ``real_bag``'s commands; return the truth.

    :param real_bag: the real recording (ROS 1 bag, ROS 2 folder or .mcap)
    :param out: output bag folder (must not exist)
    :param seed: random seed of the sensor noise
    :param overrides: ``{dotted key: value}`` (``--set``), applied after ``params_file``
    :param params_file: a simulator parameter YAML (``--params``)
    :param cmd_topic: the command topic, when the bag has several velocity topics
    :param storage: ``mcap`` or ``sqlite3``
    :raises SimError: on bad input (one line); nothing is left behind
    """
    from robot_calib.io.bags import BagError, BagWriter
    check_storage(storage)
    values: dict[str, Any] = {}
    if params_file:
        values.update(load_params_file(params_file))
    values.update(overrides or {})
    messages, truth = run_follow(real_bag, seed, values, cmd_topic)
    if params_file:
        truth['params_file'] = str(params_file)
    tpath = truth_path(out)
    try:
        with BagWriter(out, storage) as writer:
            for topic, sample in messages:
                writer.write(topic, sample)
    except BagError as exc:
        raise SimError(str(exc)) from None
    tmp = tpath.with_name('.' + tpath.name + '.partial')
    tmp.write_text(json.dumps(truth, indent=1) + '\n')
    os.replace(tmp, tpath)
    return truth
