# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Offline replay end to end, with small test pipelines given as ``module:Class``."""

from dataclasses import dataclass, field
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from robot_calib import codec, methods
from robot_calib.core import types as T
from robot_calib.core.params import param, ParamError
from robot_calib.io import bags
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline
from robot_calib.replay import parse_overrides, parse_remaps, replay, ReplayError

ECHO = f'{__name__}:EchoPipeline'


@dataclass
class OffsetParams:
    """Nested parameters (dotted names ``offset.x``)."""

    x: float = param(0.0, 'm', 'offset added to x')


@dataclass
class EchoParams:
    """Parameters of the echo test pipeline."""

    gain: float = param(1.0, '', 'factor on x', minimum=0.0)
    offset: OffsetParams = field(default_factory=OffsetParams)
    mode: str = param('improved', '', 'variant', choices=('improved', 'seed'))


class EchoPipeline(Pipeline):
    """Publish every odometry input with x scaled; note the order static transforms arrived."""

    name = 'echo'
    params_type = EchoParams
    inputs = (InputSpec('imu', 'imu', 'imu'), InputSpec('odom', 'odom', 'odom', optional=True),
              InputSpec('tf', 'tf_static', 'tf_static', optional=True))
    outputs = (OutputSpec('odom', 'echo/odom', 'odom'),
               OutputSpec('alert', 'echo/alert', 'bool', qos='latched'))

    def __init__(self, params=None, log=None):
        """Create with counters."""
        super().__init__(params, log)
        self.static_at_first = None
        self.imu_seen = 0
        self.last_imu_t = None

    def handle(self, key, sample):
        """Echo odometry; raise the alert on the first IMU sample."""
        if self.static_at_first is None:
            self.static_at_first = len(self.static_transforms)
        if key == 'imu':
            self.imu_seen += 1
            self.last_imu_t = sample.t
            if self.imu_seen == 1:
                return [('alert', T.BoolSample(sample.t, True, sample.stamp_ns))]
            return []
        p = self.params
        return [('odom', T.OdomSample(sample.t, sample.x * p.gain + p.offset.x, sample.y,
                                      sample.yaw, sample.vx, 0.0, sample.wz,
                                      stamp_ns=sample.stamp_ns))]

    def finish(self):
        """Nothing to flush."""
        return []

    def method_summary(self):
        """Report what the pipeline saw."""
        return {'static_at_first': self.static_at_first, 'imu_seen': self.imu_seen,
                'gain': self.params.gain}

    def artifacts(self):
        """Write a small YAML result."""
        return {'echo_result.yaml': f'gain: {self.params.gain}\nimu_seen: {self.imu_seen}\n'}

    def plot(self, out_dir):
        """Draw one PNG."""
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])
        fig.savefig(Path(out_dir) / 'echo.png')
        plt.close(fig)
        return ['echo.png']


class BrokenPipeline(Pipeline):
    """Raise on every other IMU sample, and in its summary hooks."""

    name = 'broken'
    params_type = EchoParams
    inputs = (InputSpec('imu', 'imu', 'imu'),)
    outputs = (OutputSpec('odom', 'broken/odom', 'odom'),)

    def __init__(self, params=None, log=None):
        """Create."""
        super().__init__(params, log)
        self.n = 0

    def handle(self, key, sample):
        """Fail half the time; otherwise publish an undeclared output."""
        self.n += 1
        if self.n % 2:
            raise RuntimeError('boom')
        return [('nope', T.BoolSample(sample.t, True))]

    def plot(self, out_dir):
        """Fail."""
        raise ValueError('no plot')


class ScanOnlyPipeline(Pipeline):
    """Needs a scan (absent from the test bags)."""

    name = 'scan_only'
    params_type = EchoParams
    inputs = (InputSpec('scan', 'scan', 'scan'),)
    outputs = ()

    def handle(self, key, sample):
        """Nothing."""
        return []


def _imu(ns, gz=0.1):
    return T.ImuSample(ns * 1e-9, np.array([0.0, 0.0, gz]), np.array([0.0, 0.0, 9.81]),
                       stamp_ns=ns)


