# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""tilt_detection: pipeline bad input, simulation, real bags, node via rclpy, CLI replay."""

import json
import math

import numpy as np
import pytest

from robot_calib.core import types as T
from robot_calib.methods.tilt_detection.params import TiltParams
from robot_calib.methods.tilt_detection.pipeline import TiltPipeline
from ros_helpers import spin_until
from tilt_onsets import fall_alert_onsets

G = 9.80665
DT = 0.005


def _imu(t, acc=(0.0, 0.0, G), gyro=(0.0, 0.0, 0.0), frame='imu_link'):
    return T.ImuSample(t, np.array(gyro, dtype=float), np.array(acc, dtype=float), frame)


def _feed(pipe, samples, key='imu'):
    outs = []
    for s in samples:
        outs.extend(pipe.process(key, s))
    return outs


def _alerts(outs):
    return [(o.t, o.value) for k, o in outs if k == 'fall_alert']


def _upright(n, t0=0.0, **kw):
    return [_imu(t0 + k * DT, **kw) for k in range(n)]


# -- outputs ----------------------------------------------------------------------------------
def test_outputs_upright_then_upside_down():
    pipe = TiltPipeline()
    outs = _feed(pipe, _upright(200))
    assert _alerts(outs) == [(0.0, False)]            # initial latched state
    imu_out = [o for k, o in outs if k == 'imu']
    assert len(imu_out) == 200
    assert imu_out[-1].orientation is not None
    assert imu_out[-1].stamp_ns == round(imu_out[-1].t * 1e9)
    diags = [o for k, o in outs if k == 'diagnostics']
    assert diags and diags[0].statuses[0].name == 'tilt_detection'
    assert diags[0].statuses[0].level == 0
    # roll over onto the back in 0.5 s (gyro consistent with the accelerometer)
    flip = []
    for k in range(400):
        t = 1.0 + k * DT
        ang = min(math.pi, math.pi * k / 100)
        rate = math.pi / 0.5 if k < 100 else 0.0
        flip.append(_imu(t, acc=(0.0, G * math.sin(ang), G * math.cos(ang)),
                         gyro=(rate, 0.0, 0.0)))
    outs = _feed(pipe, flip)
    al = _alerts(outs)
    assert al and al[0][1] is True
    # 45 deg is crossed at k = 25 (t = 1.125 s); min duration 20 ms
    assert 1.125 <= al[0][0] <= 1.125 + 0.05
    diag = [o for k, o in outs if k == 'diagnostics'][-1].statuses[0]
    values = dict(diag.values)
    assert diag.level == 2 and values['alert'] == 'true'
    assert 'fallen' in values['reason'] and float(values['tilt_deg']) > 170
    assert pipe.method_summary()['alerts'] == 1


def test_alert_clears_after_clear_duration():
    pipe = TiltPipeline(TiltParams(clear_duration=0.5))
    _feed(pipe, [_imu(k * DT, acc=(0.0, 0.0, -G)) for k in range(40)])
    assert pipe.last.alert
    # set upright again (gap free, gyro says nothing: only the accelerometer recovers it)
    outs = _feed(pipe, [_imu(0.2 + k * DT, acc=(0.0, 0.0, G)) for k in range(2000)])
    al = _alerts(outs)
    assert al and al[-1][1] is False
    assert pipe.method_summary()['alert_episodes'][0]['end'] is not None


def test_stop_on_alert_publishes_zero_cmd_vel_only_when_enabled():
    for enabled in (False, True):
        pipe = TiltPipeline(TiltParams(stop_on_alert=enabled))
        outs = _feed(pipe, [_imu(k * DT, acc=(0.0, 0.0, -G)) for k in range(100)])
        stops = [o for k, o in outs if k in ('cmd_vel', 'cmd_vel_stamped')]
        if enabled:
            assert stops and all(s.vx == 0.0 and s.wz == 0.0 for s in stops)
        else:
            assert not stops


