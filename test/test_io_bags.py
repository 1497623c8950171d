# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Bag I/O: round trips per storage and message type, fast decoders, real ROS 1 bags."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from robot_calib import codec
from robot_calib.codec import cdr
from robot_calib.core import types as T
from robot_calib.core.geometry import quat_from_rpy, quat_to_matrix
from robot_calib.io import bags, mcap
from robot_calib.io.convert_bag import convert_bag, main as convert_main, static_transform


def _cov(seed, n=3):
    a = np.random.default_rng(seed).normal(size=(n, n))
    return a @ a.T + np.eye(n)


def _samples():
    """Return (topic, sample, bag time ns) of every supported type."""
    t = 12.5
    ns = 12_500_000_000
    ranges = np.array([1.0, 2.5, np.nan, np.inf, 0.25], dtype=np.float32).astype(float)
    return [
        ('/imu', T.ImuSample(t, np.array([0.01, -0.02, 0.3]), np.array([0.1, 0.2, 9.81]),
                             'imu_link', None, None, _cov(1), _cov(2), ns), ns),
        ('/imu_q', T.ImuSample(t, np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 9.8]), 'i',
                               np.asarray(quat_from_rpy(0.1, -0.2, 0.3)), _cov(3), _cov(4),
                               _cov(5), ns), ns),
        ('/odom', T.OdomSample(t, 1.5, -2.0, 0.7, 0.4, 0.01, -0.2, 'odom', 'base_link',
                               _cov(6), _cov(7), 0.0, 0.0, 0.0, ns), ns),
        ('/scan', T.ScanSample(t, -1.5, 0.75, ranges, 0.125, 20.0, 'laser',  # float32-exact
                               np.array([1.0, 2.0, 3.0, 4.0, 5.0]), 2.0**-13, 0.125, ns), ns),
        ('/joint_states', T.JointStateSample(t, ('left_wheel_joint', 'right_wheel_joint'),
                                             np.array([1.0, 2.0]), np.array([0.5, -0.5]), ns),
         ns),
        ('/cmd_vel', T.TwistSample(t, 0.3, 0.0, -0.1, ns), ns),
        ('/fix', T.NavSatSample(t, 49.9, 8.9, 120.5, 1, _cov(8), 'gps', ns), ns),
        ('/tilt/fall_alert', T.BoolSample(t, True, ns), ns),
        ('/diagnostics', T.DiagnosticSample(t, (T.DiagnosticStatus(
            'wheel', 1, 'warn', 'hw', (('a', '1'), ('b', 'x'))),), ns), ns),
        ('/tf_static', [T.StaticTransform('base_link', 'imu_link', np.array([0.0, -0.3, 0.52]),
                                          np.asarray(quat_from_rpy(1.5, 0.0, -1.5)), t, ns)],
         ns),
    ]


def assert_same(a, b):
    """Assert two core samples (or lists of them) are equal, floats to 1e-12."""
    if isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y)
        return
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert x is not None and y is not None, f.name
            assert np.allclose(np.asarray(x, float), np.asarray(y, float), rtol=1e-12,
                               atol=1e-12, equal_nan=True), (f.name, x, y)
        elif isinstance(x, float):
            assert math.isclose(x, y, rel_tol=1e-12, abs_tol=1e-12), (f.name, x, y)
        elif isinstance(x, tuple) and x and dataclasses.is_dataclass(x[0]):
            for u, v in zip(x, y):
                assert_same(u, v)
        else:
            assert x == y, (f.name, x, y)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_round_trip_every_type(tmp_path, storage):
    items = _samples()
    path = tmp_path / f'rt_{storage}'
    with bags.BagWriter(path, storage=storage) as w:
        for topic, sample, ns in items:
            w.write(topic, sample, ns)
    assert (path / 'metadata.yaml').is_file()
    assert not list(tmp_path.glob('.*partial*'))
    topics = bags.list_topics([path])
    for topic, sample, _ in items:
        assert topics[topic] == (codec.msgtype_of(sample), 1)
    got = {m.topic: m for m in bags.read_messages([path])}
    assert set(got) == {t for t, _, _ in items}
    for topic, sample, ns in items:
        msg = got[topic]
        assert msg.time_ns == ns
        assert_same(msg.samples if isinstance(sample, list) else msg.samples[0], sample)


