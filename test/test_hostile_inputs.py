# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Hostile inputs replayed end to end: each is rejected with its reason counted, or refused.

Small simulated bags are rewritten sample by sample into hostile variants in
``tmp_path`` (clock jumps, stray stamps, bursts, absurd values, NaN, degenerate
and mirrored scans, corrupt mcap chunks) and replayed through
:func:`robot_calib.replay.replay` or the command line.
"""

import dataclasses
import json
import math
import struct
import zlib

import numpy as np
import pytest

from robot_calib.cli import main
from robot_calib.codec import cdr
from robot_calib.core import types as T
from robot_calib.io import bags
from robot_calib.pipelines import validation as V
from robot_calib.replay import replay
from robot_calib.sim.engine import simulate
from rosbags.rosbag2.storage_mcap import decompress

YEARS = 3 * 365 * 86400 * 10**9
"""A clock jump of three years (ns)."""


def rewrite(src, dst, change):
    """
    Copy bag ``src`` to ``dst`` sample by sample.

    ``change(topic, sample, time_ns)`` returns the ``(topic, sample or CDR bytes,
    time_ns)`` to write instead.
    """
    with bags.BagSet([src]) as bag, bags.BagWriter(dst) as out:
        for stream, time_ns, _, samples in bag.decoded():
            if stream.msgtype == 'tf2_msgs/msg/TFMessage':
                out.write(stream.topic, samples, time_ns)
                continue
            for sample in samples:
                for topic, new, new_ns in change(stream.topic, sample, time_ns):
                    if isinstance(new, bytes):
                        out.write_raw(topic, stream.msgtype, new, new_ns)
                    else:
                        out.write(topic, new, new_ns)


def shifted(sample, dns):
    """Return ``sample`` with its stamp moved by ``dns`` ns."""
    ns = T.stamp_of(sample.t, sample.stamp_ns) + dns
    return dataclasses.replace(sample, t=ns * 1e-9, stamp_ns=ns)


def run(bag, out, nodes, **kwargs):
    """Replay ``bag`` into ``out`` and return the summary."""
    return replay(bag, out, nodes=nodes, progress=False, **kwargs)


def odom_outputs(out, topic):
    """Return the (t, x, y, yaw) rows of an odometry output topic of a replay."""
    return np.array([(m.time_ns * 1e-9, s.x, s.y, s.yaw)
                     for m in bags.read_messages([out / 'output.mcap'], [topic])
                     for s in m.samples])


@pytest.fixture(scope='module')
def drive(tmp_path_factory):
    """Return a 20 s simulated drive bag (imu, odom, joint_states, scan) and its replay."""
    folder = tmp_path_factory.mktemp('drive')
    simulate('drive', folder / 'bag', seed=2, duration=20.0)
    clean = run(folder / 'bag', folder / 'clean', ['odometry_fusion', 'tilt_detection'])
    return folder / 'bag', clean


# -- clock jumps ----------------------------------------------------------------------------
@pytest.mark.parametrize('direction', ['ahead', 'back'])
def test_a_clock_jump_is_never_integrated_and_loses_nothing(drive, tmp_path, direction):
    bag, clean = drive
    with bags.BagSet([bag]) as b:
        middle = b.start_ns + 10 * 10**9

    def jump(topic, sample, time_ns):
        if direction == 'ahead' and time_ns > middle:       # clock and recorder jump ahead
            return [(topic, shifted(sample, YEARS), time_ns + YEARS)]
        if direction == 'back' and time_ns <= middle:       # the sensor clock is reset back
            return [(topic, shifted(sample, 3600 * 10**9), time_ns)]
        return [(topic, sample, time_ns)]

    rewrite(bag, tmp_path / 'bag', jump)
    nodes = ['odometry_fusion', 'tilt_detection', 'gyro_line_calibration',
             'loop_closure_correction', 'wheel_odometry_calibration']
    summary = run(tmp_path / 'bag', tmp_path / 'out', nodes)
    for name in nodes:
        for key, counts in summary['nodes'][name]['inputs'].items():
            if counts.get('rejected_joint_states_preferred') == counts['read']:
                continue            # odometry turned away unread: joint states drive the wheels
            if key in ('imu', 'odom', 'scan', 'joint_states'):
                assert counts['clock_jumps'] == 1, (name, key, counts)
                # every sample used, or turned down by the method (another wheel source)
                assert counts.get('accepted', 0) + counts.get('rejected_other_wheel_source_used',
                                                              0) == counts['read'], \
                    (name, key, counts)
    fused = odom_outputs(tmp_path / 'out', '/odometry/fused')
    assert np.abs(fused[:, 1:3]).max() < 50.0           # was 1e8 m ahead, 0 outputs back
    end, end_clean = (s['nodes']['odometry_fusion']['final_pose'] for s in (summary, clean))
    assert math.hypot(end['x'] - end_clean['x'], end['y'] - end_clean['y']) < 0.2
    assert summary['nodes']['tilt_detection']['alerts'] == 0
    for topic in ('/gyro_line/odom', '/loop_closure/odom'):
        poses = odom_outputs(tmp_path / 'out', topic)
        assert len(poses) == summary['topics']['/odom']['count']
        assert np.abs(poses[:, 1:3]).max() < 50.0, topic
    result = summary['nodes']['wheel_odometry_calibration']['result']
    assert all(math.isfinite(v) for v in result.values() if isinstance(v, float))


def test_one_stray_stamp_years_ahead_is_rejected_alone(drive, tmp_path):
    bag, clean = drive
    seen = {}

    def stray(topic, sample, time_ns):
        seen[topic] = seen.get(topic, 0) + 1
        if topic in ('/imu', '/odom') and seen[topic] == 500:
            return [(topic, shifted(sample, YEARS), time_ns)]
        return [(topic, sample, time_ns)]

    rewrite(bag, tmp_path / 'bag', stray)
    summary = run(tmp_path / 'bag', tmp_path / 'out', ['odometry_fusion', 'tilt_detection'])
    for name, key in (('odometry_fusion', 'imu'), ('odometry_fusion', 'odom'),
                      ('tilt_detection', 'imu')):
        counts = summary['nodes'][name]['inputs'][key]
        assert counts['rejected_clock_jump'] == 1 and counts['rejected'] == 1, counts
        assert counts['accepted'] == counts['read'] - 1       # was: every later one rejected
    end, end_clean = (s['nodes']['odometry_fusion']['final_pose'] for s in (summary, clean))
    assert math.hypot(end['x'] - end_clean['x'], end['y'] - end_clean['y']) < 0.02


def test_fusion_seed_mode_does_not_integrate_a_gap_either(drive, tmp_path):
    bag, _ = drive
    with bags.BagSet([bag]) as b:
        middle = b.start_ns + 10 * 10**9
    rewrite(bag, tmp_path / 'bag', lambda topic, s, ns: [
        (topic, shifted(s, YEARS), ns + YEARS) if ns > middle else (topic, s, ns)])
    run(tmp_path / 'bag', tmp_path / 'out', ['odometry_fusion'],
        overrides=['odometry_fusion.mode=seed'])
    fused = odom_outputs(tmp_path / 'out', '/odometry/fused')
    assert np.isfinite(fused).all() and np.abs(fused[:, 1:3]).max() < 50.0  # was 1e213 m


# -- rates ----------------------------------------------------------------------------------
def test_a_burst_of_imu_copies_at_1_mhz_is_rejected_by_rate(drive, tmp_path):
    bag, clean = drive
    burst = 200_000

    done = []

    def copies(topic, sample, time_ns):
        out = [(topic, sample, time_ns)]
        if topic == '/imu' and not done and sample.t - clean['start_time'] > 8.0:
            done.append(sample)  # one upright reading, copied at 1 us stamps
            out += [(topic, shifted(sample, 1000 * (i + 1)), time_ns + 1000 * (i + 1))
                    for i in range(burst)]
        return out

    rewrite(bag, tmp_path / 'bag', copies)
    summary = run(tmp_path / 'bag', tmp_path / 'out', ['tilt_detection'])
    node = summary['nodes']['tilt_detection']
    # at most the plausible rate over the burst's 0.2 s (plus the bucket) gets through
    allowed = V.MAX_RATE['imu'] * (burst * 1e-6 + V.RATE_BURST) + 1
    assert node['inputs']['imu']['rejected_implausible_rate'] >= burst - allowed
    assert node['alerts'] == 0
    assert abs(node['max_tilt_deg'] - clean['nodes']['tilt_detection']['max_tilt_deg']) < 0.5


@pytest.mark.parametrize('kind, rate', [('imu', 200.0), ('imu', 285.714), ('imu', 2000.0),
                                        ('imu', 4000.0), ('odom', 1000.0),
                                        ('joint_states', 1000.0), ('scan', 50.0)])
def test_legitimate_rates_are_never_rejected_even_when_stamps_bunch(kind, rate):
    guard = V.RateGuard(kind)
    rng = np.random.default_rng(0)
    # stamped at reception: packets of 4 samples arrive together, with jitter
    i = np.arange(20000)
    t = (i // 4) * 4 / rate + rng.uniform(0.0, 1e-5, i.size) + i * 1e-9
    t = np.maximum.accumulate(t)
    assert all(guard.allow(float(x)) for x in t)
    burst = V.RateGuard(kind)
    allowed = sum(burst.allow(1.0 + k * 1e-6) for k in range(1000))
    assert allowed <= max(V.MAX_RATE[kind] * V.RATE_BURST, 5) + V.MAX_RATE[kind] * 1e-3 + 1


def test_a_simulated_2_khz_imu_is_kept(tmp_path):
    simulate('bumpy_drive', tmp_path / 'bag', seed=1, duration=3.0,
             overrides={'imu.rate': 2000.0})
    summary = run(tmp_path / 'bag', tmp_path / 'out', ['tilt_detection'])
    counts = summary['nodes']['tilt_detection']['inputs']['imu']
    assert counts['read'] > 5900 and counts['accepted'] == counts['read']


# -- absurd and non-finite values ------------------------------------------------------------
def _odom_raw(sample, quaternion):
    """Serialize an odometry sample with its quaternion (x, y, z, w) replaced."""
    raw = bytearray(cdr.odom_to_cdr(sample))
    struct.pack_into('<4d', raw, len(raw) - 85 * 8 + 3 * 8, *quaternion)
    return bytes(raw)


BAD_VALUES = {
    '/imu': [
        ('implausible', lambda s: dataclasses.replace(s, gyro=np.array([3e5, 0.0, 0.0]))),
        ('implausible', lambda s: dataclasses.replace(s, accel=np.array([0.0, 0.0, 6e4]))),
        ('implausible', lambda s: dataclasses.replace(
            s, orientation=np.array([6.8e229, 0.0, 0.0, 0.0]), orientation_cov=np.zeros((3, 3)))),
        ('non_finite', lambda s: dataclasses.replace(s, accel=np.array([0.0, math.nan, 9.8]))),
    ],
    '/odom': [
        ('implausible', lambda s: dataclasses.replace(s, vx=4e3)),
        ('implausible', lambda s: dataclasses.replace(s, x=3e12)),
        ('implausible', lambda s: dataclasses.replace(s, wz=-900.0)),
        ('implausible', lambda s: _odom_raw(s, (0.0, 0.0, 1e30, 1.0))),
        ('non_finite', lambda s: _odom_raw(s, (0.0, 0.0, math.nan, 1.0))),
    ],
    '/joint_states': [
        ('implausible', lambda s: dataclasses.replace(s, velocity=np.full(len(s.names), 5e6))),
        ('non_finite', lambda s: dataclasses.replace(s, position=np.full(len(s.names), math.inf))),
    ],
    '/scan': [
        ('implausible', lambda s: dataclasses.replace(s, range_max=1e9)),
        ('implausible', lambda s: dataclasses.replace(s, angle_increment=0.5)),
        ('implausible', lambda s: dataclasses.replace(s, time_increment=3.0)),
        ('non_finite', lambda s: dataclasses.replace(s, range_min=math.nan)),
    ],
}


def test_absurd_values_are_rejected_as_implausible_and_never_used(drive, tmp_path):
    bag, clean = drive
    seen = {}

    def damage(topic, sample, time_ns):
        seen[topic] = n = seen.get(topic, 0) + 1
        cases = BAD_VALUES.get(topic, [])
        if n % 20 == 10 and cases:
            return [(topic, cases[(n // 20) % len(cases)][1](sample), time_ns)]
        return [(topic, sample, time_ns)]

    rewrite(bag, tmp_path / 'bag', damage)
    nodes = ['odometry_fusion', 'tilt_detection', 'gyro_line_calibration',
             'wheel_odometry_calibration']
    summary = run(tmp_path / 'bag', tmp_path / 'out', nodes)
    expected = {}
    for topic, cases in BAD_VALUES.items():
        n = seen[topic]
        for k in range(10, n + 1, 20):
            reason = cases[(k // 20) % len(cases)][0]
            expected.setdefault(topic, {}).setdefault(reason, 0)
            expected[topic][reason] += 1
    for name in nodes:
        node = summary['nodes'][name]
        for key, topic in node['input_topics'].items():
            counts = node['inputs'][key]
            if counts.get('rejected_joint_states_preferred') == counts.get('read'):
                continue            # odometry turned away unread: joint states drive the wheels
            for reason, count in expected.get(topic, {}).items():
                assert counts.get('rejected_' + reason) == count, (name, key, counts)
    fused = odom_outputs(tmp_path / 'out', '/odometry/fused')
    assert np.isfinite(fused).all() and np.abs(fused[:, 1:3]).max() < 50.0
    end, end_clean = (s['nodes']['odometry_fusion']['final_pose'] for s in (summary, clean))
    assert math.hypot(end['x'] - end_clean['x'], end['y'] - end_clean['y']) < 0.3
    assert summary['nodes']['tilt_detection']['alerts'] == 0


# -- scans ----------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def vacuum(tmp_path_factory):
    """Return a 60 s robot-vacuum bag with an undistorted lidar (beam times do not matter)."""
    folder = tmp_path_factory.mktemp('vacuum')
    simulate('vacuum', folder / 'bag', seed=1, duration=60.0,
             overrides={'lidar.motion_distortion': False})
    return folder / 'bag'


def test_scans_with_zero_angle_increment_are_rejected(vacuum, tmp_path):
    rewrite(vacuum, tmp_path / 'bag', lambda topic, s, ns: [
        (topic, dataclasses.replace(s, angle_increment=0.0) if topic == '/scan' else s, ns)])
    nodes = ['gyro_line_calibration', 'loop_closure_correction']
    summary = run(tmp_path / 'bag', tmp_path / 'out', nodes)
    for name in nodes:
        counts = summary['nodes'][name]['inputs']['scan']
        assert counts['rejected_implausible'] == counts['read'] > 500
    assert summary['nodes']['gyro_line_calibration']['corrections'] == 0   # was 154
    assert summary['nodes']['loop_closure_correction']['closures_accepted'] == 0


def mirrored(scan, exact_times=True):
    """
    Return the same scan from a lidar listing its beams clockwise (negative increment).

    With ``exact_times`` the beams keep their measurement times: the stamp moves to the
    beam listed first and ``time_increment`` turns negative.
    """
    n = scan.ranges.size
    change = {'angle_min': scan.angle_min + scan.angle_increment * (n - 1),
              'angle_increment': -scan.angle_increment, 'ranges': scan.ranges[::-1].copy()}
    if exact_times:
        ns = scan.stamp_ns + int(round(scan.time_increment * (n - 1) * 1e9))
        change.update(t=ns * 1e-9, stamp_ns=ns, time_increment=-scan.time_increment)
    return dataclasses.replace(scan, **change)


def test_a_mirrored_lidar_gives_the_same_corrections(vacuum, tmp_path):
    rewrite(vacuum, tmp_path / 'bag', lambda topic, s, ns: [
        (topic, mirrored(s, exact_times=False) if topic == '/scan' else s, ns)])
    nodes = ['gyro_line_calibration', 'loop_closure_correction']
    plain = run(vacuum, tmp_path / 'plain', nodes)
    mirror = run(tmp_path / 'bag', tmp_path / 'mirror', nodes)
    # the same points in the other order: only the rounding, and which point of a voxel
    # loop closure's thinning keeps first, differ
    for name, count, yaw_deg in (('gyro_line_calibration', 'corrections', 0.1),
                                 ('loop_closure_correction', 'closures_accepted', 0.3)):
        a, b = plain['nodes'][name], mirror['nodes'][name]
        assert a[count] > 10 and abs(b[count] - a[count]) <= 0.05 * a[count], name
        assert b['final_pose'][:2] == pytest.approx(a['final_pose'][:2], abs=0.01), name
        assert b['final_pose'][2] == pytest.approx(a['final_pose'][2],
                                                   abs=math.radians(yaw_deg)), name


def test_a_mirrored_lidar_gives_the_same_wheel_calibration(tmp_path):
    simulate('diff_segments', tmp_path / 'bag', seed=1, duration=60.0)
    rewrite(tmp_path / 'bag', tmp_path / 'mirror_bag', lambda topic, s, ns: [
        (topic, mirrored(s), max(ns, s.stamp_ns)) if topic == '/scan' else (topic, s, ns)])
    results = [run(b, tmp_path / f'out{i}', ['wheel_odometry_calibration'])[
        'nodes']['wheel_odometry_calibration']['result']
        for i, b in enumerate((tmp_path / 'bag', tmp_path / 'mirror_bag'))]
    plain, mirror = results
    assert abs(mirror['segments_used'] - plain['segments_used']) <= 2   # was 54 of 67
    for key in ('left_wheel_radius', 'right_wheel_radius', 'track_width', 'lidar_x', 'lidar_y',
                'lidar_yaw'):
        std = math.hypot(plain[key + '_std'], mirror[key + '_std'])
        assert abs(mirror[key] - plain[key]) < 2.0 * std, key


# -- corrupt mcap chunks --------------------------------------------------------------------
def _chunks(bag):
    """Return the chunk index of a one-file mcap bag (folder or bare file)."""
    with bags.BagSet([bag]) as b:
        reader = b._readers[0][0]
        mcap = reader.mcap if hasattr(reader, 'mcap') else reader.storage.storages[0]
        return list(mcap.chunks)


def corrupt_chunk(bag, index=1):
    """Flip one bit inside chunk ``index`` of a one-file mcap bag (its CRC fails); return it."""
    mcap = next(bag.glob('*.mcap'))
    chunk = _chunks(bag)[index]
    data = bytearray(mcap.read_bytes())
    data[chunk.chunk_start_offset + 49 + len(chunk.compression) + chunk.compressed_size // 10] ^= 4
    mcap.write_bytes(bytes(data))
    return chunk


@pytest.mark.parametrize('compress', [False, True])
def test_every_chunk_we_write_carries_its_crc(tmp_path, compress):
    simulate('drive', tmp_path / 'bag', seed=1, duration=8.0, compress=compress)
    data = next((tmp_path / 'bag').glob('*.mcap')).read_bytes()
    chunks = _chunks(tmp_path / 'bag')
    assert len(chunks) >= 2
    for c in chunks:
        crc = struct.unpack_from('<I', data, c.chunk_start_offset + 33)[0]
        start = c.chunk_start_offset + 9 + 40 + len(c.compression)
        records = data[start:start + c.compressed_size]
        records = decompress(records, c.compression, c.uncompressed_size, 0)
        assert crc == zlib.crc32(records) != 0
    summary = run(tmp_path / 'bag', tmp_path / 'out', ['tilt_detection'])
    out_data = (tmp_path / 'out' / 'output.mcap').read_bytes()
    out_chunks = _chunks(tmp_path / 'out' / 'output.mcap')
    assert summary['corrupt_chunks'] == [] and out_chunks
    assert all(struct.unpack_from('<I', out_data, c.chunk_start_offset + 33)[0]
               for c in out_chunks)


@pytest.mark.parametrize('compress', [False, True])
def test_a_corrupt_chunk_is_skipped_whole_and_reported(tmp_path, compress, capsys):
    simulate('fusion_drive', tmp_path / 'bag', seed=1, duration=30.0, compress=compress)
    chunk = corrupt_chunk(tmp_path / 'bag')
    out = tmp_path / 'out'
    code = main(['replay', str(tmp_path / 'bag'), '--out', str(out), '--nodes',
                 'odometry_fusion,tilt_detection', '--no-progress'])
    err = capsys.readouterr().err
    assert code == 0 and 'corrupt mcap chunk' in err and len(err.strip().splitlines()) == 1
    summary = json.loads((out / 'summary.json').read_text())
    [bad] = summary['corrupt_chunks']
    assert bad['offset'] == chunk.chunk_start_offset and bad['messages']['/imu'] > 100
    assert '**Corrupt:** 1 chunk(s)' in (out / 'report.md').read_text()
    lost = bad['messages']['/imu']
    imu = summary['nodes']['tilt_detection']['inputs']['imu']
    assert imu['read'] == imu['accepted'] == summary['topics']['/imu']['count'] - lost
    fused = odom_outputs(out, '/odometry/fused')
    assert np.isfinite(fused).all() and np.abs(fused[:, 1:]).max() < 50.0
    inside = (fused[:, 0] > bad['start_time']) & (fused[:, 0] < bad['end_time'])
    assert not inside.any()                             # nothing from the corrupt chunk
    assert len(fused) > 0.5 * summary['topics']['/odom']['count']


# -- parameters -----------------------------------------------------------------------------
@pytest.mark.parametrize('value', ['nan,0,0', '0,inf,0', '0,0', '0,0,0,0', 'a,b,c'])
def test_list_parameters_with_bad_elements_or_length_are_refused(drive, tmp_path, capsys,
                                                                 value):
    bag, _ = drive
    out = tmp_path / 'out'
    code = main(['replay', str(bag), '--out', str(out), '--nodes', 'tilt_detection', '--set',
                 f'tilt_detection.mounting_rpy={value}'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'mounting_rpy' in err[0], err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith('.')]


def test_list_parameters_are_checked_in_files_and_in_the_simulator(drive, tmp_path, capsys):
    bag, _ = drive
    params = tmp_path / 'params.yaml'
    params.write_text('odometry_fusion:\n  ros__parameters:\n    imu_rpy: [.inf, 0.0, 0.0]\n')
    code = main(['replay', str(bag), '--out', str(tmp_path / 'out'), '--nodes',
                 'odometry_fusion', '--params', str(params)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'imu_rpy' in err[0] and 'finite' in err[0]
    code = main(['simulate', 'drive', '--out', str(tmp_path / 'sim'), '--set',
                 'imu.gyro_bias=0.1,0.2'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and 'gyro_bias' in err[0]
    assert not (tmp_path / 'sim').exists()


def test_list_parameters_are_checked_on_a_live_node(ros):
    from rclpy.parameter import Parameter
    from robot_calib.core.params import ParamError
    from robot_calib.nodes.base import PipelineNode
    from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
    for value, message in (([math.nan, 0.0, 0.0], 'finite'), ([0.0, 0.0], 'list of 3')):
        with pytest.raises(ParamError, match=message):
            PipelineNode(TiltPipeline,
                         parameter_overrides=[Parameter('mounting_rpy', value=value)])