# -- bad input ---------------------------------------------------------------------------------
@pytest.mark.parametrize('bad, reason', [
    ({'acc': (math.nan, 0.0, G)}, 'non_finite'),
    ({'gyro': (0.0, math.inf, 0.0)}, 'non_finite'),
    ({'acc': (0.0, 0.0, -17 * G)}, 'accel_out_of_range'),
    ({'gyro': (40.0, 0.0, 0.0)}, 'gyro_out_of_range'),
    ({'acc': (0.0, 0.0, 0.0)}, 'accel_zero'),
])
def test_single_bad_sample_is_rejected_without_alert(bad, reason):
    pipe = TiltPipeline()
    samples = _upright(100)
    samples[50] = _imu(samples[50].t, **bad)
    outs = _feed(pipe, samples)
    assert pipe.counts['imu']['rejected_' + reason] == 1
    assert _alerts(outs) == [(0.0, False)]
    assert pipe.counts['imu']['read'] == 100


def test_in_range_spike_does_not_raise_alert():
    pipe = TiltPipeline()
    samples = _upright(400)
    samples[200] = _imu(samples[200].t, acc=(100.0, 20.0, -80.0), gyro=(20.0, -25.0, 5.0))
    outs = _feed(pipe, samples)
    assert _alerts(outs) == [(0.0, False)]
    assert pipe.counts['imu'].get('rejected', 0) == 0


def test_repeated_and_backwards_stamps_are_rejected():
    pipe = TiltPipeline()
    samples = _upright(50)
    samples += [_imu(samples[-1].t), _imu(samples[-1].t - 0.1)]
    _feed(pipe, samples)
    assert pipe.counts['imu']['rejected_duplicate_stamp'] == 1
    assert pipe.counts['imu']['rejected_out_of_order'] == 1


def test_gap_of_seconds_restarts_with_warning():
    logs = []
    pipe = TiltPipeline(log=lambda level, msg: logs.append((level, msg)))
    _feed(pipe, _upright(100))
    outs = _feed(pipe, _upright(100, t0=5.0))
    assert pipe.est.result().restarts == 1
    assert any(level == 'warn' and 'gap' in msg for level, msg in logs)
    assert pipe.counts['imu']['gaps'] == 1
    assert _alerts(outs) == []
    diags = [o for k, o in outs if k == 'diagnostics']
    assert diags[0].statuses[0].level == 1


def test_missing_covariance_is_fine():
    pipe = TiltPipeline()
    s = T.ImuSample(0.0, np.zeros(3), np.array([0.0, 0.0, G]), 'imu_link', None, None,
                    np.full((3, 3), np.nan), np.full((3, 3), np.nan))
    outs = pipe.process('imu', s)
    assert outs[0][0] == 'imu' and outs[0][1].orientation is not None


def test_mounting_from_parameter_and_from_tf_static():
    # IMU mounted upside down (roll = pi about x) on an upright robot
    p = TiltParams(mounting_rpy=[math.pi, 0.0, 0.0])
    pipe = TiltPipeline(p)
    outs = _feed(pipe, [_imu(k * DT, acc=(0.0, 0.0, -G)) for k in range(100)])
    assert _alerts(outs) == [(0.0, False)]
    out = [o for k, o in outs if k == 'imu'][-1]
    assert out.frame_id == 'base_link'
    np.testing.assert_allclose(out.accel, [0.0, 0.0, G], atol=1e-9)
    # the same through /tf_static (base_link -> imu_link rotation)
    pipe = TiltPipeline()
    tf = T.StaticTransform('base_link', 'imu_link', np.zeros(3), np.array([0.0, 1.0, 0.0, 0.0]))
    pipe.process('tf_static', tf)
    outs = _feed(pipe, [_imu(k * DT, acc=(0.0, 0.0, -G)) for k in range(100)])
    assert _alerts(outs) == [(0.0, False)]
    assert pipe.method_summary()['mounting'] == '/tf_static'
    # without the mounting the same data is a robot on its back
    pipe = TiltPipeline()
    outs = _feed(pipe, [_imu(k * DT, acc=(0.0, 0.0, -G)) for k in range(100)])
    assert _alerts(outs)[-1][1] is True


def test_seed_mode_pipeline_runs():
    pipe = TiltPipeline(TiltParams(mode='seed'))
    outs = _feed(pipe, [_imu(k * DT, acc=(0.0, G, 0.0)) for k in range(50)])   # on its side
    assert _alerts(outs)[-1][1] is True