def test_writer_is_atomic_and_checks_target(tmp_path):
    path = tmp_path / 'bag'
    with pytest.raises(RuntimeError):
        with bags.BagWriter(path) as w:
            w.write('/cmd_vel', T.TwistSample(1.0, 0.1), 1_000_000_000)
            raise RuntimeError('interrupted')
    assert not path.exists()
    assert list(tmp_path.iterdir()) == []
    with bags.BagWriter(path) as w:
        w.write('/cmd_vel', T.TwistSample(1.0, 0.1), 1_000_000_000)
    with pytest.raises(bags.BagError, match='already exists'):
        bags.BagWriter(path)
    with pytest.raises(bags.BagError, match='not writable'):
        bags.BagWriter(tmp_path / 'missing' / 'bag')
    with pytest.raises(bags.BagError, match='storage'):
        bags.BagWriter(tmp_path / 'x', storage='rosbag1')


def test_compressed_mcap_reads_back(tmp_path):
    path = tmp_path / 'z'
    with bags.BagWriter(path, compress=True) as w:
        for i in range(500):
            w.write('/cmd_vel', T.TwistSample(i * 0.01, 0.5, 0.0, 0.1), 10**9 + i * 10**7)
    msgs = list(bags.read_messages([path]))
    assert len(msgs) == 500
    assert msgs[-1].samples[0].t == pytest.approx(5.99)  # unstamped: bag time 1 s + 4.99 s


def _imu_msgs():
    ty = codec.typestore().types
    out = []
    rng = np.random.default_rng(4)
    for n, frame in enumerate(['', 'a', 'ab', 'abc', 'imu', 'imu_l', 'imu_lnk', 'imu_link']):
        for with_q in (False, True):
            cov = rng.normal(size=9)
            cov[0] = abs(cov[0]) if n % 3 else -1.0
            ocov = np.zeros(9) if with_q else np.r_[-1.0, np.zeros(8)]
            q = ty['geometry_msgs/msg/Quaternion'](*rng.normal(size=4)) if with_q else \
                ty['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 0.0)
            hdr = ty['std_msgs/msg/Header'](ty['builtin_interfaces/msg/Time'](
                1_700_000_000 + n, 123_456_789 * n % 10**9), frame)
            out.append(ty['sensor_msgs/msg/Imu'](
                hdr, q, ocov, ty['geometry_msgs/msg/Vector3'](*rng.normal(size=3)), cov,
                ty['geometry_msgs/msg/Vector3'](*rng.normal(size=3)), -cov))
    return out


def _odom_msgs():
    ty = codec.typestore().types
    rng = np.random.default_rng(5)
    out = []
    for frame in ['', 'o', 'odom', 'odom_x']:
        for child in ['', 'b', 'bas', 'base_link', 'base_footprint']:
            q = rng.normal(size=4)
            pose = ty['geometry_msgs/msg/Pose'](ty['geometry_msgs/msg/Point'](*rng.normal(
                size=3)), ty['geometry_msgs/msg/Quaternion'](*q))
            twist = ty['geometry_msgs/msg/Twist'](
                ty['geometry_msgs/msg/Vector3'](*rng.normal(size=3)),
                ty['geometry_msgs/msg/Vector3'](*rng.normal(size=3)))
            hdr = ty['std_msgs/msg/Header'](ty['builtin_interfaces/msg/Time'](5, 7), frame)
            out.append(ty['nav_msgs/msg/Odometry'](
                hdr, child, ty['geometry_msgs/msg/PoseWithCovariance'](pose, rng.normal(size=36)),
                ty['geometry_msgs/msg/TwistWithCovariance'](twist, rng.normal(size=36))))
    return out


@pytest.mark.parametrize('msgtype,make,fast', [
    ('sensor_msgs/msg/Imu', _imu_msgs, cdr.imu_from_cdr),
    ('nav_msgs/msg/Odometry', _odom_msgs, cdr.odom_from_cdr)])
def test_fast_cdr_decoder_equals_generic(msgtype, make, fast):
    store = codec.typestore()
    msgs = make()
    assert len(msgs) >= 16
    for msg in msgs:
        raw = bytes(store.serialize_cdr(msg, msgtype))
        assert_same(fast(raw), codec.from_msg(msgtype, msg)[0])


@pytest.mark.parametrize('msgtype,make,fast', [
    ('sensor_msgs/msg/Imu', _imu_msgs, cdr.imu_from_ros1),
    ('nav_msgs/msg/Odometry', _odom_msgs, cdr.odom_from_ros1)])
def test_fast_ros1_decoder_equals_generic(msgtype, make, fast):
    from rosbags.typesys import get_typestore, Stores
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    ros1_header = ros1.types['std_msgs/msg/Header']
    for msg in make():
        # The same message in ROS 1 form: the header gains a seq.
        hdr = msg.header
        fields = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)
                  if f.name != '__msgtype__'}
        fields['header'] = ros1_header(17, ros1.types['builtin_interfaces/msg/Time'](
            hdr.stamp.sec, hdr.stamp.nanosec), hdr.frame_id)
        raw = bytes(ros1.serialize_ros1(ros1.types[msgtype](**fields), msgtype))
        generic = codec.from_msg(msgtype, ros1.deserialize_ros1(raw, msgtype))[0]
        assert_same(fast(raw), generic)


