# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""The codec's fast paths against rosbags' type store, and the stored type definitions."""

import math

import numpy as np
import pytest

from robot_calib import codec
from robot_calib.codec import cdr_more
from robot_calib.codec.definitions import DEFINITIONS
from robot_calib.core import types as T
from test_io_bags import assert_same


def _frame(rng):
    """Return a frame id of 0-9 characters (every string padding case)."""
    return 'base_link_'[:int(rng.integers(0, 10))]


def _stamp(rng):
    """Return (t, stamp_ns): an exact stamp, or none (time from t)."""
    if rng.random() < 0.5:
        return float(rng.uniform(0, 2e9)), -1
    ns = int(rng.integers(0, 2**31 * 10**9))
    return ns * 1e-9, ns


def _array(rng, n, scale=1.0):
    return rng.normal(scale=scale, size=n)


def _samples(kind, rng, count=40):
    """Return ``count`` random core samples of ``kind`` covering empty and odd-sized fields."""
    out = []
    for i in range(count):
        t, ns = _stamp(rng)
        n = int(rng.integers(0, 6))
        if kind == 'scan':
            out.append(T.ScanSample(t, float(rng.uniform(-3, 0)), float(rng.uniform(-0.1, 0.1)),
                                    np.abs(_array(rng, n * 7, 5.0)), float(rng.uniform(0, 1)),
                                    float(rng.uniform(1, 40)), _frame(rng),
                                    None if i % 2 else np.abs(_array(rng, n * 7)),
                                    float(rng.uniform(-1e-4, 1e-4)), 0.1, ns))
        elif kind == 'joint_states':
            names = tuple(f'wheel_{k}'[:3 + k] for k in range(n))
            out.append(T.JointStateSample(t, names, _array(rng, n), _array(rng, n), ns))
        elif kind == 'cmd_vel':
            out.append(T.TwistSample(t, *_array(rng, 3), stamp_ns=ns))
        elif kind == 'cmd_vel_stamped':
            out.append(T.StampedTwistSample(t, *_array(rng, 3), ns, _frame(rng)))
        elif kind == 'fix':
            cov = _array(rng, 9).reshape(3, 3)
            if i % 3 == 0:
                cov[1, 2] = np.nan
            out.append(T.NavSatSample(t, *_array(rng, 3, 50.0), int(rng.integers(-1, 3)), cov,
                                      _frame(rng), ns))
        elif kind == 'bool':
            out.append(T.BoolSample(t, bool(i % 2), ns))
        elif kind == 'diagnostics':
            statuses = tuple(T.DiagnosticStatus(
                _frame(rng), int(rng.integers(0, 4)), 'ok'[:k], _frame(rng),
                tuple((f'k{j}'[:j + 1], f'{j * 1.5}') for j in range(k + i % 3)))
                for k in range(n))
            out.append(T.DiagnosticSample(t, statuses, ns))
        elif kind == 'tf_static':
            q = _array(rng, 4)
            out.append([T.StaticTransform(_frame(rng), _frame(rng), _array(rng, 3),
                                          q / np.linalg.norm(q), t, ns) for _ in range(n)])
    return out


KINDS = ['scan', 'joint_states', 'cmd_vel', 'cmd_vel_stamped', 'fix', 'bool', 'diagnostics',
         'tf_static']


@pytest.mark.parametrize('kind', KINDS)
def test_fast_paths_match_the_type_store(kind):
    store = codec.typestore()
    rng = np.random.default_rng(KINDS.index(kind))
    row = codec.KINDS[kind]
    assert row.fast.encode_cdr is not None and row.fast.decode is not None
    for sample in _samples(kind, rng):
        msgtype, msg = codec.to_msg(sample)
        generic = bytes(store.serialize_cdr(msg, msgtype))
        assert codec.serialize(sample) == (msgtype, generic)
        time_ns = int(rng.integers(0, 2**62))
        expected = codec.from_msg(msgtype, store.deserialize_cdr(generic, msgtype), time_ns)
        assert_same(codec.decoder(msgtype)(generic, time_ns), expected)