# -- simulated scenarios ------------------------------------------------------------------------
def test_sim_tip_over_alerts_within_100_ms():
    sim = pytest.importorskip('robot_calib.sim')
    r = sim.run_scenario('tip_over', seed=2, overrides={'lidar.rate': 0.5})
    tr = r.true
    tilt = np.arccos(np.cos(tr['roll']) * np.cos(tr['pitch']))
    cross = float(tr['t'][np.argmax(tilt > math.pi / 4)]) + r.truth['start_time']
    assert r.truth['tilt_crossing'] + r.truth['start_time'] == pytest.approx(cross, abs=0.005)
    onsets = fall_alert_onsets(TiltPipeline(), r.messages)
    assert len(onsets) == 1
    assert 0.0 <= onsets[0] - cross <= 0.1


def test_sim_bumpy_drive_has_no_alert():
    sim = pytest.importorskip('robot_calib.sim')
    r = sim.run_scenario('bumpy_drive', seed=3, duration=150.0, overrides={'lidar.rate': 0.5})
    tr = r.true
    true_tilt = np.degrees(np.arccos(np.cos(tr['roll']) * np.cos(tr['pitch'])))
    assert 13.0 < true_tilt.max() < 20.0            # the ramps were really driven over
    pipe = TiltPipeline()
    assert fall_alert_onsets(pipe, r.messages) == []
    assert pipe.method_summary()['max_tilt_deg'] < 25.0


# -- real data --------------------------------------------------------------------------------
def test_phidgets_upside_down_bag_alerts_at_once(shared_data):
    from robot_calib.io.datasets import imu_tools
    samples = imu_tools.load_imu(shared_data / 'imu_tools' / 'phidgets_imu_upside_down.bag')
    assert samples
    pipe = TiltPipeline()
    outs = _feed(pipe, samples[:500])
    al = [a for a in _alerts(outs) if a[1]]
    assert al and al[0][0] - samples[0].t <= 0.5


def test_broad_slice_accuracy(shared_data):
    from robot_calib.io.datasets import broad
    from robot_calib.methods.tilt_detection.variants import track as run
    tr = broad.load_trial(shared_data / 'broad' / '10_undisturbed_slow_translation_A.npz')
    n = 20000
    out = run(tr.t[:n], tr.gyr[:n], tr.acc[:n])
    e = np.degrees(broad.inclination_error(out['quat'], tr.gt_quat[:n]))
    m = tr.movement[:n] & np.isfinite(e)
    assert m.sum() > 1000
    assert np.sqrt(np.mean(e[m] ** 2)) < 1.0
    seed = run(tr.t[:n], tr.gyr[:n], tr.acc[:n], TiltParams(mode='seed'))
    es = np.degrees(broad.inclination_error(seed['quat'], tr.gt_quat[:n]))
    assert np.sqrt(np.mean(es[m] ** 2)) > np.sqrt(np.mean(e[m] ** 2))


# -- node through rclpy -----------------------------------------------------------------------
def test_node_in_process_latched_alert_and_late_subscriber():
    rclpy = pytest.importorskip('rclpy')
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                           ReliabilityPolicy)
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Bool

    from robot_calib import codec
    from robot_calib.nodes.base import PipelineNode
    latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    rclpy.init()
    try:
        node = PipelineNode(TiltPipeline)
        peer = rclpy.create_node('tilt_peer')
        got_imu, got_alert, late_alert = [], [], []
        peer.create_subscription(Imu, 'tilt/imu', got_imu.append, 50)
        peer.create_subscription(Bool, 'tilt/fall_alert', got_alert.append, latched)
        pub = peer.create_publisher(Imu, 'imu', qos_profile_sensor_data)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.add_node(peer)
        for _ in range(20):  # discovery
            ex.spin_once(timeout_sec=0.02)
        for k in range(60):
            acc = (0.0, 0.0, G) if k < 20 else (0.0, 0.0, -G)   # upright, then on its back
            s = _imu(1.0 + k * DT, acc=acc)
            pub.publish(codec.serialize(s)[1])
            ex.spin_once(timeout_sec=0.05)
        spin_until(ex, lambda: got_alert and got_alert[-1].data and len(got_imu) >= 20, 50)
        assert len(got_imu) >= 20
        q = got_imu[-1].orientation
        assert abs(q.w) + abs(q.x) + abs(q.y) + abs(q.z) > 0.5
        assert got_imu[-1].header.frame_id == 'imu_link'
        assert got_alert and got_alert[-1].data is True
        # a subscriber that joins after the alert still receives it (transient local)
        late = rclpy.create_node('tilt_late_peer')
        late.create_subscription(Bool, 'tilt/fall_alert', late_alert.append, latched)
        ex.add_node(late)
        spin_until(ex, lambda: late_alert)
        assert late_alert and late_alert[-1].data is True
        # best-effort delivery may drop some; every delivered one was accepted
        assert node.pipeline.counts['imu']['accepted'] == node.pipeline.counts['imu']['read']
        for n in (late, peer, node):
            n.destroy_node()
    finally:
        rclpy.try_shutdown()