def test_bigendian_cdr_takes_generic_path(tmp_path):
    msg = _imu_msgs()[5]
    store = codec.typestore()
    raw = bytes(store.serialize_cdr(msg, 'sensor_msgs/msg/Imu', little_endian=False))
    path = tmp_path / 'be'
    with bags.BagWriter(path) as w:
        w.write_raw('/imu', 'sensor_msgs/msg/Imu', raw, 5)
    got = next(bags.read_messages([path]))
    assert_same(got.samples[0], codec.from_msg('sensor_msgs/msg/Imu', msg)[0])


def test_fast_path_agrees_on_a_whole_bag(tmp_path):
    path = tmp_path / 'fast'
    store = codec.typestore()
    with bags.BagWriter(path, storage='sqlite3') as w:
        for i, m in enumerate(_imu_msgs()):
            w.write_raw('/imu', 'sensor_msgs/msg/Imu', bytes(store.serialize_cdr(
                m, 'sensor_msgs/msg/Imu')), i)
        for i, m in enumerate(_odom_msgs()):
            w.write_raw('/odom', 'nav_msgs/msg/Odometry', bytes(store.serialize_cdr(
                m, 'nav_msgs/msg/Odometry')), i)
    n = 0
    with bags.BagSet([path]) as bs:
        for stream, t, raw in bs.messages():
            assert_same(stream.decode(raw, t), stream.decode_generic(raw, t))
            n += 1
    assert n == len(_imu_msgs()) + len(_odom_msgs())


def test_missing_and_bad_paths(tmp_path):
    with pytest.raises(bags.BagError, match='not found'):
        bags.list_topics([tmp_path / 'nope'])
    (tmp_path / 'empty').mkdir()
    with pytest.raises(bags.BagError, match='metadata.yaml'):
        bags.list_topics([tmp_path / 'empty'])
    junk = tmp_path / 'junk.bag'
    junk.write_bytes(b'#ROSBAG V2.0\n' + bytes(100))
    with pytest.raises(bags.BagError, match='cannot read'):
        bags.list_topics([junk])