def write_test_bag(path, storage='mcap', imu_topic='/imu', odom_topic='/odom',
                   ground_truth=True):
    """
    Write a 4 s bag with known defects; return the counts to expect.

    IMU 100 Hz with one NaN sample, one duplicate stamp, one out-of-order stamp and a
    2 s gap; odometry 20 Hz; ground truth odometry; /tf_static written last in time
    (must still reach the pipeline first).
    """
    base = 1_000_000_000_000
    step = 10_000_000
    imu_times = [base + i * step for i in range(100)]
    imu_times += [base + 99 * step + 2_000_000_000 + i * step for i in range(1, 101)]
    with bags.BagWriter(path, storage=storage) as w:
        for i, ns in enumerate(imu_times):
            w.write(imu_topic, _imu(ns), ns)
            if i == 10:
                w.write(imu_topic, _imu(ns, gz=float('nan')), ns + 1)  # NaN, new stamp
            if i == 20:
                w.write(imu_topic, _imu(ns), ns + 2)  # duplicate stamp
            if i == 30:
                w.write(imu_topic, _imu(ns - 5 * step), ns + 3)  # out of order
        for i in range(60):
            ns = base + i * 50_000_000
            w.write(odom_topic, T.OdomSample(ns * 1e-9, 0.1 * i, 0.0, 0.01 * i, 0.1,
                                             stamp_ns=ns), ns)
            if ground_truth:
                w.write('/ground_truth/odom', T.OdomSample(ns * 1e-9, 0.1 * i, 0.001 * i,
                                                           0.0, stamp_ns=ns), ns)
        w.write('/tf_static', [T.StaticTransform('base_link', 'imu_link', np.zeros(3),
                                                 np.array([1.0, 0, 0, 0]))], imu_times[-1] + 1)
    return {'imu_read': 203, 'nan': 1, 'dup': 1, 'ooo': 1, 'gaps': 1, 'odom': 60}


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / 'in'
    write_test_bag(path)
    return path


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_replay_end_to_end(tmp_path, storage):
    path = tmp_path / 'in'
    expect = write_test_bag(path, storage=storage)
    out = tmp_path / 'out'
    summary = replay([path], out, nodes=[ECHO], overrides=['echo.gain=2', 'echo.offset.x=0.5'],
                     progress=False)
    assert sorted(p.name for p in out.iterdir()) == [
        'echo_result.yaml', 'metadata.yaml', 'output.mcap', 'plots', 'report.md',
        'summary.json']
    # the output folder opens as a ROS 2 bag, with rosbags as with our reader
    from rosbags.rosbag2 import Reader
    with Reader(out) as reader:
        count = reader.message_count
    assert count == sum(summary['output']['topics'].values()) > 0
    assert sum(1 for _ in bags.read_messages([out])) == count
    on_disk = json.loads((out / 'summary.json').read_text())
    assert on_disk == summary
    node = summary['nodes']['echo']
    imu = node['inputs']['imu']
    assert imu['read'] == expect['imu_read']
    assert imu['rejected_non_finite'] == expect['nan']
    assert imu['rejected_duplicate_stamp'] == expect['dup']
    assert imu['rejected_out_of_order'] == expect['ooo']
    assert imu['gaps'] == expect['gaps']
    assert imu['accepted'] == expect['imu_read'] - 3
    assert node['inputs']['odom']['accepted'] == expect['odom']
    assert node['static_at_first'] == 1  # /tf_static came before every other message
    assert node['params']['gain'] == 2.0 and node['params']['offset.x'] == 0.5
    assert node['timing']['input_messages'] == expect['imu_read'] + expect['odom']
    assert node['timing']['per_message_ms_p99'] >= node['timing']['per_message_ms_p50'] > 0
    assert summary['topics']['/imu']['read'] == expect['imu_read']
    assert summary['topics']['/ground_truth/odom']['read'] == 60
    assert summary['static_transforms'] == 1
    assert summary['duration'] == pytest.approx(3.99, abs=1e-6)  # 0.99 s + 2 s gap + 1 s
    assert summary['output']['topics'] == {'/echo/odom': 60, '/echo/alert': 1}
    assert (out / 'echo_result.yaml').read_text().startswith('gain: 2.0')
    # Output bag: same types as live, each output stamped with its input's stamp.
    topics = bags.list_topics([out / 'output.mcap'])
    assert topics == {'/echo/odom': ('nav_msgs/msg/Odometry', 60),
                      '/echo/alert': ('std_msgs/msg/Bool', 1)}
    odom = list(bags.read_messages([out / 'output.mcap'], ['/echo/odom']))
    for i, m in enumerate(odom):
        s = m.samples[0]
        assert m.time_ns == s.stamp_ns == 1_000_000_000_000 + i * 50_000_000
        assert s.x == pytest.approx(0.1 * i * 2 + 0.5)
    report = (out / 'report.md').read_text()
    for plot in summary['plots']:
        assert (out / plot).is_file() and f']({plot})' in report
    assert 'plots/trajectories.png' in summary['plots']
    assert 'plots/echo/echo.png' in summary['plots']
    assert not [p for p in tmp_path.iterdir() if p.name.startswith('.')]


