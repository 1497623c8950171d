# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Geometry, parameter dataclasses and the pipeline base against exact values."""

import dataclasses
import math

import numpy as np
import pytest

from robot_calib.core import geometry as G
from robot_calib.core import types as T
from robot_calib.core.params import describe, flatten_nested, from_flat, param, ParamError
from robot_calib.core.params import to_flat
from robot_calib.pipelines.base import InputSpec, OutputSpec, Pipeline
from robot_calib.pipelines.validation import sample_problem, UNCHECKED


def test_wrap_angle_range_is_half_open():
    assert G.wrap_angle(math.pi) == pytest.approx(math.pi)
    assert G.wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert G.wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    np.testing.assert_allclose(G.wrap_angle(np.array([0.1, 2 * math.pi + 0.1])), [0.1, 0.1])
    assert G.wrap_half_pi(math.pi - 0.1) == pytest.approx(-0.1)


def test_se2_compose_inverse_between():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = np.array([*rng.normal(size=2), rng.uniform(-3, 3)])
        b = np.array([*rng.normal(size=2), rng.uniform(-3, 3)])
        np.testing.assert_allclose(G.se2_compose(a, G.se2_between(a, b)), b, atol=1e-12)
        np.testing.assert_allclose(G.se2_compose(a, G.se2_inverse(a)), [0, 0, 0], atol=1e-12)
    pts = np.array([[1.0, 0.0]])
    np.testing.assert_allclose(G.se2_apply([1, 2, math.pi / 2], pts), [[1, 3]], atol=1e-12)


def test_quaternion_round_trips_and_tilt():
    rng = np.random.default_rng(2)
    for _ in range(50):
        q = G.quat_normalize(rng.normal(size=4))
        np.testing.assert_allclose(G.matrix_to_quat(G.quat_to_matrix(q)), q, atol=1e-9)
        v = rng.normal(size=3)
        qv = G.quat_multiply(G.quat_multiply(q, np.array([0, *v])), G.quat_conjugate(q))[1:]
        np.testing.assert_allclose(qv, G.quat_rotate(q, v), atol=1e-9)
    roll, pitch, yaw = 0.3, -0.2, 1.1
    q = G.quat_from_rpy(roll, pitch, yaw)
    np.testing.assert_allclose(G.quat_to_rpy(q), (roll, pitch, yaw), atol=1e-12)
    assert G.yaw_from_quat(q) == pytest.approx(yaw)
    assert G.tilt_from_quat(G.quat_from_rpy(0.0, math.pi / 3, 0.7)) == pytest.approx(math.pi / 3)
    assert G.tilt_from_quat(G.quat_from_rpy(math.pi, 0, 0)) == pytest.approx(math.pi)
    assert G.tilt_from_gravity([0, 0, 9.81]) == pytest.approx(0.0)
    assert G.tilt_from_gravity([9.81, 0, 0]) == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(G.quat_from_rotvec([0, 0, 0.5]), G.quat_from_rpy(0, 0, 0.5))


@dataclasses.dataclass
class _Inner:
    gain: float = param(0.5, '', 'a gain', minimum=0.0, maximum=1.0)


@dataclasses.dataclass
class _Params:
    mode: str = param('improved', '', 'variant', choices=('improved', 'seed'))
    angle: float = param(math.pi / 4, 'rad', 'an angle')
    count: int = param(3, '', 'a count', minimum=1)
    enabled: bool = param(False, '', 'a switch')
    weights: list = param([1.0, 2.0], '', 'weights', length=2)
    inner: _Inner = dataclasses.field(default_factory=_Inner)


def test_params_describe_flatten_and_validate():
    names = [i.name for i in describe(_Params)]
    assert names == ['mode', 'angle', 'count', 'enabled', 'weights', 'inner.gain']
    p = from_flat(_Params, {'inner.gain': '0.25', 'count': 4, 'enabled': 'true', 'angle': 'pi'})
    assert p.inner.gain == 0.25 and p.count == 4 and p.enabled is True
    assert p.angle == pytest.approx(math.pi)
    assert to_flat(p)['inner.gain'] == 0.25
    assert flatten_nested({'a': {'b': 1}, 'c': 2}) == {'a.b': 1, 'c': 2}
    with pytest.raises(ParamError, match='unknown parameter'):
        from_flat(_Params, {'nope': 1})
    with pytest.raises(ParamError, match='not one of'):
        from_flat(_Params, {'mode': 'fancy'})
    with pytest.raises(ParamError, match='above the maximum'):
        from_flat(_Params, {'inner.gain': 2.0})
    with pytest.raises(ParamError, match='expected int'):
        from_flat(_Params, {'count': 1.5})
    with pytest.raises(ParamError, match='expected float'):
        from_flat(_Params, {'angle': 'abc'})
    with pytest.raises(ParamError, match='must be finite'):
        from_flat(_Params, {'angle': 'nan'})


@pytest.mark.parametrize('value, message', [
    ('nan,1', 'must be finite'), ([1.0, math.inf], 'must be finite'), ('-inf, 2', 'finite'),
    ('1,2,3', 'expected a list of 2 numbers, got 3'), ([1.0], 'expected a list of 2 numbers'),
    ('', 'got 0 element'), ('a,b', 'expected a list of 2 numbers'), (7.0, 'expected a list'),
    ({'a': 1, 'b': 2}, 'expected a list')])
def test_list_params_check_element_type_length_and_finiteness(value, message):
    with pytest.raises(ParamError, match=message) as err:
        from_flat(_Params, {'weights': value})
    assert '\n' not in str(err.value) and str(err.value).startswith('parameter weights: ')


