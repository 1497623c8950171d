# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""Every variant of every method folder is an Estimator of the one API (core.estimator)."""

import dataclasses
import importlib

import numpy as np
import pytest

from robot_calib import methods
from robot_calib.core import types as T
from robot_calib.core.estimator import Estimator, run_batch

CASES = [(name, mode) for name in methods.names() for mode in ('seed', 'improved')]


def _samples(pipeline_cls) -> list:
    """Return a short drive at rest in the sample kinds the method reads (IMU and odometry)."""
    kinds = {spec.kind for spec in pipeline_cls.inputs}
    out = []
    for k in range(40):
        t = 0.01 * k
        if 'imu' in kinds:
            out.append(T.ImuSample(t, np.zeros(3), np.array([0.0, 0.0, 9.80665])))
        if 'odom' in kinds and k % 4 == 0:
            out.append(T.OdomSample(t, 0.0, 0.0, 0.0))
    return out


@pytest.mark.parametrize('name,mode', CASES)
def test_variant_has_the_estimator_api(name, mode):
    """make_estimator(mode) gives an Estimator: mounting, update, a frozen result, reset."""
    variants = importlib.import_module(f'robot_calib.methods.{name}.variants')
    assert set(variants.VARIANTS) == {'seed', 'improved'}
    pipeline_cls = methods.load(name)
    est = variants.make_estimator(pipeline_cls.params_type(mode=mode))
    assert isinstance(est, Estimator)
    assert isinstance(est, variants.VARIANTS[mode])
    est.set_mounting(T.StaticTransform('base_link', 'some_sensor_link', np.zeros(3),
                                       np.array([1.0, 0.0, 0.0, 0.0])))
    first = run_batch(est, _samples(pipeline_cls)).result
    for result in (first, est.result()):
        assert dataclasses.is_dataclass(result) and type(result).__dataclass_params__.frozen
    est.reset()
    assert dataclasses.is_dataclass(est.result())


def test_variants_never_share_a_class():
    """The seed-faithful and improved variants are different classes in every method."""
    for name in methods.names():
        variants = importlib.import_module(f'robot_calib.methods.{name}.variants').VARIANTS
        assert variants['seed'] is not variants['improved'], name