def test_default_nodes_and_skips(bag, tmp_path, monkeypatch):
    monkeypatch.setattr(methods, 'REGISTRY', {
        'echo': ECHO, 'scan_only': f'{__name__}:ScanOnlyPipeline',
        'absent': 'robot_calib.pipelines.does_not_exist:Nothing'})
    summary = replay(bag, tmp_path / 'out', progress=False)
    assert list(summary['nodes']) == ['echo']
    assert '/scan' in summary['skipped']['scan_only']
    assert 'not installed' in summary['skipped']['absent']
    # Replaying again into the same folder replaces the previous output.
    summary2 = replay(bag, tmp_path / 'out', progress=False)
    assert summary2['nodes']['echo']['inputs'] == summary['nodes']['echo']['inputs']
    with pytest.raises(ReplayError, match='no node can run'):
        replay(bag, tmp_path / 'out2', nodes=None, remaps=['imu:=/nothing'], progress=False)
    assert not (tmp_path / 'out2').exists()


def test_remaps_both_ways(tmp_path):
    path = tmp_path / 'in'
    write_test_bag(path, imu_topic='/imu/data', odom_topic='/wheel/odom', ground_truth=False)
    # Node-side remap: the node's imu reads /imu/data; its output follows the rule too.
    s = replay(path, tmp_path / 'a', nodes=ECHO,
               remaps=['imu:=/imu/data', '/odom:=/wheel/odom', 'echo/odom:=/fixed/odom'],
               progress=False)
    assert s['nodes']['echo']['input_topics'] == {'imu': '/imu/data', 'odom': '/wheel/odom'}
    assert s['output']['topics']['/fixed/odom'] == 60
    # Bag-side remap: the bag's /imu/data is seen as /imu.
    s = replay(path, tmp_path / 'b', nodes=ECHO, remaps={'/imu/data': '/imu'}, progress=False)
    # (the optional odom reads the bag's only odometry, whose name ends like it)
    assert s['nodes']['echo']['input_topics'] == {'imu': '/imu', 'odom': '/wheel/odom'}
    with pytest.raises(ReplayError, match='neither'):
        replay(path, tmp_path / 'c', nodes=ECHO, remaps=['/nothing:=/imu'], progress=False)
    assert not (tmp_path / 'c').exists()
    # no remap: each input reads the bag's only topic of its type
    s = replay(path, tmp_path / 'g', nodes=ECHO, progress=False)
    assert s['nodes']['echo']['input_topics'] == {'imu': '/imu/data', 'odom': '/wheel/odom'}
    # the node's static transforms remapped away: none delivered (it was silently ignored)
    tf = replay(path, tmp_path / 'e', nodes=ECHO, remaps=['imu:=/imu/data',
                                                          '/tf_static:=/nothing'],
                progress=False)
    assert tf['nodes']['echo']['static_at_first'] == 0
    tf = replay(path, tmp_path / 'f', nodes=ECHO, remaps=['imu:=/imu/data'], progress=False)
    assert tf['nodes']['echo']['static_at_first'] == 1
    # onto a topic the bag already holds: two odometry streams silently merged (an audit)
    both = tmp_path / 'both'
    write_test_bag(both)
    with pytest.raises(ReplayError, match='would be merged'):
        replay(both, tmp_path / 'd', nodes=ECHO, remaps=['/ground_truth/odom:=/odom'],
               progress=False)
    assert not (tmp_path / 'd').exists()