# -- replay through the CLI ---------------------------------------------------------------------
def test_cli_replay_of_simulated_tip_over_bag(tmp_path):
    sim = pytest.importorskip('robot_calib.sim')
    cli = pytest.importorskip('robot_calib.cli')
    from robot_calib.io.bags import read_messages
    bag = tmp_path / 'tip'
    truth = sim.simulate('tip_over', bag, seed=4, overrides={'lidar.rate': '0.5'})
    out = tmp_path / 'out'
    code = cli.main(['replay', str(bag), '--out', str(out), '--nodes', 'tilt_detection',
                     '--no-progress'])
    assert code == 0
    alerts = [(m.time_ns, s.value) for m in read_messages([out / 'output.mcap'],
                                                          ['/tilt/fall_alert'])
              for s in m.samples]
    raised = [t for t, v in alerts if v]
    assert raised, 'no fall alert in the replay output'
    cross = truth['tilt_crossing'] + truth['start_time']
    assert 0.0 <= raised[0] * 1e-9 - cross <= 0.1
    summary = json.loads((out / 'summary.json').read_text())
    node = summary['nodes']['tilt_detection']
    assert json.dumps(node).count('alert') > 0
    topics = {m.topic for m in read_messages([out / 'output.mcap'], ['/tilt/imu'])}
    assert topics == {'/tilt/imu'}


def test_clock_jumping_back_recovers_after_a_few_samples():
    logs = []
    pipe = TiltPipeline(log=lambda level, msg: logs.append((level, msg)))
    _feed(pipe, _upright(50))
    _feed(pipe, [_imu(100.0, acc=(0.0, 0.0, -G))])     # one stray stamp from the future
    outs = _feed(pipe, [_imu(-30.0 + k * DT, acc=(0.0, 0.0, -G)) for k in range(40)])
    # the stray stamp is not used; the samples that confirm the reset are (nothing is lost)
    assert pipe.counts['imu']['rejected_clock_jump'] == 1
    assert 'rejected_out_of_order' not in pipe.counts['imu']
    assert pipe.counts['imu']['accepted'] == 90 and pipe.counts['imu']['clock_jumps'] == 1
    assert any('jumped back' in msg for _, msg in logs)
    assert _alerts(outs) and _alerts(outs)[-1][1] is True   # data flows again
    # a driver repeating one stamp is rejected forever (no recovery from duplicates)
    pipe = TiltPipeline()
    _feed(pipe, _upright(5))
    _feed(pipe, [_imu(0.02) for _ in range(30)])
    assert pipe.counts['imu']['rejected_duplicate_stamp'] == 30


def test_sim_rotated_imu_mounting_from_tf_static():
    sim = pytest.importorskip('robot_calib.sim')
    over = {'lidar.rate': 0.5, 'imu.roll': 1.5708, 'imu.yaw': -1.5708}
    r = sim.run_scenario('tip_over', seed=5, overrides=over)
    cross = r.truth['tilt_crossing'] + r.truth['start_time']
    pipe = TiltPipeline()
    onsets = fall_alert_onsets(pipe, r.messages)
    assert pipe.method_summary()['mounting'] == '/tf_static'
    assert len(onsets) == 1 and 0.0 <= onsets[0] - cross <= 0.1
    # ignoring the mounting, the IMU on its side looks like a fallen robot at once
    onsets = fall_alert_onsets(TiltPipeline(TiltParams(use_tf_static=False)), r.messages)
    assert onsets and onsets[0] - r.truth['start_time'] < 0.1