def test_fast_joint_state_decoder_with_efforts_and_missing_values():
    store = codec.typestore()
    ty = store.types
    hdr = ty['std_msgs/msg/Header'](ty['builtin_interfaces/msg/Time'](3, 4), 'abc')
    for pos, vel, eff in [([], [1.0, 2.0], [5.0]), ([1.0, 2.0], [], []),
                          ([1.0, 2.0], [3.0, 4.0], [5.0, 6.0, 7.0])]:
        msg = ty['sensor_msgs/msg/JointState'](hdr, ['a', 'bb'], np.array(pos),
                                               np.array(vel), np.array(eff))
        raw = bytes(store.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
        assert_same(cdr_more.joint_state_from_cdr(raw),
                    codec.from_msg('sensor_msgs/msg/JointState', msg))


def test_joint_states_sharing_a_layout_decode_as_alone():
    """The layout kept from the last JointState is used only where it holds."""
    store = codec.typestore()
    ty = store.types

    def raw_of(sec, frame, names, pos, vel):
        hdr = ty['std_msgs/msg/Header'](ty['builtin_interfaces/msg/Time'](sec, 7), frame)
        msg = ty['sensor_msgs/msg/JointState'](hdr, list(names), np.array(pos, dtype=float),
                                               np.array(vel, dtype=float), np.zeros(0))
        return bytes(store.serialize_cdr(msg, 'sensor_msgs/msg/JointState')), msg
    rng = np.random.default_rng(3)
    cases = [(1, 'b', ('l', 'r'), rng.normal(size=2), rng.normal(size=2)),
             (2, 'b', ('l', 'r'), rng.normal(size=2), rng.normal(size=2)),   # same layout
             (3, 'b', ('l', 'r'), rng.normal(size=2), []),                   # velocities gone
             (4, 'b', ('l', 'rr'), rng.normal(size=2), rng.normal(size=2)),  # a name longer
             (5, 'bb', ('l', 'r'), rng.normal(size=2), rng.normal(size=2)),  # another frame
             (6, 'bb', ('l', 'r'), rng.normal(size=3), rng.normal(size=2))]  # one more value
    for case in cases + cases:
        raw, msg = raw_of(*case)
        assert_same(cdr_more.joint_state_from_cdr(raw),
                    codec.from_msg('sensor_msgs/msg/JointState', msg))
    raw, _ = raw_of(*cases[0])
    cdr_more.joint_state_from_cdr(raw)
    with pytest.raises(Exception):  # noqa: B017 - truncated: no layout may read past its end
        cdr_more.joint_state_from_cdr(raw[:-9])


def test_big_endian_messages_take_the_generic_path():
    store = codec.typestore()
    sample = _samples('scan', np.random.default_rng(1), 2)[1]
    msgtype, msg = codec.to_msg(sample)
    raw = bytes(store.serialize_cdr(msg, msgtype, little_endian=False))
    assert raw[1] == 0
    assert_same(codec.decoder(msgtype)(raw, 0),
                codec.from_msg(msgtype, store.deserialize_cdr(raw, msgtype)))


def test_stored_definitions_match_the_type_store():
    store = codec.typestore()
    assert set(DEFINITIONS) == set(codec.TYPES)
    for msgtype in codec.TYPES:
        text, _ = store.generate_msgdef(msgtype, ros_version=2)
        assert codec.definition(msgtype) == (text, store.hash_rihs01(msgtype)), msgtype
    assert codec.definition('geometry_msgs/msg/PoseStamped')[1].startswith('RIHS01_')


def test_replay_of_supported_types_needs_no_type_store(tmp_path, fresh_python):
    """Reading and writing every supported type goes without the Jazzy type store."""
    from robot_calib.io import bags
    from test_io_bags import _samples as every_type
    path = tmp_path / 'bag'
    with bags.BagWriter(path) as w:
        for topic, sample, time_ns in every_type():
            w.write(topic, sample, time_ns)
    code = (
        'import sys\n'
        'from robot_calib.io import bags\n'
        f'msgs = list(bags.read_messages([{str(path)!r}]))\n'
        f'with bags.BagWriter({str(tmp_path / "copy")!r}) as w:\n'
        '    for m in msgs:\n'
        '        for s in m.samples:\n'
        '            w.write(m.topic, s if not hasattr(s, "parent") else [s], m.time_ns)\n'
        'print(len(msgs), "rosbags.typesys.stores.ros2_jazzy" in sys.modules)\n')
    out = fresh_python(code).split()
    assert int(out[0]) == len(every_type()) and out[1] == 'False'


def _odd_covariance(rng, i):
    """Return a 3x3 covariance of another layout or type, or with non-finite or huge values."""
    cov = rng.normal(size=(3, 3))
    return [cov, cov.astype(np.float32), cov.astype('>f8'), cov.T, cov.ravel(), cov.tolist(),
            np.where(rng.random((3, 3)) < 0.3, np.nan, cov), np.full((3, 3), 1e308),
            np.where(rng.random((3, 3)) < 0.3, -np.inf, cov), None][i % 10]


def test_whole_message_encoders_on_odd_fields():
    """Imu and Odometry encoders give rosbags' bytes whatever the fields' types and values."""
    store = codec.typestore()
    rng = np.random.default_rng(5)
    vectors = [lambda n: rng.normal(size=n), lambda n: rng.normal(size=n).astype(np.float32),
               lambda n: rng.normal(size=n).tolist(), lambda n: np.arange(n),
               lambda n: rng.normal(size=(n, 1)), lambda n: rng.normal(size=n + 1)]
    samples = []
    for i in range(300):
        vec = vectors[i % len(vectors)]
        frame = ('imu_link', 'gyro_ø', '', 'x' * (i % 11))[i % 4]
        t, ns = _stamp(rng)
        orientation = None if i % 3 == 0 else vec(4)
        samples.append(T.ImuSample(t, vec(3), vec(3), frame, orientation,
                                   _odd_covariance(rng, i + 1) if i % 3 != 1 else None,
                                   _odd_covariance(rng, i), _odd_covariance(rng, i // 10), ns))
        cov = _odd_covariance(rng, i)
        samples.append(T.OdomSample(
            t, *rng.normal(size=3), *(np.float32(v) for v in rng.normal(size=3)), frame,
            frame[::-1] + 'base', np.eye(3) if cov is None else cov, _odd_covariance(rng, i + 3),
            *rng.normal(size=3), ns, 1.0))
    for i in range(300):  # more frame ids than the encoders keep layouts of
        samples.append(T.OdomSample(i * 0.1, 1.0, 2.0, 0.3, frame_id=f'odom_{i}',
                                    child_frame_id=f'base_{i}'))
    written = 0
    for sample in samples:
        try:
            msgtype, msg = codec.to_msg(sample)
            expected = (msgtype, bytes(store.serialize_cdr(msg, msgtype)))
        except (TypeError, ValueError, IndexError):
            continue  # a sample rosbags cannot write either
        assert codec.serialize(sample) == expected
        written += 1
    assert written > 500


def test_odometry_decoder_takes_the_orientation_as_quat_normalize_does():
    """Roll, pitch, yaw and covariances are bit for bit the geometry helpers' on any quaternion."""
    from robot_calib.codec import cdr
    from robot_calib.codec.messages import POSE_IDX
    from robot_calib.core.geometry import quat_normalize, quat_to_rpy
    rng = np.random.default_rng(8)
    quats = [rng.normal(size=4), -np.abs(rng.normal(size=4)), rng.normal(size=4) * 1e-160,
             rng.normal(size=4) * 1e160, np.zeros(4), [np.nan, 0.0, 0.0, 1.0],
             [0.0, np.inf, 0.0, 1.0], [-0.0, 0.0, 0.0, -1.0]]
    for i in range(200):
        v = rng.normal(size=85)
        v[3:7] = quats[i % len(quats)] if i < 80 else rng.normal(size=4) * 10.0 ** (i % 9 - 4)
        q = (float(v[6]), float(v[3]), float(v[4]), float(v[5]))
        with np.errstate(all='ignore'):
            rpy = quat_to_rpy(quat_normalize(q))
            s = cdr._odom_sample(5, 'odom', 'base', v)
        got = (s.roll, s.pitch, s.yaw, s.x, s.y, s.z, s.vx, s.vy, s.wz, s.orientation_norm)
        expected = (*rpy, *v[[0, 1, 2, 43, 44, 48]], math.hypot(*q))
        assert np.array(got).tobytes() == np.array(expected, dtype=float).tobytes()
        assert s.pose_cov.tobytes() == v[7:43].reshape(6, 6)[POSE_IDX].tobytes()
        assert s.twist_cov.tobytes() == v[49:85].reshape(6, 6)[POSE_IDX].tobytes()


def test_odometry_pose_decoder_gives_the_full_decoders_values():
    rng = np.random.default_rng(11)
    pose_of = codec.pose_decoder('nav_msgs/msg/Odometry')
    assert codec.pose_decoder('sensor_msgs/msg/Imu') is None
    assert codec.pose_decoder('nav_msgs/msg/Odometry', ros1=True) is None
    for i in range(200):
        t, ns = _stamp(rng)
        q = rng.normal(size=4) * (0.0 if i == 7 else 1.0)      # one all-zero quaternion
        sample = T.OdomSample(t, *rng.normal(size=2) * 50, 0.0, stamp_ns=ns,
                              frame_id=_frame(rng), child_frame_id=_frame(rng))
        msgtype, raw = codec.serialize(sample)
        raw = bytearray(raw)
        cdr_pos = 4 + ((12 + raw[12] + 3) & ~3)
        child = int.from_bytes(raw[cdr_pos:cdr_pos + 4], 'little')
        off = 4 + ((cdr_pos - 4 + 4 + child + 7) & ~7)
        raw[off + 24:off + 56] = np.array([q[1], q[2], q[3], q[0]]).tobytes()
        full = codec.decoder(msgtype)(bytes(raw), 0)[0]
        assert pose_of(bytes(raw)) == (full.t, full.x, full.y, full.yaw)