def test_params_file_then_set(bag, tmp_path):
    params = tmp_path / 'p.yaml'
    params.write_text('echo:\n  ros__parameters:\n    gain: 3.0\n    offset:\n      x: 1.0\n'
                      'other_node:\n  ros__parameters:\n    anything: 1\n')
    s = replay(bag, tmp_path / 'o', nodes=ECHO, params_file=params, progress=False)
    assert s['nodes']['echo']['params'] == {'gain': 3.0, 'offset.x': 1.0, 'mode': 'improved'}
    s = replay(bag, tmp_path / 'o', nodes=ECHO, params_file=params,
               overrides={'echo.gain': '0.5', 'echo.mode': 'seed'}, progress=False)
    assert s['nodes']['echo']['params'] == {'gain': 0.5, 'offset.x': 1.0, 'mode': 'seed'}
    params.write_text('/**:\n  ros__parameters:\n    offset.x: 2.0\n    unrelated: 3\n')
    s = replay(bag, tmp_path / 'o', nodes=ECHO, params_file=params, progress=False)
    assert s['nodes']['echo']['params']['offset.x'] == 2.0
    params.write_text('echo:\n  ros__parameters:\n    gian: 3.0\n')
    with pytest.raises(ParamError, match='gian'):
        replay(bag, tmp_path / 'p', nodes=ECHO, params_file=params, progress=False)
    with pytest.raises(ParamError, match='minimum'):
        replay(bag, tmp_path / 'p', nodes=ECHO, overrides=['echo.gain=-1'], progress=False)
    with pytest.raises(ReplayError, match='not among'):
        replay(bag, tmp_path / 'p', nodes=ECHO, overrides=['tilt_detection.x=1'],
               progress=False)
    params.write_text('echo: [1, 2]\n')
    with pytest.raises(ReplayError, match='ros__parameters'):
        replay(bag, tmp_path / 'p', nodes=ECHO, params_file=params, progress=False)
    # typos that would silently set nothing: the section's key, one of our node names
    params.write_text('echo:\n  ros_parameters:\n    gain: 3.0\n')
    with pytest.raises(ReplayError, match="found \\['ros_parameters'\\]"):
        replay(bag, tmp_path / 'p', nodes=ECHO, params_file=params, progress=False)
    params.write_text('/**/tilt_detecton:\n  ros__parameters:\n    fall_angle: 40.0\n')
    with pytest.raises(ReplayError, match="did you mean 'tilt_detection'"):
        replay(bag, tmp_path / 'p', nodes=ECHO, params_file=params, progress=False)
    params.write_text('echo: {ros__parameters: {gain: [1,\n')
    with pytest.raises(ReplayError, match='cannot read'):
        replay(bag, tmp_path / 'p', nodes=ECHO, params_file=params, progress=False)
    assert not (tmp_path / 'p').exists()


def test_a_sample_the_method_turns_down_is_rejected_not_also_accepted():
    """Read = accepted + rejected: a rejection inside handle() was counted as both."""
    class Picky(EchoPipeline):
        def handle(self, key, sample):
            if key == 'imu' and round(sample.t * 100) % 2:
                return self.reject(key, 'odd')
            return super().handle(key, sample)
    pipe = Picky()
    for i in range(10):
        pipe.process('imu', _imu(10**9 + i * 10**7))
    c = pipe.summary()['inputs']['imu']
    assert (c['accepted'], c['rejected'], c['rejected_odd']) == (5, 5, 5)


def test_pipeline_errors_are_counted_not_fatal(bag, tmp_path):
    s = replay(bag, tmp_path / 'o', nodes=[ECHO, f'{__name__}:BrokenPipeline'],
               progress=False)
    broken = s['nodes']['broken']
    assert broken['errors']['process'] > 50 and broken['errors']['output'] > 50
    assert broken['inputs']['imu']['rejected_processing_error'] == broken['errors']['process']
    assert 'plot' in broken['errors']
    assert s['nodes']['echo']['inputs']['imu']['read'] == 203


def test_undecodable_messages_are_counted(tmp_path):
    path = tmp_path / 'in'
    with bags.BagWriter(path) as w:
        for i in range(20):
            ns = 10**9 + i * 10**7
            _, raw = __import__('robot_calib.codec', fromlist=['x']).serialize(_imu(ns))
            if i in (3, 7):
                raw = raw[:30]  # cut short: cannot be decoded
            w.write_raw('/imu', 'sensor_msgs/msg/Imu', raw, ns)
    s = replay(path, tmp_path / 'o', nodes=ECHO, progress=False)
    assert s['undecodable'] == {'/imu': 2}
    assert s['nodes']['echo']['inputs']['imu']['read'] == 18


def test_parsers():
    assert parse_remaps(['imu:=/imu/data', '/a/b:=c']) == [('/imu', '/imu/data'),
                                                           ('/a/b', '/c')]
    for bad in (['imu'], ['imu:='], [':=x'], ['a b:=c']):
        with pytest.raises(ReplayError, match='FROM:=TO'):
            parse_remaps(bad)
    assert parse_overrides(['n.a.b=1', 'n.c= x ']) == {'n': {'a.b': '1', 'c': 'x'}}
    for bad in (['n=1'], ['n.a'], ['.a=1'], ['n..a=1']):
        with pytest.raises(ReplayError, match='NODE.PARAM=VALUE'):
            parse_overrides(bad)


