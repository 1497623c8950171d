# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""``odometry_fusion`` through ``robot-calib replay``: a simulated bag and the real Husky bag."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from robot_calib.cli import main
from robot_calib.io.bags import read_messages

pytestmark = pytest.mark.slow  # over a few seconds each: left out by -m "not slow"

REPO = Path(__file__).resolve().parents[1]


def _track(bag, topic):
    rows = []
    for m in read_messages([bag], topics=[topic]):
        for s in m.samples:
            rows.append((s.t, s.x, s.y, s.yaw))
    return np.array(rows)


def _ate(est, ref):
    """RMS distance (m) after one SE(2) alignment of est onto ref (Kabsch, no scale)."""
    e = np.column_stack([np.interp(ref[:, 0], est[:, 0], est[:, 1]),
                         np.interp(ref[:, 0], est[:, 0], est[:, 2])])
    a, b = e - e.mean(0), ref[:, 1:3] - ref[:, 1:3].mean(0)
    u, _, vt = np.linalg.svd(a.T @ b)
    r = vt.T @ np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    return float(np.sqrt(np.mean(np.sum((a @ r.T - b) ** 2, axis=1))))


@pytest.fixture(scope='module')
def sim_bag(tmp_path_factory):
    pytest.importorskip('robot_calib.sim')
    out = tmp_path_factory.mktemp('fusion') / 'drive'
    assert main(['simulate', 'fusion_drive', '--out', str(out), '--seed', '1',
                 '--duration', '90']) == 0
    return out


def test_replay_of_a_simulated_bag_beats_raw_odometry(sim_bag, tmp_path):
    out = tmp_path / 'replay'
    assert main(['replay', str(sim_bag), '--out', str(out), '--nodes', 'odometry_fusion']) == 0
    summ = json.loads((out / 'summary.json').read_text())['nodes']['odometry_fusion']
    assert summ['imu_extrinsic'] == 'tf' and summ['mode'] == 'improved'
    assert summ['outputs']['odom'] > 1000 and summ['outputs']['diagnostics'] > 50
    assert summ['nis']['updates'] > 1000
    truth = json.loads(Path(str(sim_bag) + '.truth.json').read_text())
    est = _track(out / 'output.mcap', '/odometry/fused')
    gt = _track(sim_bag, '/ground_truth/odom')
    raw = _track(sim_bag, '/odom')
    assert _ate(est, gt) < 0.5 * _ate(raw, gt)
    bias = summ['estimates']['gyro_bias']
    assert bias == pytest.approx(truth['gyro_bias_z'] if 'gyro_bias_z' in truth
                                 else truth['gyro_bias'][2], abs=0.003)
    # the seed-faithful mode runs through the same replay
    out2 = tmp_path / 'seed'
    assert main(['replay', str(sim_bag), '--out', str(out2), '--nodes', 'odometry_fusion',
                 '--set', 'odometry_fusion.mode=seed']) == 0
    summ2 = json.loads((out2 / 'summary.json').read_text())['nodes']['odometry_fusion']
    assert summ2['mode'] == 'seed' and summ2['outputs']['odom'] > 1000


def test_replay_of_the_real_husky_bag(tmp_path):
    bag = REPO / 'bags' / 'husky_test1'
    if not bag.exists():
        pytest.skip('bags/husky_test1 is not present')
    out = tmp_path / 'husky'
    assert main(['replay', str(bag), '--out', str(out), '--nodes', 'odometry_fusion']) == 0
    summ = json.loads((out / 'summary.json').read_text())['nodes']['odometry_fusion']
    assert summ['imu_extrinsic'] == 'tf'  # base_link -> imu_link from /tf_static
    assert summ['accel_units'] == 'detected_mps2'
    est = _track(out / 'output.mcap', '/odometry/fused')
    raw = _track(bag, '/odom')
    fixes = [s for m in read_messages([bag], topics=['/fix']) for s in m.samples]
    lat0, lon0 = fixes[0].latitude, fixes[0].longitude
    gps = np.array([[f.t, math.radians(f.longitude - lon0) * 6378137.0 *
                     math.cos(math.radians(lat0)), math.radians(f.latitude - lat0) * 6378137.0]
                    for f in fixes])
    # GPS is not an input of the filter; it only scores the result
    assert _ate(est, gps) < _ate(raw, gps)
    assert summ['filter_counts'].get('reinitialisations', 0) == 0
    # a skid-steer robot: its odometry over-reads turns; the fit says so with a std that holds
    fit = summ['yaw_rate_calibration']
    assert fit['status'] == 'ok' and fit['blocks'] >= 30
    assert 0.6 < summ['estimates']['yaw_rate_scale'] < 0.95
    assert summ['estimates']['yaw_rate_scale_std'] < 0.05


def test_joint_states_of_the_simulator_with_its_geometry():
    sim = pytest.importorskip('robot_calib.sim')
    from robot_calib.methods.odometry_fusion.params import FusionParams
    from robot_calib.methods.odometry_fusion.pipeline import FusionPipeline
    res = sim.run_scenario('fusion_drive', seed=2, duration=60.0)
    nominal = res.truth.get('nominal', {})
    radius = nominal.get('wheel_radius', 0.05)
    track = nominal.get('track_width', 0.30)
    keys = {'/imu': 'imu', '/odom': 'odom', '/joint_states': 'joint_states',
            '/tf_static': 'tf_static'}

    def run(**kw):
        pipe = FusionPipeline(FusionParams(wheel_radius=radius, track_width=track, **kw))
        outs = []
        for topic, s in res.messages:
            if topic in keys:
                for x in (s if isinstance(s, list) else [s]):
                    outs += pipe.process(keys[topic], x)
        return pipe, np.array([(o.t, o.x, o.y, o.yaw) for k, o in outs if k == 'odom'])
    gt = np.array([(s.t, s.x, s.y, s.yaw) for tp, s in res.messages
                   if tp == '/ground_truth/odom'])
    pipe, est = run()  # auto: odometry wins, joint states are counted as not used
    assert pipe.summary()['inputs']['joint_states']['rejected_other_wheel_source_used'] > 100
    pipe_js, est_js = run(wheel_source='joint_states', initial_pose_from_odom=False)
    assert pipe_js.summary()['inputs']['odom']['rejected_other_wheel_source_used'] > 100
    raw = np.array([(s.t, s.x, s.y, s.yaw) for tp, s in res.messages if tp == '/odom'])
    assert _ate(est_js, gt) < 0.5 * _ate(raw, gt) + 0.1
    assert _ate(est_js, gt) < 2.0 * _ate(est, gt) + 0.2