def _write_imu_bag(path, storage, n=3000):
    with bags.BagWriter(path, storage=storage) as w:
        for i in range(n):
            ns = 10**9 + i * 10**7
            w.write('/imu', T.ImuSample(ns * 1e-9, np.array([0.0, 0.0, 0.1]),
                                        np.array([0.0, 0.0, 9.81]), stamp_ns=ns), ns)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_truncated_bag_is_a_bag_error(tmp_path, storage):
    path = tmp_path / 'cut'
    _write_imu_bag(path, storage)
    data_file = next(p for p in path.iterdir() if p.name != 'metadata.yaml')
    data = data_file.read_bytes()
    data_file.write_bytes(data[: len(data) // 2])
    with pytest.raises(bags.BagError):
        list(bags.read_messages([path]))


def test_merges_bags_in_time_order(tmp_path):
    a, b = tmp_path / 'a', tmp_path / 'b'
    with bags.BagWriter(a) as w:
        for i in range(0, 20, 2):
            w.write('/cmd_vel', T.TwistSample(i, 0.1), i * 10**9)
    with bags.BagWriter(b, storage='sqlite3') as w:
        for i in range(1, 20, 2):
            w.write('/cmd_vel', T.TwistSample(i, 0.2), i * 10**9)
    times = [m.time_ns for m in bags.read_messages([a, b])]
    assert times == [i * 10**9 for i in range(20)]


def test_read_robot_localization_test1(shared_data):
    path = shared_data / 'robot_localization' / 'test1.bag'
    topics = bags.list_topics([path])
    assert topics['/imu/data'] == ('sensor_msgs/msg/Imu', 11865)
    assert topics['/husky_velocity_controller/odom'][0] == 'nav_msgs/msg/Odometry'
    errors = {}
    n = {}
    last = -1
    with bags.BagSet([path]) as bs:
        for stream, t, raw in bs.messages():
            assert t >= last
            last = t
            n[stream.topic] = n.get(stream.topic, 0) + 1
            if stream.msgtype in ('sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry') \
                    and n[stream.topic] < 300:
                assert_same(stream.decode(raw, t), stream.decode_generic(raw, t))
    assert n == {'/imu/data': 11865, '/husky_velocity_controller/odom': 3952, '/fix': 989}
    msgs = list(bags.read_messages([path], topics=['/imu/data'], errors=errors))
    assert not errors
    imu = msgs[0].samples[0]
    assert imu.frame_id == 'imu_link'
    # Level robot: gravity on the IMU's y axis (mounted rotated, see bags/README.md).
    assert np.linalg.norm(imu.accel) == pytest.approx(9.8, abs=0.3)


def test_read_robot_pose_ekf_gps_data(shared_data):
    path = shared_data / 'robot_pose_ekf' / 'gps_data.bag'
    errors = {}
    msgs = list(bags.read_messages([path], topics=['/imu/data', '/encoder', '/fix', '/tf'],
                                   errors=errors))
    assert not errors
    kinds = {m.topic for m in msgs}
    assert kinds == {'/imu/data', '/encoder', '/fix'}  # /tf is ROS 1 tf/tfMessage: not read
    imu = [m.samples[0] for m in msgs if m.topic == '/imu/data']
    assert len(imu) == 316
    # This bag's accelerometer is in g, not m/s^2 (documented in shared/data/README.md).
    assert np.median([np.linalg.norm(s.accel) for s in imu]) == pytest.approx(1.0, abs=0.1)
    enc = [m.samples[0] for m in msgs if m.topic == '/encoder']
    assert len(enc) == 380 and all(isinstance(s, T.OdomSample) for s in enc)


def test_convert_test1_slice(shared_data, tmp_path):
    src = shared_data / 'robot_localization' / 'test1.bag'
    dst = tmp_path / 'husky'
    tf = static_transform(0, -0.3, 0.52, -1.570796327, 0, 1.570796327, 'base_link', 'imu_link')
    counts = convert_bag(src, dst, {'/imu/data': '/imu',
                                    '/husky_velocity_controller/odom': '/odom'},
                         ['/imu', '/odom', '/fix'], [tf], duration=10.0)
    assert counts['/tf_static'] == 1 and 250 < counts['/imu'] < 350
    msgs = list(bags.read_messages([dst]))
    assert msgs[0].topic == '/tf_static'
    got = msgs[0].samples[0]
    assert (got.parent, got.child) == ('base_link', 'imu_link')
    imu = [m.samples[0] for m in msgs if m.topic == '/imu']
    g = quat_to_matrix(got.rotation) @ np.mean([s.accel for s in imu], axis=0)
    assert g[2] == pytest.approx(9.8, abs=0.3) and abs(g[0]) < 0.5 and abs(g[1]) < 0.5
    # Field for field: the converted IMU equals the original.
    orig = next(m for m in bags.read_messages([src], topics=['/imu/data']))
    assert_same(imu[0], orig.samples[0])
    assert convert_main([str(src), str(tmp_path / 'bad'), '--rename', 'nonsense']) == 2


def test_shipped_sample_bag(repo_root):
    path = repo_root / 'bags' / 'husky_test1'
    topics = bags.list_topics([path])
    assert topics['/imu'] == ('sensor_msgs/msg/Imu', 11865)
    assert topics['/odom'] == ('nav_msgs/msg/Odometry', 3952)
    assert topics['/tf_static'][1] == 1
    size = sum(p.stat().st_size for p in Path(path).iterdir())
    assert size < 5 * 2**20


@pytest.mark.parametrize('compress', [False, True])
@pytest.mark.parametrize('shuffle', ['none', 'swap', 'random'])
def test_fast_mcap_reader_matches_rosbags(tmp_path, compress, shuffle):
    from rosbags.rosbag2 import Reader
    path = tmp_path / 'multi'
    rng = np.random.default_rng(1)
    times = np.arange(6000) * 5_000_000 + 10**9
    if shuffle == 'swap':  # out of order inside one chunk: the fast reader sorts it
        times[[10, 11]] = times[[11, 10]]
    if shuffle == 'random':  # chunks overlapping in time: rosbags merges them
        times = times + rng.integers(0, 400_000_000, times.size)
    with bags.BagWriter(path, compress=compress) as w:
        for i, ns in enumerate(times):
            w.write('/imu', T.ImuSample(ns * 1e-9, rng.normal(size=3), rng.normal(size=3),
                                        stamp_ns=int(ns)), int(ns))
            if i % 10 == 0:
                w.write('/cmd_vel', T.TwistSample(0.0, i * 0.001), int(ns))
    with Reader(path) as reader:
        assert len(reader.storage.storages[0].chunks) > 1  # several chunks
        expected = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    with bags.BagSet([path]) as bs:
        fast = mcap.messages(bs._readers[0][0], [s.conn for s in bs.streams],
                             {id(s.conn): s for s in bs.streams})
        assert fast is not None  # overlapping chunks too: merged as rosbags merges them
        got = [(s.topic, t, bytes(raw)) for s, t, raw in bs.messages()]
        only_imu = [(s.topic, t) for s, t, _ in bs.messages([bs.streams[0]])]
    assert [g[:2] for g in got] == [e[:2] for e in expected]
    assert got == expected
    assert only_imu == [e[:2] for e in expected if e[0] == bs.streams[0].topic]


def test_fast_encoders_are_byte_identical():
    rng = np.random.default_rng(9)
    samples = []
    for i in range(120):
        frame = 'imu_link'[:i % 9]
        samples.append(T.ImuSample(
            float(rng.uniform(0, 1e9)), rng.normal(size=3), rng.normal(size=3), frame,
            None if i % 2 else rng.normal(size=4), None if i % 3 else _cov(i),
            None if i % 5 == 0 else _cov(i + 1), _cov(i) if i % 4 else np.full((3, 3), np.nan),
            -1 if i % 7 else int(rng.integers(0, 2**60))))
        c = _cov(i + 2)
        if i % 6 == 0:
            c[0, 1] = np.nan
        samples.append(T.OdomSample(
            float(rng.uniform(0, 1e9)), *rng.normal(size=6), 'odom'[:i % 5],
            'base_link'[:i % 10], c, _cov(i + 3), *rng.normal(size=3),
            stamp_ns=-1 if i % 3 else int(rng.integers(0, 2**60))))
    store = codec.typestore()
    for s in samples:
        msgtype, msg = codec.to_msg(s)
        assert codec.serialize(s) == (msgtype, bytes(store.serialize_cdr(msg, msgtype)))


def test_bare_mcap_file(tmp_path):
    folder = tmp_path / 'bag'
    _write_imu_bag(folder, 'mcap', n=50)
    bare = tmp_path / 'copy.mcap'
    bare.write_bytes(next(folder.glob('*.mcap')).read_bytes())
    assert bags.list_topics([bare]) == bags.list_topics([folder])
    a = [(m.topic, m.time_ns) for m in bags.read_messages([bare])]
    b = [(m.topic, m.time_ns) for m in bags.read_messages([folder])]
    assert a == b and len(a) == 50
    # A file inside a bag folder means the folder.
    assert len(list(bags.read_messages([next(folder.glob('*.mcap'))]))) == 50
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'not an mcap file')
    with pytest.raises(bags.BagError, match='cannot read'):
        bags.list_topics([junk])
    lone_db = tmp_path / 'lone.db3'
    lone_db.write_bytes(b'')
    with pytest.raises(bags.BagError, match='metadata.yaml'):
        bags.list_topics([lone_db])


def test_batch_decoder_equals_per_message(tmp_path):
    store = codec.typestore()
    msgs = _imu_msgs()
    raws = [bytes(store.serialize_cdr(m, 'sensor_msgs/msg/Imu')) for m in msgs]
    # Same layout (same frame id): decoded together, equal to one by one.
    same = [r for m, r in zip(msgs, raws) if m.header.frame_id == 'imu_link']
    assert len(same) == 2
    for got, raw in zip(cdr.imu_batch_from_cdr(same * 5), same * 5):
        assert_same(got, [cdr.imu_from_cdr(raw)])
    # Empty frame id, covariances marked unknown (-1), with and without orientation.
    unknown = [r for m, r in zip(msgs, raws) if m.header.frame_id == '']
    assert len(unknown) == 2 and np.isnan(cdr.imu_from_cdr(unknown[0]).gyro_cov).all()
    for got, raw in zip(cdr.imu_batch_from_cdr(unknown * 3), unknown * 3):
        assert_same(got, [cdr.imu_from_cdr(raw)])
        assert_same(got, codec.deserialize('sensor_msgs/msg/Imu', raw))
    with pytest.raises(ValueError):
        cdr.imu_batch_from_cdr(raws)  # frame ids differ: the caller decodes one by one
    be = bytes(store.serialize_cdr(msgs[15], 'sensor_msgs/msg/Imu', little_endian=False))
    with pytest.raises(ValueError):
        cdr.imu_batch_from_cdr([raws[15], be])
    # Through a bag: mixed layouts, a big-endian and a cut message, small blocks.
    path = tmp_path / 'mixed'
    with bags.BagWriter(path) as w:
        for i in range(300):
            raw = raws[i % len(raws)] if i % 7 else same[i % 2]
            if i == 100:
                raw = be
            if i == 200:
                raw = raw[:40]
            w.write_raw('/imu', 'sensor_msgs/msg/Imu', raw, 10**9 + i)
    with bags.BagSet([path]) as bs:
        plain = [(s.topic, t, raw) for s, t, raw in bs.messages()]
        for (stream, t, raw, samples), (_, t2, raw2) in zip(bs.decoded(block=16), plain):
            assert t == t2 and raw == raw2
            if t == 10**9 + 200:
                assert samples is None
            else:
                assert_same(samples, stream.decode_generic(raw, t))
    errors = {}
    assert len(list(bags.read_messages([path], errors=errors))) == 299
    assert errors == {'/imu': 1}


@pytest.mark.parametrize('compress', [False, True])
def test_direct_mcap_records_are_byte_identical(tmp_path, compress):
    rng = np.random.default_rng(3)
    items = []
    for i in range(4000):  # several chunks, three topics, out-of-order times
        ns = 10**9 + i * 5_000_000 + int(rng.integers(0, 20_000_000))
        items.append(('/imu', T.ImuSample(ns * 1e-9, rng.normal(size=3), rng.normal(size=3),
                                          stamp_ns=ns), ns))
        if i % 4 == 0:
            items.append(('/odom', T.OdomSample(ns * 1e-9, *rng.normal(size=3), stamp_ns=ns),
                          ns))
        if i % 50 == 0:
            items.append(('/alert', T.BoolSample(ns * 1e-9, bool(i % 100)), ns))
    files = []
    for fast in (True, False):
        (tmp_path / str(fast)).mkdir()
        writer = bags.BagWriter(tmp_path / str(fast) / 'bag', compress=compress)
        writer.fast_mcap = fast
        with writer as w:
            assert (w._mcap is not None) == fast
            for topic, sample, ns in items:
                w.write(topic, sample, ns)
        files.append({p.name: p.read_bytes() for p in (tmp_path / str(fast) / 'bag').iterdir()})
    assert files[0] == files[1]
    assert len(list(bags.read_messages([tmp_path / 'True' / 'bag']))) == len(items)


@pytest.mark.parametrize('fast', [False, True])
def test_raw_writer_writes_what_write_raw_writes(tmp_path, fast):
    """A topic's raw writer adds its connection at its first message and the same records."""
    rng = np.random.default_rng(4)
    items = []
    for i in range(3000):
        ns = 10**9 + i * 5_000_000 + int(rng.integers(0, 20_000_000))
        sample = (T.ImuSample(ns * 1e-9, rng.normal(size=3), rng.normal(size=3), stamp_ns=ns)
                  if i % 3 else T.OdomSample(ns * 1e-9, *rng.normal(size=3), stamp_ns=ns))
        items.append(('/a' if i % 3 else 'b', *codec.serialize(sample), ns))
    files = []
    for how in ('write_raw', 'raw_writer'):
        (tmp_path / how).mkdir()
        writer = bags.BagWriter(tmp_path / how / 'bag', compress=True)
        writer.fast_mcap = fast
        with writer as w:
            writers = {}
            for topic, msgtype, data, ns in items:
                if how == 'write_raw':
                    w.write_raw(topic, msgtype, data, ns)
                else:
                    if topic not in writers:
                        writers[topic] = w.raw_writer(topic, msgtype)
                    writers[topic](data, ns)
            with pytest.raises(bags.BagError, match='two types'):
                w.raw_writer('/b', 'sensor_msgs/msg/Imu')(items[1][2], 10**9)
            counts = (w.count, list(w.counts.items()))
        files.append(({p.name: p.read_bytes() for p in (tmp_path / how / 'bag').iterdir()},
                      counts))
    assert files[0] == files[1]
    assert files[0][1] == (3000, [('/b', 1000), ('/a', 2000)])


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_receive_time_no_bag_can_hold_is_refused_and_the_bag_stays_whole(tmp_path, storage):
    path = tmp_path / 'b'
    odom = 'nav_msgs/msg/Odometry'
    with bags.BagWriter(path, storage=storage) as w:
        w.write('/odom', T.OdomSample(1.0, 0.0, 0.0, 0.0, stamp_ns=10**9))
        with pytest.raises(bags.BagError, match='receive time'):
            w.write('/odom', T.OdomSample(-1.0, 0.0, 0.0, 0.0))
        _, raw = codec.serialize(T.OdomSample(1.5, 0.0, 0.0, 0.0))
        fast = w.raw_writer('/odom', odom)
        for bad in (-5, 2**63):
            with pytest.raises(bags.BagError, match='receive time'):
                fast(raw, bad)
        fast(raw, 15 * 10**8)
        w.write('/odom', T.OdomSample(2.0, 0.0, 0.0, 0.0, stamp_ns=2 * 10**9))
    assert [m.time_ns for m in bags.read_messages([path])] == [10**9, 15 * 10**8, 2 * 10**9]