def test_bad_node_specs(bag, tmp_path):
    for spec, match in (('no_such_node', 'unknown node'), ('nomodule_xyz:Thing', 'import'),
                        (f'{__name__}:Missing', 'no class'), (f'{__name__}:write_test_bag',
                                                              'not a robot_calib Pipeline'),
                        (f'{ECHO},{ECHO}', 'twice')):
        with pytest.raises(ReplayError, match=match):
            replay(bag, tmp_path / 'o', nodes=spec, progress=False)
    assert not (tmp_path / 'o').exists()


def test_output_folder_checks(bag, tmp_path):
    other = tmp_path / 'notes'
    other.mkdir()
    (other / 'keep.txt').write_text('mine')
    with pytest.raises(ReplayError, match='not empty'):
        replay(bag, other, nodes=ECHO, progress=False)
    assert (other / 'keep.txt').read_text() == 'mine'
    afile = tmp_path / 'file'
    afile.write_text('x')
    with pytest.raises(ReplayError, match='not a folder'):
        replay(bag, afile, nodes=ECHO, progress=False)


def test_registered_pipelines_on_sample_bag(repo_root, tmp_path):
    names = methods.available()
    if not names:
        pytest.skip('no registered pipeline is installed yet')
    from robot_calib.io.convert_bag import convert_bag
    sliced = tmp_path / 'husky_60s'  # the first minute keeps the test quick
    convert_bag(repo_root / 'bags' / 'husky_test1', sliced, duration=60.0)
    s = replay(sliced, tmp_path / 'o', progress=False)
    assert set(s['nodes']) | set(s['skipped']) == set(methods.REGISTRY)
    for name, node in s['nodes'].items():
        assert node['inputs'], name
        assert all(v.get('read', 0) > 0 for v in node['inputs'].values()), name
        assert not node['errors'], (name, node.get('first_errors'))
    assert math.isclose(s['duration'], 60.0, abs_tol=0.1)
    assert s['static_transforms'] == 1


def test_registered_pipelines_on_simulated_bag(tmp_path):
    try:
        from robot_calib import sim
        simulate = sim.simulate
    except (ImportError, AttributeError):
        pytest.skip('robot_calib.sim.simulate is not available yet')
    if not methods.available():
        pytest.skip('no registered pipeline is installed yet')
    bag = tmp_path / 'drive'
    simulate('drive', bag, seed=1, duration=10.0)
    s = replay(bag, tmp_path / 'o', progress=False)
    assert s['nodes'], s['skipped']
    out_topics = bags.list_topics([tmp_path / 'o' / 'output.mcap'])
    for name, node in s['nodes'].items():
        assert not node['errors'], (name, node.get('first_errors'))
        assert all(v.get('read', 0) > 0 for v in node['inputs'].values()), name
        cls = methods.load(name)
        for spec in cls.outputs:
            topic = '/' + spec.topic.lstrip('/')
            if topic in out_topics:  # same type as the live node publishes
                assert out_topics[topic][0] == codec.KINDS[spec.kind].msgtype, topic
    assert s['topics']['/ground_truth/odom']['read'] > 0
    assert 'plots/trajectories.png' in s['plots']
    if 'wheel_odometry_calibration' in s['nodes']:
        assert (tmp_path / 'o' / 'wheel_calibration.yaml').is_file()


def test_two_bags_merged_with_progress_bar(tmp_path, capsys):
    a, b = tmp_path / 'imu_bag', tmp_path / 'odom_bag'
    with bags.BagWriter(a) as w:
        for i in range(300):
            ns = 10**9 + i * 10**7
            w.write('/imu', _imu(ns), ns)
    with bags.BagWriter(b, storage='sqlite3') as w:
        for i in range(60):
            ns = 10**9 + i * 5 * 10**7
            w.write('/odom', T.OdomSample(ns * 1e-9, 0.01 * i, 0.0, 0.0, stamp_ns=ns), ns)
    s = replay([a, b], tmp_path / 'o', nodes=ECHO, progress=True)
    assert s['bags'] == [str(a), str(b)]
    assert s['nodes']['echo']['inputs']['imu']['accepted'] == 300
    assert s['nodes']['echo']['inputs']['odom']['accepted'] == 60
    assert s['output']['topics']['/echo/odom'] == 60
    assert 'replay' in capsys.readouterr().err  # the tqdm bar went to stderr