def test_list_params_parse_every_form_and_declare_their_shape():
    for value in ('0.5, pi', '[0.5, pi]', [0.5, math.pi], (0.5, math.pi)):
        assert from_flat(_Params, {'weights': value}).weights == [0.5, math.pi]

    @dataclasses.dataclass
    class Groups:
        episodes: list = param([], 's', 'pairs', length_multiple=2, items=float, minimum=0.0)

    assert from_flat(Groups, {'episodes': '1,2,3,4'}).episodes == [1.0, 2.0, 3.0, 4.0]
    with pytest.raises(ParamError, match='in groups of 2, got 3'):
        from_flat(Groups, {'episodes': '1,2,3'})
    with pytest.raises(ParamError, match='below the minimum'):
        from_flat(Groups, {'episodes': '1,-2'})
    with pytest.raises(TypeError, match='length'):
        param([1.0], '', 'no shape')
    with pytest.raises(TypeError, match='items'):
        param([], '', 'no element type', length_multiple=2)


class _Counter(Pipeline):
    name = 'counter'
    params_type = _Params
    inputs = (InputSpec('imu', 'imu', 'imu'),)
    outputs = (OutputSpec('out', 'counter/imu', 'imu'),)

    def handle(self, key, sample):
        return [('out', sample)]


def _imu(t, gz=0.0):
    return T.ImuSample(t, np.array([0.0, 0.0, gz]), np.array([0.0, 0.0, 9.81]))


def test_pipeline_base_counts_bad_samples_per_reason():
    pipe = _Counter()
    assert pipe.process('imu', _imu(1.0)) != []
    assert pipe.process('imu', _imu(1.0)) == []            # duplicate stamp
    assert pipe.process('imu', _imu(0.5)) == []            # backwards
    assert pipe.process('imu', _imu(2.0, float('nan'))) == []
    assert pipe.process('imu', _imu(5.0)) != []            # after a gap
    counts = pipe.summary()['inputs']['imu']
    assert counts['read'] == 5 and counts['accepted'] == 2 and counts['rejected'] == 3
    assert counts['rejected_duplicate_stamp'] == 1
    assert counts['rejected_out_of_order'] == 1
    assert counts['rejected_non_finite'] == 1
    assert counts['gaps'] == 1
    assert pipe.summary()['outputs'] == {'out': 2}
    assert pipe.summary()['params']['mode'] == 'improved'


def test_a_verdict_taken_once_gives_what_each_pipeline_finds_alone():
    """process_checked with sample_problem's verdict (or none yet) is process, counts included."""
    bad, nan = 1e9, float('nan')
    stream = [(0.0, 0.0), (0.01, 0.0), (0.01, 0.0), (0.005, 0.0), (0.02, nan), (0.03, bad),
              (5000.0, 0.0), (0.04, 0.0)]  # duplicate, backwards, non-finite, implausible, stray
    stream += [(900.0 + 0.01 * k, 0.0) for k in range(6)]  # a clock jump
    stream += [(902.0 + 1e-7 * k, 0.0) for k in range(80)]  # a burst
    samples = [_imu(t, gz) for t, gz in stream]
    samples.append(T.StaticTransform('base_link', 'imu_link', np.zeros(3),
                                     np.array([1.0, 0.0, 0.0, 0.0])))
    runs = []
    for how in ('alone', 'verdict', 'unchecked'):
        pipe, outs = _Counter(), []
        for s in samples:
            if how == 'alone':
                outs.append(pipe.process('imu', s))
            else:
                problem = UNCHECKED if how == 'unchecked' or isinstance(
                    s, T.StaticTransform) else sample_problem(s)
                outs.append(pipe.process_checked('imu', s, problem))
        summary = pipe.summary()
        runs.append((outs, list(summary['inputs']['imu'].items()), summary['outputs'],
                     pipe.static_transforms))
    counts = dict(runs[0][1])
    assert counts['rejected_implausible'] and counts['rejected_non_finite']
    assert counts['clock_jumps'] == 1 and counts['rejected_implausible_rate']
    assert runs[1] == runs[0] and runs[2] == runs[0]


def test_wrap_scalar_is_wrap_angle_for_floats():
    """The float fast path gives what the numpy wrap gives, edges included."""
    rng = np.random.default_rng(3)
    for a in list(rng.uniform(-40.0, 40.0, 500)) + [math.pi, -math.pi, 3 * math.pi, 0.0]:
        assert G.wrap_scalar(float(a)) == pytest.approx(G.wrap_angle(float(a)), abs=1e-12)
    assert G.wrap_scalar(-math.pi) == math.pi


def test_wrap_fast_paths_match_the_array_arithmetic():
    """One float wraps bit for bit as in an array; infinities give NaN as numpy does."""
    rng = np.random.default_rng(4)
    edges = [math.pi, -math.pi, math.pi / 2, -math.pi / 2, 0.0, 7 * math.pi]
    angles = np.concatenate([rng.uniform(-30.0, 30.0, 2000), edges])
    full, half = G.wrap_angle(angles), G.wrap_half_pi(angles)
    for k, a in enumerate(angles.tolist()):
        assert G.wrap_angle(a) == full[k]
        assert G.wrap_half_pi(a) == half[k]
    with np.errstate(invalid='ignore'):
        assert math.isnan(G.wrap_angle(math.inf)) and math.isnan(G.wrap_half_pi(-math.inf))