def test_time_window(bag, tmp_path):
    # IMU at 100 Hz from t0 for 0.99 s, then a 2 s gap; odometry at 20 Hz for 3 s.
    s = replay(bag, tmp_path / 'o', nodes=ECHO, start_offset=0.5, duration=1.0,
               progress=False)
    node = s['nodes']['echo']
    assert node['static_at_first'] == 1  # static transforms are delivered all the same
    assert node['inputs']['odom']['read'] == 21  # t0 + 0.5 s ... t0 + 1.5 s, both ends
    assert node['inputs']['imu']['read'] == 50  # t0 + 0.5 s ... t0 + 0.99 s
    assert s['window'] == [0.5, 1.0]
    with pytest.raises(ReplayError, match='time window'):
        replay(bag, tmp_path / 'p', nodes=ECHO, start_offset=-1.0, progress=False)
    with pytest.raises(ReplayError, match='time window'):
        replay(bag, tmp_path / 'p', nodes=ECHO, duration=0.0, progress=False)
    # a window past the end of the recording, or too short to hold a message: nothing read,
    # every output written all the same (it crashed on the empty timing sample)
    for start, length in ((10.0, None), (0.5005, 0.0001)):
        out = tmp_path / f'empty{start}'
        s = replay(bag, out, nodes=ECHO, start_offset=start, duration=length, progress=False)
        assert sum(c['read'] for c in s['nodes']['echo']['inputs'].values()) == 0
        assert (out / 'summary.json').is_file() and (out / 'report.md').is_file()


def test_progress_bar_counts_the_time_window(tmp_path, monkeypatch):
    from robot_calib.sim import simulate
    import tqdm
    bars = []

    class Bar(tqdm.tqdm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.first_total = self.total
            bars.append(self)

    monkeypatch.setattr(tqdm, 'tqdm', Bar)
    bag = tmp_path / 'drive'
    simulate('drive', bag, seed=1, duration=6.0)  # IMU 200 Hz, odometry 50 Hz, for 6 s
    whole = replay(bag, tmp_path / 'all', nodes=ECHO, progress=True, plots=False)
    s = replay(bag, tmp_path / 'o', nodes=ECHO, start_offset=2.0, duration=2.0, progress=True,
               plots=False)
    read = s['timing']['messages']
    assert read == 200 * 2 + 50 * 2 + 2  # both ends of the window
    all_bar, bar = bars
    assert all_bar.first_total == all_bar.total == all_bar.n == whole['timing']['messages']
    # the total was the whole bag's (1502): the bar stopped at a third
    assert abs(bar.first_total - read) <= 5
    assert bar.total == bar.n == read  # closed at 100 %


class CollidingPipeline(EchoPipeline):
    """Report keys that replay also writes (its own errors and timing)."""

    name = 'colliding'

    def method_summary(self):
        """Report an 'errors' count and a 'timing' block of its own."""
        return {'errors': 5, 'timing': {'fit_ms': 1.0}}

    def plot(self, out_dir):
        """Fail, to record a plot error."""
        raise RuntimeError('no plot')


def test_method_keys_are_never_hidden(bag, tmp_path):
    s = replay(bag, tmp_path / 'o', nodes=f'{__name__}:CollidingPipeline', progress=False)
    node = s['nodes']['colliding']
    assert node['errors'] == 5 and node['method_timing'] == {'fit_ms': 1.0}
    assert node['timing']['input_messages'] > 0
    assert 'no plot' in node['replay_errors']['plot']
    assert (tmp_path / 'o' / 'report.md').is_file()


def test_output_bag_is_one_mcap_file_even_when_empty(tmp_path):
    path = tmp_path / 'in'
    with bags.BagWriter(path) as w:
        for i in range(10):
            ns = 10**9 + i * 10**7
            w.write('/imu', _imu(ns), ns)
    s = replay(path, tmp_path / 'o', nodes=ECHO, progress=False)  # IMU only: no odometry out
    out = tmp_path / 'o' / 'output.mcap'
    assert out.is_file() and out.read_bytes()[:8] == b'\x89MCAP0\r\n'
    assert s['output']['topics'] == {'/echo/alert': 1}
    assert bags.list_topics([out]) == {'/echo/alert': ('std_msgs/msg/Bool', 1)}
    assert b'serialized_metadata' in out.read_bytes()  # rosbag2's metadata is inside
    umask = os.umask(0o022)
    os.umask(umask)
    assert (tmp_path / 'o').stat().st_mode & 0o777 == 0o777 & ~umask


def test_output_chunks_are_zstd_compressed(bag, tmp_path):
    """output.mcap has zstd chunks (as rosbag2 writes by default) and the same messages."""
    from rosbags.highlevel import AnyReader
    replay(bag, tmp_path / 'z', nodes=ECHO, progress=False)
    replay(bag, tmp_path / 'plain', nodes=ECHO, progress=False, compress=False)
    data = (tmp_path / 'z' / 'output.mcap').read_bytes()
    assert b'zstd' in data and b'zstd' not in (tmp_path / 'plain' / 'output.mcap').read_bytes()

    def messages(folder):
        with AnyReader([folder]) as reader:
            return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    assert messages(tmp_path / 'z') == messages(tmp_path / 'plain') != []


class GatedPipeline(EchoPipeline):
    """Echo odometry, but turn it away unread while 1000 to 1999 IMU samples were seen."""

    name = 'gated'
    refusable = ('odom',)

    def refusal(self, key):
        """Refuse odometry in the middle of the bag."""
        return 'gated' if 1000 <= self.imu_seen < 2000 else ''


def test_refused_inputs_count_and_resume_as_in_a_live_node(tmp_path):
    """Replay skips decoding refused odometry, yet counts, outputs and plots stay the same."""
    path = tmp_path / 'in'
    samples = []
    with bags.BagWriter(path) as w:
        for i in range(3000):                      # 100 Hz IMU, 50 Hz odometry: 4500 messages
            ns = 10**9 + i * 10**7
            samples.append(('imu', _imu(ns)))
            w.write('/imu', samples[-1][1], ns)
            if i % 2:
                samples.append(('odom', T.OdomSample(ns * 1e-9, 0.01 * i, 0.0, 0.0,
                                                     stamp_ns=ns + 1)))
                w.write('/odom', samples[-1][1], ns + 1)
    live = GatedPipeline()
    outputs = [out for key, sample in samples for out in live.process(key, sample)]
    s = replay(path, tmp_path / 'o', nodes=f'{__name__}:GatedPipeline', progress=False)
    odom = s['nodes']['gated']['inputs']['odom']
    assert odom == dict(live.counts['odom'])
    assert odom['read'] == 1500 and odom['rejected_gated'] == 500 and odom['accepted'] == 1000
    assert 'gaps' not in odom                      # its time line started again after
    echoed = list(bags.read_messages([tmp_path / 'o'], topics=['/echo/odom']))
    assert [m.samples[0].x for m in echoed] == [o[1].x for o in outputs if o[0] == 'odom']
    assert s['nodes']['gated']['timing']['input_messages'] == 4500


def test_wheel_calibration_refuses_odometry_while_joint_states_drive_it(repo_root, tmp_path,
                                                                        monkeypatch):
    from robot_calib.methods.wheel_odometry_calibration.pipeline import (
        WheelCalibrationPipeline)
    node = 'wheel_odometry_calibration'
    bag = repo_root / 'bags' / 'sim_drive'
    refused = replay(bag, tmp_path / 'a', nodes=node, progress=False)
    monkeypatch.setattr(WheelCalibrationPipeline, 'refusable', ())
    handled = replay(bag, tmp_path / 'b', nodes=node, progress=False)
    a, b = refused['nodes'][node], handled['nodes'][node]
    assert a['inputs']['odom'] == {'read': b['inputs']['odom']['read'],
                                   'rejected': b['inputs']['odom']['read'],
                                   'rejected_joint_states_preferred': b['inputs']['odom']['read']}
    assert a['result'] == b['result'] and a['result']['verdict'] == 'converged'
    assert a['timing']['input_messages'] == b['timing']['input_messages']


def test_an_output_no_bag_can_hold_is_counted_and_the_output_bag_stays_whole(tmp_path):
    """An echoed odometry stamped before 1970 cannot be written: counted, the rest kept."""
    path = tmp_path / 'in'
    with bags.BagWriter(path) as w:
        for i in range(10):
            ns = 10**9 + i * 10**8
            w.write('/imu', _imu(ns), ns)
            t = -0.5 if i == 0 else ns * 1e-9          # the first header stamp before 1970
            w.write('/odom', T.OdomSample(t, 0.1 * i, 0.0, 0.0), ns + 1)
    s = replay(path, tmp_path / 'o', nodes=ECHO, progress=False)
    assert s['nodes']['echo']['errors']['output'] == 1
    echoed = list(bags.read_messages([tmp_path / 'o'], topics=['/echo/odom']))
    assert len(echoed) == s['nodes']['echo']['inputs']['odom']['accepted'] - 1


def test_replay_keeps_freed_heap_under_glibc():
    """Under glibc both malloc thresholds are accepted, once a process (then remembered)."""
    import subprocess
    import sys
    libc = os.confstr('CS_GNU_LIBC_VERSION') if 'CS_GNU_LIBC_VERSION' in os.confstr_names else ''
    if not libc.startswith('glibc'):
        pytest.skip('not glibc')
    code = ('from robot_calib.replay.run import keep_freed_heap; '
            'print(keep_freed_heap(), keep_freed_heap())')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ['True', 'True']


def _imu_odom_bag(path, n, imu_topics, odom_topics, start_ns=10**9, imu_stamped=True):
    """Write ``n`` IMU messages at 100 Hz on each of ``imu_topics``, odometry at 20 Hz."""
    with bags.BagWriter(path) as w:
        for i in range(n):
            ns = start_ns + i * 10**7
            for topic in imu_topics:
                w.write(topic, _imu(ns if imu_stamped else 0), ns)
            if i % 5 == 0:
                for topic in odom_topics:
                    w.write(topic, T.OdomSample(ns * 1e-9, 0.001 * i, 0.0, 0.0, 0.1,
                                                stamp_ns=ns), ns)


def test_messages_without_a_header_stamp_take_their_receive_time(tmp_path, capsys):
    """Header stamps left 0 by the driver: the bag's log time stands in, and the user is told."""
    from robot_calib.cli import main
    from robot_calib.pipelines.validation import restamp_unset
    path = tmp_path / 'unstamped'
    # a wall clock (recorded on a robot); IMU stamps 0 every time, odometry stamped
    _imu_odom_bag(path, 200, ('/imu',), ('/odom',), 1_700_000_000 * 10**9, imu_stamped=False)
    assert main(['replay', str(path), '--out', str(tmp_path / 'o'), '--nodes',
                 'tilt_detection,odometry_fusion', '--no-plots', '--no-progress']) == 0
    assert 'warning: 200 message(s) on /imu have no header stamp' in capsys.readouterr().err
    s = json.loads((tmp_path / 'o' / 'summary.json').read_text())
    assert s['restamped'] == {'/imu': 200}
    assert s['nodes']['tilt_detection']['inputs']['imu']['accepted'] == 200
    assert s['nodes']['odometry_fusion']['inputs']['imu']['accepted'] == 200
    # set stamps are kept; a stamp of 0 with no receive time, and static transforms, too
    assert restamp_unset([_imu(5)], 1_500_000_000 * 10**9) is None
    assert restamp_unset([_imu(0)], 0) is None
    assert restamp_unset([_imu(0)], 10**9) is None     # simulated time: 0 is its start
    tf = T.StaticTransform('base_link', 'imu_link', (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                           stamp_ns=0)
    assert restamp_unset([tf], 1_500_000_000 * 10**9) is None
    fixed = restamp_unset([_imu(0)], 1_500_000_000 * 10**9)
    assert fixed[0].stamp_ns == 1_500_000_000 * 10**9 and fixed[0].t == 1.5e9


def test_inputs_read_the_only_topic_of_their_type(tmp_path):
    """/imu/data and /wheel/odom (robot_localization's names): read without --remap, said."""
    path = tmp_path / 'names'
    _imu_odom_bag(path, 300, ('/imu/data', '/imu/data_raw'), ('/wheel/odom', '/ground_truth/odom'))
    # two Imu topics: none is chosen for the node, which says what to remap
    with pytest.raises(ReplayError, match='needs /imu'):
        replay(path, tmp_path / 'o1', nodes='odometry_fusion', progress=False, plots=False)
    s = replay(path, tmp_path / 'o2', nodes='odometry_fusion', remaps=['imu:=/imu/data'],
               progress=False, plots=False)
    node = s['nodes']['odometry_fusion']
    assert node['inputs']['odom']['accepted'] == 60   # /wheel/odom, not the ground truth
    assert any('input odom reads /wheel/odom' in n for n in node['notes'])
    assert s['remaps'] == {'/odom': '/wheel/odom', '/imu': '/imu/data'}
